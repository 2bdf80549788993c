"""The HMI's users: a small JSON file of names, roles and salted scrypt password hashes.

Format (``cell-hmi-users/1``), written by ``cellctl hmi passwd USER --role ROLE``::

    {"format": "cell-hmi-users/1",
     "users": {"alice": {"role": "maintenance",
                         "password": "scrypt$16384$8$1$<salt b64>$<hash b64>",
                         "generation": "<16 hex digits, new at every passwd>"}}}

Passwords are hashed with :func:`hashlib.scrypt` (n = 2**14, r = 8, p = 1, a 16-byte random
salt, 32-byte key) and compared in constant time. Roles: ``maintenance`` and ``engineer``
may edit recipes; ``viewer`` may only log in and look. The file is validated at load
(pydantic, unknown keys refused): a damaged file stops the HMI with the field named at
start; damaged later, it counts as no users until fixed. It is written atomically with mode
0600, and read again whenever it changes (:class:`Users`).
"""
from __future__ import annotations

import base64
import contextlib
import hashlib
import hmac
import json
import os
import re
import secrets
import tempfile
import threading
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cell.errors import ConfigError

FORMAT = "cell-hmi-users/1"
ROLES = ("maintenance", "engineer", "viewer")
EDIT_ROLES = frozenset({"maintenance", "engineer"})      #: roles that may save recipes
Role = Literal["maintenance", "engineer", "viewer"]
USER_NAME = r"^[A-Za-z0-9_.-]{1,40}$"
_N, _R, _P, _SALT, _KEY = 2 ** 14, 8, 1, 16, 32
MIN_PASSWORD = 8


class User(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    role: Role
    password: str = Field(pattern=r"^scrypt\$\d+\$\d+\$\d+\$[A-Za-z0-9+/=]+\$[A-Za-z0-9+/=]+$",
                          description="scrypt$n$r$p$salt$key, salt and key base64")
    generation: str = Field(default="", pattern=r"^[0-9a-f]{0,32}$",
                            description="renewed by every passwd: sessions made before it end")


class UsersFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    format: Literal["cell-hmi-users/1"] = FORMAT
    users: dict[str, User] = {}


def hash_password(password: str) -> str:
    """A fresh salted scrypt hash of ``password`` in the file's format."""
    salt = secrets.token_bytes(_SALT)
    key = hashlib.scrypt(password.encode("utf-8"), salt=salt, n=_N, r=_R, p=_P, dklen=_KEY)
    b64 = lambda b: base64.b64encode(b).decode("ascii")   # noqa: E731
    return f"scrypt${_N}${_R}${_P}${b64(salt)}${b64(key)}"


def check_password(password: str, stored: str) -> bool:
    """Whether ``password`` matches ``stored`` (constant-time compare)."""
    try:
        _, n, r, p, salt, key = stored.split("$")
        want = base64.b64decode(key)
        got = hashlib.scrypt(password.encode("utf-8"), salt=base64.b64decode(salt), n=int(n), r=int(r),
                             p=int(p), dklen=len(want), maxmem=256 * 1024 * 1024)
    except (ValueError, TypeError):
        return False
    return hmac.compare_digest(got, want)


# a hash to check against when the user does not exist, so a wrong name costs as long as a
# wrong password (no user enumeration by timing)
_DUMMY = hash_password(secrets.token_hex(16))


class Users:
    """The users of one file, read again whenever it changes (its stat signature is looked
    at on each use, which costs one ``stat``), so ``cellctl hmi passwd`` takes effect at once.

    Sessions: :meth:`stamp` is what a session remembers of its user at login; the session is
    valid while the stamp is the same. It changes when ``passwd`` writes the user again (a
    new ``generation`` in the file) and when :meth:`end_sessions` is called (logout), so
    either ends every session of that user. A file that cannot be read or is damaged counts
    as no users (everyone logged out, nobody can log in) until it is fixed; :attr:`error`
    says why.
    """

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self.error: str | None = None
        self._sig: tuple | None = None
        self._lock = threading.Lock()
        self._ended: dict[str, int] = {}          # user -> sessions ended in memory (logouts)
        self.file = load(self.path)               # a damaged file stops the HMI at start
        self._sig = _signature(self.path)

    def current(self) -> UsersFile:
        """The users as the file says now."""
        sig = _signature(self.path)
        with self._lock:
            if sig != self._sig:
                try:
                    self.file, self.error = load(self.path), None
                except ConfigError as exc:
                    self.file, self.error = UsersFile(), str(exc)
                self._sig = sig
            return self.file

    def authenticate(self, name: str, password: str) -> tuple[str, str, str] | None:
        """(name, role, stamp) when ``password`` is ``name``'s, else None. A name no user
        can have is refused without hashing; any other costs one scrypt hash, known or not."""
        if not re.match(USER_NAME, name):
            return None
        user = self.current().users.get(name)
        ok = check_password(password, user.password if user else _DUMMY)
        return (name, user.role, self._stamp(name, user)) if (ok and user is not None) else None

    def role(self, name: str, stamp: str) -> str | None:
        """``name``'s role if a session stamped ``stamp`` is still valid, else None."""
        user = self.current().users.get(name)
        if user is None:
            return None
        if not hmac.compare_digest(self._stamp(name, user).encode(), str(stamp).encode("utf-8", "replace")):
            return None
        return user.role

    def end_sessions(self, name: str) -> None:
        """Every session of ``name`` ends (logout)."""
        with self._lock:
            self._ended[name] = self._ended.get(name, 0) + 1

    def _stamp(self, name: str, user: User) -> str:
        return f"{user.generation}.{self._ended.get(name, 0)}"

    def __len__(self) -> int:
        return len(self.current().users)


def _signature(path: Path) -> tuple | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_dev, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def load(path: Path) -> UsersFile:
    """The users file at ``path`` (no file: no users). Raises ConfigError naming the field."""
    if not path.exists():
        return UsersFile()
    try:
        return UsersFile.model_validate(json.loads(path.read_text(encoding="utf-8")))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the HMI users file: {exc.strerror}") from None
    except ValidationError as exc:
        from cell.yamlio import error_text
        e = exc.errors()[0]
        where = ".".join(str(p) for p in e["loc"])
        raise ConfigError(f"{path}: {where}: {error_text(e, UsersFile)}") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not a JSON users file: {exc}") from None


def set_user(path: Path | str, name: str, role: str, password: str) -> None:
    """Add ``name`` or replace its role and password, with a new session ``generation``
    (every session of the user ends); writes the file atomically, mode 0600, through a
    temporary file made by :func:`tempfile.mkstemp` (``O_CREAT | O_EXCL | O_NOFOLLOW``, a
    random name: a symlink planted beside the file cannot redirect the write).

    :raises ConfigError: bad name, role or a password shorter than 8 characters.
    """
    path = Path(path)
    if not re.match(USER_NAME, name):
        raise ConfigError(f"user name {name!r}: use 1-40 letters, digits, '_', '.' or '-'")
    if role not in ROLES:
        raise ConfigError(f"role {role!r}: one of {', '.join(ROLES)}")
    if len(password) < MIN_PASSWORD:
        raise ConfigError(f"the password must have at least {MIN_PASSWORD} characters")
    current = load(path)
    users = dict(current.users)
    users[name] = User(role=role, password=hash_password(password), generation=secrets.token_hex(8))
    doc = UsersFile(users=users).model_dump(mode="json")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(json.dumps(doc, indent=2) + "\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
