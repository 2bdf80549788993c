"""Project-wide pytest options: ``--hw`` runs the tests marked ``@pytest.mark.hw`` on real devices;
``--slow`` runs the tests marked ``@pytest.mark.slow`` (the long end-to-end tier, about half
the suite's CPU), which otherwise run only under ``CI=true``: a developer's ``python3 dev.py
test`` takes a few minutes, and CI (``.ci/run``: ``python3 dev.py test --slow``) still runs
every test before anything lands.

Under ``CI=true`` (CI runs ``python3 dev.py test`` so) a test may skip only if it is marked
``hw``: any other skip, whatever raised it (a ``skipif``, ``pytest.skip``, a missing tool
of :mod:`tests.tools`), is turned into a failure that names the skip's reason, so CI cannot
pass by not running a test.
"""
import pytest

from tests.tools import under_ci


def pytest_addoption(parser):
    parser.addoption("--hw", action="store_true", default=False,
                     help="run @pytest.mark.hw tests against real hardware (camera, CAN interface)")
    parser.addoption("--slow", action="store_true", default=False,
                     help="run the long end-to-end tests (@pytest.mark.slow); CI=true always does")


def pytest_collection_modifyitems(config, items):
    hw = None if config.getoption("--hw") else \
        pytest.mark.skip(reason="needs real hardware: run with --hw")
    slow = None if config.getoption("--slow") or under_ci() else \
        pytest.mark.skip(reason="the slow tier: run with --slow (CI=true runs it)")
    for item in items:
        if hw is not None and "hw" in item.keywords:
            item.add_marker(hw)
        if slow is not None and "slow" in item.keywords:
            item.add_marker(slow)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if not (report.skipped and under_ci()) or hasattr(report, "wasxfail") or "hw" in item.keywords:
        return
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    report.outcome = "failed"
    report.longrepr = (f"skipped under CI=true, where only real-hardware (hw) tests may skip: "
                       f"{reason}")
