"""Project-wide pytest options: ``--hw`` runs the tests marked ``@pytest.mark.hw`` on real devices."""
import pytest


def pytest_addoption(parser):
    parser.addoption("--hw", action="store_true", default=False,
                     help="run @pytest.mark.hw tests against real hardware (camera, CAN interface)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--hw"):
        return
    skip = pytest.mark.skip(reason="needs real hardware: run with --hw")
    for item in items:
        if "hw" in item.keywords:
            item.add_marker(skip)
