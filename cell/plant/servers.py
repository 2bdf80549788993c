"""A real MQTT broker and a real PostgreSQL on loopback, started by this project's own code.

For tests and for trying the plant path on one machine: :class:`Mosquitto` runs Debian's
``mosquitto`` (2.0), :class:`Postgres` runs PostgreSQL 15's ``initdb``/``pg_ctl``
(Debian keeps them in ``/usr/lib/postgresql/<v>/bin``, off ``PATH``), each in a temporary
folder of its own on a free loopback port. Both are context managers; ``stop()`` ends the
server and removes its folder; ``kill()`` ends it with SIGKILL (a crash) and leaves the folder,
so ``start()`` can bring the same server back on the same port.

PostgreSQL refuses to run as root. As root, every PostgreSQL program here runs as an
unprivileged user (``postgres`` if the system has it, else ``nobody``) through
``runuser -u USER --`` (util-linux), and the data folder is made that user's; as any
other user they run as that user. The server trusts loopback connections of its one
role (``cell``): a test server, never a plant's (the plant's set-up is ``deploy/``'s).

:class:`Mosquitto` given ``users`` (user name -> password) runs the plant's deployed
configuration instead, ``deploy/mosquitto/plant.conf`` with its ACL ``plant.acl``: TLS
only, logins from a password file (made with ``mosquitto_passwd``), a cell publishing only
under its own topics. Only the port, the file paths, persistence and the log's destination
are replaced; the certificates are made for it (:func:`cell.plant.pki.broker_certificates`).

Not found binaries raise :class:`ServerMissing` naming the Debian package to install
(``mosquitto``, ``postgresql``); a server that does not come up raises
:class:`ServerError` with the end of its own log.
"""
from __future__ import annotations

import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path

from cell.errors import CellError

DEPLOY = Path(__file__).resolve().parents[2] / "deploy" / "mosquitto"
DEPLOY_CONF = DEPLOY / "plant.conf"        #: the broker configuration a plant deploys
DEPLOY_ACL = DEPLOY / "plant.acl"          #: who may read and write what on it

PG_ROLE = "cell"            #: the one (super)user of a test PostgreSQL
PG_DATABASE = "historian"   #: the database a test PostgreSQL is started with


class ServerError(CellError):
    """A server could not be started or stopped; the message says which and why."""


class ServerMissing(ServerError):
    """The server's binaries are not installed; ``package`` is the Debian package."""

    def __init__(self, what: str, package: str):
        super().__init__(f"{what} not installed (apt-get install {package})")
        self.package = package


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now (the kernel's choice)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_port(port: int, alive, timeout: float, what: str, log: Path) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not alive():
            raise ServerError(f"{what} exited at start: {_tail(log)}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                return
        except OSError:
            time.sleep(0.05)
    raise ServerError(f"{what} did not listen on 127.0.0.1:{port} within {timeout:g} s: {_tail(log)}")


def _tail(path: Path, n: int = 1500) -> str:
    try:
        return path.read_text(errors="replace")[-n:].strip() or "(empty log)"
    except OSError:
        return "(no log)"


# ---------------------------------------------------------------------------- mosquitto
def mosquitto_binary() -> str:
    """The path of ``mosquitto``; raises :class:`ServerMissing`."""
    found = shutil.which("mosquitto") or next(
        (p for p in ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto") if os.access(p, os.X_OK)), None)
    if not found:
        raise ServerMissing("mosquitto", "mosquitto")
    return found


class Mosquitto:
    """A mosquitto broker on ``127.0.0.1:port``, anonymous, MQTT 3.1.1 and 5; or, given
    ``users``, the deployed one (TLS, logins, ACL; see the module doc).

    :param users: user name -> password; the broker then serves TLS with the certificates
        in :attr:`certificates` (clients trust ``certificates.ca``).
    :param persistence: keep retained messages and sessions in a file across a clean stop
        (mosquitto writes it at exit and every ``autosave_s``; a SIGKILL loses what came
        after the last save, as on a plant broker's power cut).
    :param port: the port (default: a free one, kept across :meth:`kill` and :meth:`start`).
    """

    def __init__(self, persistence: bool = False, port: int | None = None, autosave_s: int = 60,
                 users: Mapping[str, str] | None = None):
        self.binary = mosquitto_binary()
        self.users = dict(users) if users is not None else None
        self.port = port or free_port()
        self.host = "127.0.0.1"
        self.persistence = persistence
        self.autosave_s = autosave_s
        self.folder = Path(tempfile.mkdtemp(prefix="cell-mosquitto-"))
        self.log = self.folder / "mosquitto.log"
        self.proc: subprocess.Popen | None = None
        self.certificates = None
        if self.users is not None:
            from cell.plant.pki import broker_certificates
            self.certificates = broker_certificates(self.folder / "certs")
            self._password_file(self.folder / "plant.passwd")

    def _password_file(self, path: Path) -> None:
        tool = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"
        if not os.access(tool, os.X_OK):
            raise ServerMissing("mosquitto_passwd", "mosquitto")
        path.touch(mode=0o600)
        for user, password in self.users.items():
            done = subprocess.run([tool, "-b", str(path), user, password], capture_output=True, text=True,
                                  timeout=60)
            if done.returncode != 0:
                raise ServerError(f"mosquitto_passwd could not add {user!r}: {(done.stderr or done.stdout).strip()}")

    def _deployed_config(self) -> list[str]:
        """``deploy/mosquitto/plant.conf`` with this broker's port, files and persistence."""
        c = self.certificates
        replace = {"listener": f"listener {self.port} 127.0.0.1", "cafile": f"cafile {c.ca}",
                   "certfile": f"certfile {c.cert}", "keyfile": f"keyfile {c.key}",
                   "password_file": f"password_file {self.folder / 'plant.passwd'}",
                   "acl_file": f"acl_file {DEPLOY_ACL}",
                   "persistence": f"persistence {'true' if self.persistence else 'false'}",
                   "persistence_location": f"persistence_location {self.folder}/",
                   "autosave_interval": f"autosave_interval {self.autosave_s}", "log_dest": "log_dest stderr"}
        lines = []
        for line in DEPLOY_CONF.read_text().splitlines():
            key = line.split()[0] if line.strip() and not line.lstrip().startswith("#") else None
            lines.append(replace.get(key, line))
        return lines

    def _config(self) -> Path:
        conf = self.folder / "mosquitto.conf"
        if self.users is not None:
            lines = self._deployed_config()
            if os.geteuid() == 0:
                lines.append("user root")
            conf.write_text("\n".join(lines) + "\n")
            return conf
        lines = [f"listener {self.port} 127.0.0.1", "allow_anonymous true",
                 f"persistence {'true' if self.persistence else 'false'}",
                 f"persistence_location {self.folder}/", f"autosave_interval {self.autosave_s}",
                 "max_queued_messages 100000", "log_dest stderr", "log_type error",
                 "log_type warning", "log_type notice"]
        if os.geteuid() == 0:
            lines.append("user root")           # a test broker; its folder is root's
        conf.write_text("\n".join(lines) + "\n")
        return conf

    def start(self, timeout: float = 30.0) -> "Mosquitto":
        """Start the broker and wait until it accepts connections; raises :class:`ServerError`."""
        conf = self._config()
        with open(self.log, "ab") as out:
            self.proc = subprocess.Popen([self.binary, "-c", str(conf)], stdout=out, stderr=out,
                                         stdin=subprocess.DEVNULL)
        _wait_port(self.port, lambda: self.proc.poll() is None, timeout, "mosquitto", self.log)
        return self

    def kill(self) -> None:
        """SIGKILL the broker (a crash: nothing saved since the last autosave) and reap it."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=30)

    def stop(self) -> None:
        """End the broker (SIGTERM, then SIGKILL after 10 s) and remove its folder."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> "Mosquitto":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


# ---------------------------------------------------------------------------- PostgreSQL
def postgres_bindir() -> Path:
    """The folder holding ``initdb``, ``pg_ctl`` and ``postgres``: ``PATH``'s if it has
    them, else the newest ``/usr/lib/postgresql/<v>/bin``; raises :class:`ServerMissing`."""
    on_path = shutil.which("initdb")
    if on_path and shutil.which("pg_ctl"):
        return Path(os.path.realpath(on_path)).parent
    folders = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda p: int(p.split("/")[-2])
                     if p.split("/")[-2].isdigit() else 0)
    for folder in reversed(folders):
        if os.access(os.path.join(folder, "initdb"), os.X_OK):
            return Path(folder)
    raise ServerMissing("PostgreSQL (initdb, pg_ctl)", "postgresql")


def unprivileged_user() -> str | None:
    """The user PostgreSQL runs as when we are root: ``postgres``, else ``nobody``;
    None when we are not root (then it runs as us)."""
    if os.geteuid() != 0:
        return None
    for name in ("postgres", "nobody"):
        try:
            pwd.getpwnam(name)
            return name
        except KeyError:
            continue
    raise ServerError("running as root and neither a 'postgres' nor a 'nobody' user exists: "
                      "PostgreSQL refuses to run as root")


class Postgres:
    """A PostgreSQL cluster in a temporary folder, on ``127.0.0.1:port``, with database
    :data:`PG_DATABASE` owned by role :data:`PG_ROLE` (trust auth, loopback only).

    :attr:`dsn` is a libpq connection string for it. :meth:`kill` is an immediate shutdown
    (``pg_ctl stop -m immediate``: every backend quits at once, no checkpoint; the next
    start recovers from the WAL, as after a crash); :meth:`start` brings it back.
    """

    def __init__(self, port: int | None = None):
        self.bindir = postgres_bindir()
        self.user = unprivileged_user()
        self.port = port or free_port()
        self.host = "127.0.0.1"
        self.folder = Path(tempfile.mkdtemp(prefix="cell-postgres-"))
        self.data = self.folder / "data"
        self.log = self.folder / "postgres.log"
        self._initialised = False
        if self.user is not None:
            pw = pwd.getpwnam(self.user)
            os.chown(self.folder, pw.pw_uid, pw.pw_gid)

    @property
    def dsn(self) -> str:
        return f"host={self.host} port={self.port} user={PG_ROLE} dbname={PG_DATABASE} connect_timeout=5"

    def _run(self, program: str, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
        argv = [str(self.bindir / program), *args]
        if self.user is not None:
            argv = ["runuser", "-u", self.user, "--", *argv]
        env = {k: v for k, v in os.environ.items() if not k.startswith("PG")}
        env["LC_ALL"] = env["LANG"] = "C.UTF-8"
        return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, cwd=self.folder, env=env)

    def _check(self, done: subprocess.CompletedProcess, what: str) -> None:
        if done.returncode != 0:
            raise ServerError(f"PostgreSQL {what} failed (exit {done.returncode}): "
                              f"{(done.stderr or done.stdout).strip()[-1500:]} {_tail(self.log)}")

    def start(self, timeout: float = 120.0) -> "Postgres":
        """Initialise the cluster the first time, then start it and wait until it accepts
        connections; raises :class:`ServerError`."""
        if not self._initialised:
            self._check(self._run("initdb", "-D", str(self.data), "-U", PG_ROLE, "--auth=trust",
                                  "--encoding=UTF8", "--no-sync"), "initdb")
            with open(self.data / "postgresql.conf", "a") as conf:
                conf.write(f"\nlisten_addresses = '127.0.0.1'\nport = {self.port}\n"
                           f"unix_socket_directories = '{self.folder}'\n"
                           "fsync = off\nshared_buffers = 16MB\nmax_connections = 30\n")
        opts = "-c log_min_messages=warning"
        self._check(self._run("pg_ctl", "-D", str(self.data), "-l", str(self.log), "-o", opts,
                              "-w", "-t", str(int(timeout)), "start", timeout=timeout + 30), "start")
        if not self._initialised:
            self._check(self._run("createdb", "-h", self.host, "-p", str(self.port), "-U", PG_ROLE,
                                  PG_DATABASE), "createdb")
            self._initialised = True
        return self

    def running(self) -> bool:
        return self._run("pg_ctl", "-D", str(self.data), "status").returncode == 0

    def kill(self) -> None:
        """Immediate shutdown: backends end at once, nothing is checkpointed (a crash)."""
        self._check(self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop"),
                    "immediate stop")

    def stop(self) -> None:
        """Stop the server (fast shutdown; immediate if that fails) and remove its folder."""
        if self.data.exists() and self.running():
            if self._run("pg_ctl", "-D", str(self.data), "-m", "fast", "-w", "-t", "30", "stop").returncode:
                self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")
        pid_file = self.data / "postmaster.pid"
        if pid_file.exists():                    # still there: the postmaster did not go
            try:
                os.kill(int(pid_file.read_text().split()[0]), signal.SIGKILL)
            except (OSError, ValueError, IndexError):
                pass
        shutil.rmtree(self.folder, ignore_errors=True)

    def __enter__(self) -> "Postgres":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
