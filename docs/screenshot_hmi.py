#!/usr/bin/env python3
"""Write ``docs/img/hmi.png``: the maintenance HMI's status page beside a running simulated
cell, in headless Chromium.

    .venv/bin/python docs/screenshot_hmi.py [--cycles-first 40] [--out docs/img/hmi.png]

It starts ``cellctl run --sim`` (private recipes and log in a temporary folder) and
``cellctl hmi`` on a free loopback port (:mod:`tests.system.hmi_cell`), waits until the log
holds ``--cycles-first`` cycles, logs in as the demo maintenance user, opens ``/`` and
saves the screenshot once the page shows the cycles and the trend. Needs Chromium and
ChromeDriver (``python3 dev.py test`` installs them).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.browser import chromium  # noqa: E402
from tests.system.hmi_cell import PASSWORD, USER, SimCellWithHmi, poll, query  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles-first", type=int, default=40, help="cycles logged before the shot (default 40)")
    ap.add_argument("--out", default=str(ROOT / "docs/img/hmi.png"))
    ap.add_argument("--width", type=int, default=1400)
    ap.add_argument("--height", type=int, default=900)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hmi-shot-") as tmp:
        tmp = Path(tmp)
        with SimCellWithHmi(tmp / "cell") as cell, chromium(tmp, args.width, args.height) as driver:
            poll(lambda: query(cell.db, "SELECT COUNT(*) FROM cycles")[0][0] >= args.cycles_first, 600,
                 f"{args.cycles_first} cycles")
            driver.get(cell.url + "/login")
            driver.find_element("id", "user").send_keys(USER)
            driver.find_element("id", "password").send_keys(PASSWORD)
            driver.find_element("id", "login").click()
            poll(lambda: driver.find_elements("id", "who"), 60, "logged in")
            driver.get(cell.url + "/")
            poll(lambda: len(driver.find_elements("css selector", "#cycles tbody tr")) >= 10, 60, "the cycle table")
            poll(lambda: driver.execute_script(
                "const i = document.getElementById('trend'); return i.complete && i.naturalWidth > 0"), 60, "the trend")
            out = Path(args.out)
            out.parent.mkdir(parents=True, exist_ok=True)
            driver.save_screenshot(str(out))
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
