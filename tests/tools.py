"""The system tools some tests drive (Chromium, ChromeDriver, mbpoll): one rule for all.

A missing tool skips the test that needs it, saying which package to install, except under
``CI=true``, where it fails: CI must run every test but the real-hardware ones (``hw``).
``python3 dev.py test`` installs the tools when it may (root with apt-get).

Usage::

    from tests.tools import require_tool

    def test_x():
        mbpoll = require_tool("mbpoll", package="mbpoll")
"""
from __future__ import annotations

import os
import shutil

import pytest


def under_ci() -> bool:
    """True when the tests run in CI (``CI`` set to 1, true or yes, as CI services set it)."""
    return os.environ.get("CI", "").strip().lower() in {"1", "true", "yes"}


def skip_unless_ci(why: str) -> None:
    """Skip the calling test for ``why``; under CI fail with it instead (CI runs everything)."""
    if under_ci():
        pytest.fail(f"{why}; CI must run this test (only real-hardware tests may skip)")
    pytest.skip(why)


def require_tool(*names: str, package: str) -> str:
    """The path of the first of ``names`` on PATH; if none is, skip (fail under CI) naming
    the Debian ``package`` to install."""
    for name in names:
        path = shutil.which(name)
        if path:
            return path
    skip_unless_ci(f"{' or '.join(names)} not installed (apt-get install {package})")
    raise AssertionError("unreachable")   # pytest.skip/fail raise
