"""Run a check as an unprivileged user, so a test of "cannot write" or "cannot read" means
what it says even when the suite runs as root (CI does).

Root writes read-only files and reads unreadable ones, so such a check run as root never
meets its condition. :func:`as_unprivileged` forks: the child drops to ``nobody`` (uid and
gid 65534, no supplementary groups) before it runs the check, and sends back its result
or its exception. The child is a fork of the test process, so it needs no interpreter or
project files it cannot read (the interpreter under ``/root`` is not readable by
``nobody``): import what the check needs before calling. Not root, the check runs in this
process, which is already unprivileged.

:func:`nobody_dir` gives a temporary folder the child can use: pytest's ``tmp_path`` lies
under a folder only its owner may enter.
"""
from __future__ import annotations

import contextlib
import os
import pickle
import shutil
import signal
import tempfile
import traceback
from pathlib import Path
from typing import Any, Callable, Iterator

NOBODY = 65534          #: uid and gid of ``nobody`` on Debian
CHILD_LIMIT_S = 60      #: the child is killed (SIGALRM) if its check has not ended by then


def is_root() -> bool:
    return os.geteuid() == 0


@contextlib.contextmanager
def nobody_dir(prefix: str = "cell-test-") -> Iterator[Path]:
    """A fresh temporary folder owned by ``nobody`` when root (else by this user), mode
    0700; removed afterwards."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    try:
        if is_root():
            os.chown(path, NOBODY, NOBODY)
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def give_to_nobody(*paths: Path) -> None:
    """Make ``paths`` (files or whole folders) ``nobody``'s when root; nothing otherwise."""
    if not is_root():
        return
    for path in paths:
        os.chown(path, NOBODY, NOBODY, follow_symlinks=False)
        if Path(path).is_dir() and not Path(path).is_symlink():
            for root, dirs, files in os.walk(path):
                for name in dirs + files:
                    os.chown(os.path.join(root, name), NOBODY, NOBODY, follow_symlinks=False)


def as_unprivileged(check: Callable[..., Any], *args: Any) -> Any:
    """``check(*args)`` run as ``nobody`` (see the module doc); returns what it returns.

    Its exception (an AssertionError of the check, say) is raised here as an
    AssertionError carrying the child's traceback. The result must pickle.
    """
    if not is_root():
        return check(*args)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:                                     # the child: never returns
        code = 0
        try:
            os.close(read)
            # a fork of a threaded process: should it ever block on a lock another thread
            # held at the fork, it dies (the parent then reports an empty answer) instead
            # of hanging the test run
            signal.signal(signal.SIGALRM, signal.SIG_DFL)
            signal.alarm(CHILD_LIMIT_S)
            try:
                os.setgroups([])
                os.setgid(NOBODY)
                os.setuid(NOBODY)
                if os.geteuid() != NOBODY or os.getegid() != NOBODY:
                    raise RuntimeError(f"still uid {os.geteuid()} gid {os.getegid()} after dropping")
                payload = (True, check(*args))
            except BaseException as exc:             # noqa: BLE001 -- reported to the parent
                payload = (False, f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}")
            with os.fdopen(write, "wb") as out:
                pickle.dump(payload, out)
        except BaseException:                        # noqa: BLE001 -- the child must not go on
            code = 1
        finally:
            os._exit(code)
    os.close(write)
    with os.fdopen(read, "rb") as inp:
        data = inp.read()
    _, status = os.waitpid(pid, 0)
    if not data:
        raise AssertionError(f"the unprivileged child sent nothing back (wait status {status})")
    ok, value = pickle.loads(data)
    if not ok:
        raise AssertionError(f"as uid {NOBODY} (nobody): {value}")
    return value
