"""Shared fixtures of the driver tests."""
import socket
import threading
import time

import pytest

from cell.clock import ManualClock
from drivers.plc.server import PlcLink
from tests import waiting

PLC_THREADS = ("plc-modbus-server", "plc-modbus-tls-server", "sim-plc-scan", "bare-pymodbus", "controller-stand-in")


@pytest.fixture
def no_leaked_plc_threads():
    """Fail a PLC test that leaves a server or scan thread running after it."""
    yield
    leaked = [t.name for t in threading.enumerate() if t.name in PLC_THREADS]
    assert not leaked, f"threads left running: {leaked}"


@pytest.fixture
def link():
    """A started PlcLink on a free loopback port (test files may define their own variant),
    on a ManualClock: the owning client's link never times out unless a test advances it,
    however slowly the machine runs."""
    link = PlcLink(clock=ManualClock(0.0))
    link.start()
    yield link
    link.stop()


def wait_for(pred, timeout=2.0, what="condition"):
    """:func:`tests.waiting.wait_for` polling every 2 ms (the PLC link answers in microseconds)."""
    return waiting.wait_for(pred, timeout, what, every=0.002)


def server_closed(s: socket.socket, timeout: float = 10.0) -> bool:
    """The server closed ``s`` (EOF or reset) within ``timeout`` s: polls, a generous bound,
    not a timing. Data the server sends meanwhile is read and dropped."""
    deadline = time.monotonic() + timeout
    s.settimeout(0.2)
    while time.monotonic() < deadline:
        try:
            if s.recv(4096) == b"":
                return True
        except socket.timeout:
            continue
        except OSError:
            return True
    return False


# ------------------------------------------------------------------ simulated clock helpers
def clock_wait_for(clock, pred, timeout=2.0, what="condition", step=0.0005):
    """:func:`wait_for` in the time of ``clock`` (a ``VirtualClock`` the calling thread keeps
    time on, or a wall clock): poll ``pred`` every ``step`` clock seconds; returns the clock
    time at which it was first seen true; AssertionError naming ``what`` after ``timeout``
    clock seconds. On the simulated clock the result is exact to ``step``."""
    deadline = clock.now() + timeout
    while not pred():
        if clock.now() >= deadline:
            raise AssertionError(f"timed out after {timeout} s of clock time waiting for {what} "
                                 f"(clock at {clock.now():.6f} s)")
        clock.sleep(step)
    return clock.now()


def unique_channel(prefix="t"):
    """A virtual CAN channel name no other test uses (wires are shared by name)."""
    import uuid
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


def drain(bus):
    """Every frame a pull-mode (sniffing) bus holds right now, oldest first (never waits)."""
    out = []
    while True:
        msg = bus.recv(0)
        if msg is None:
            return out
        out.append(msg)


@pytest.fixture
def vclock():
    """A fresh pure ``VirtualClock`` whose time the test's thread keeps for the whole test
    (setup, body and teardown of fixtures requested after it); closed afterwards."""
    from cell.sim.clock import VirtualClock
    clock = VirtualClock()
    with clock.attach("test"):
        yield clock
    clock.close()
    assert clock._thread is None or not clock._thread.is_alive(), "the clock's thread outlived the test"
