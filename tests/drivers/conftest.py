"""Shared fixtures of the driver tests."""
import threading
import time

import pytest

from drivers.plc.server import PlcLink

PLC_THREADS = ("plc-modbus-server", "sim-plc-scan", "bare-pymodbus", "controller-stand-in")


@pytest.fixture
def no_leaked_plc_threads():
    """Fail a PLC test that leaves a server or scan thread running after it."""
    yield
    leaked = [t.name for t in threading.enumerate() if t.name in PLC_THREADS]
    assert not leaked, f"threads left running: {leaked}"


@pytest.fixture
def link():
    """A started PlcLink on a free loopback port (test files may define their own variant)."""
    link = PlcLink()
    link.start()
    yield link
    link.stop()


def wait_for(pred, timeout=2.0, what="condition"):
    """Poll ``pred`` every 2 ms until true; AssertionError naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.002)
