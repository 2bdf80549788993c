"""A real headless Chromium for the browser tests (Debian's ``chromium`` and
``chromium-driver``, driven by Selenium; nothing is downloaded).

``python3 dev.py test`` installs both when it may. Without them a browser test skips, except
under ``CI=true``, where a missing browser is a failure (the rule of :mod:`tests.tools`).

Usage::

    from tests.browser import chromium

    def test_page(tmp_path):
        with chromium(tmp_path, width=1280, height=800) as driver:
            driver.get(url)
"""
from __future__ import annotations

import contextlib
from pathlib import Path

from tests.tools import require_tool

# the flags that keep Chromium off the network this machine does not have (and quiet)
FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
         "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--disable-extensions",
         "--hide-scrollbars", "--force-device-scale-factor=1")


def require_browser() -> tuple[str, str]:
    """The paths of Chromium and ChromeDriver; skip the calling test when either is missing
    (fail under CI: :func:`tests.tools.require_tool`)."""
    return (require_tool("chromium", "chromium-browser", package="chromium"),
            require_tool("chromedriver", package="chromium-driver"))


@contextlib.contextmanager
def chromium(profile_dir: Path, width: int = 1280, height: int = 800):
    """A Selenium WebDriver on a fresh headless Chromium with a ``width`` × ``height``
    window and its profile in ``profile_dir`` (a test's tmp_path). Quits on exit."""
    browser, driver_path = require_browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = browser
    for f in FLAGS:
        opts.add_argument(f)
    opts.add_argument(f"--window-size={width},{height}")
    opts.add_argument(f"--user-data-dir={Path(profile_dir) / 'chromium-profile'}")
    driver = webdriver.Chrome(options=opts, service=Service(executable_path=driver_path))
    try:
        driver.set_page_load_timeout(60)
        yield driver
    finally:
        driver.quit()
