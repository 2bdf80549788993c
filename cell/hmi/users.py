"""The HMI's users: a small JSON file of names, roles and salted scrypt password hashes.

Format (``cell-hmi-users/1``), written by ``cellctl hmi passwd USER --role ROLE``::

    {"format": "cell-hmi-users/1",
     "users": {"alice": {"role": "maintenance",
                         "password": "scrypt$16384$8$1$<salt b64>$<hash b64>"}}}

Passwords are hashed with :func:`hashlib.scrypt` (n = 2**14, r = 8, p = 1, a 16-byte random
salt, 32-byte key) and compared in constant time. Roles: ``maintenance`` and ``engineer``
may edit recipes; ``viewer`` may only log in and look. The file is validated at load
(pydantic, unknown keys refused): a damaged file stops the HMI with the field named. It is
written atomically with mode 0600.
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import json
import os
import secrets
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
    """The users of one file. :meth:`authenticate` → (name, role) or None."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self.file = load(self.path)

    def authenticate(self, name: str, password: str) -> tuple[str, str] | None:
        user = self.file.users.get(name)
        ok = check_password(password, user.password if user else _DUMMY)
        return (name, user.role) if (ok and user is not None) else None

    def __len__(self) -> int:
        return len(self.file.users)


def load(path: Path) -> UsersFile:
    """The users file at ``path`` (no file: no users). Raises ConfigError naming the field."""
    if not path.exists():
        return UsersFile()
    try:
        return UsersFile.model_validate(json.loads(path.read_text(encoding="utf-8")))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the HMI users file: {exc.strerror}") from None
    except ValidationError as exc:
        e = exc.errors()[0]
        where = ".".join(str(p) for p in e["loc"])
        raise ConfigError(f"{path}: {where}: {e['msg']}") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not a JSON users file: {exc}") from None


def set_user(path: Path | str, name: str, role: str, password: str) -> None:
    """Add ``name`` or replace its role and password; writes the file atomically, mode 0600.

    :raises ConfigError: bad name, role or a password shorter than 8 characters.
    """
    import re
    path = Path(path)
    if not re.match(USER_NAME, name):
        raise ConfigError(f"user name {name!r}: use 1-40 letters, digits, '_', '.' or '-'")
    if role not in ROLES:
        raise ConfigError(f"role {role!r}: one of {', '.join(ROLES)}")
    if len(password) < MIN_PASSWORD:
        raise ConfigError(f"the password must have at least {MIN_PASSWORD} characters")
    current = load(path)
    users = dict(current.users)
    users[name] = User(role=role, password=hash_password(password))
    doc = UsersFile(users=users).model_dump(mode="json")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(json.dumps(doc, indent=2) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


class LoginThrottle:
    """Failed logins slow guessing down: after ``limit`` failures for one user name, or
    from one client address, within ``window_s``, further attempts for it are refused
    unchecked until ``window_s`` has passed since the oldest of them (times from ``clock``,
    wall time in the product). A successful login clears the user's count."""

    def __init__(self, clock=None, limit: int = 5, window_s: float = 300.0):
        from cell.clock import MonotonicClock
        self.clock = clock or MonotonicClock()
        self.limit, self.window_s = int(limit), float(window_s)
        self._fails: dict[str, list[float]] = {}

    def _recent(self, key: str) -> list[float]:
        now = self.clock.now()
        times = [t for t in self._fails.get(key, []) if now - t < self.window_s]
        if times:
            self._fails[key] = times
        else:
            self._fails.pop(key, None)
        return times

    def blocked(self, user: str, client: str) -> float:
        """Seconds until ``user`` from ``client`` may try again (0: now)."""
        now, wait = self.clock.now(), 0.0
        for key in (f"u:{user}", f"c:{client}"):
            times = self._recent(key)
            if len(times) >= self.limit:
                wait = max(wait, times[-self.limit] + self.window_s - now)
        return wait

    def failed(self, user: str, client: str) -> None:
        now = self.clock.now()
        for key in (f"u:{user}", f"c:{client}"):
            self._fails.setdefault(key, []).append(now)
            del self._fails[key][:-self.limit]          # bounded memory per key
        if len(self._fails) > 10_000:                   # many names guessed: forget the oldest
            for key in sorted(self._fails, key=lambda k: self._fails[k][-1])[:5_000]:
                del self._fails[key]

    def succeeded(self, user: str) -> None:
        self._fails.pop(f"u:{user}", None)
