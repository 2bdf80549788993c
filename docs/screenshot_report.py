"""Make the README's pictures: the accuracy trend of a fresh simulated run and the
diagnosis page's first screen, as a person at a 1280 × 800 screen sees it.

    .venv/bin/python docs/screenshot_report.py [--cycles 60] [--seed 7] [--out docs/img]

Writes, into ``--out``:

- ``accuracy-trend.png``: ``cellctl run --sim --cycles N --seed S`` on a fresh log, then
  ``cellctl report --db LOG --png accuracy-trend.png`` (matplotlib, Agg);
- ``diagnosis-report.png``: ``cellctl diagnose tests/data/real/tiago-mocap-train --html``
  (real data: the PAL TIAGo campaign), screenshot of the first screen in headless
  Chromium (``tests/browser.py``: Debian's chromium and chromium-driver);
- ``diagnosis-report-sim.png``: the same for ``cellctl diagnose LOG`` on the fresh run.

Everything else goes to a temporary folder that is removed. Any folder will do: the
commands take the project's ``recipes/`` and ``deploy/`` wherever they run from.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TIAGO = ROOT / "tests" / "data" / "real" / "tiago-mocap-train"


def cellctl(*argv: str) -> None:
    from cell.cli import main
    code = main(list(argv))
    if code != 0:
        raise SystemExit(f"cellctl {' '.join(argv)}: exit {code}")


def screenshot(index: Path, png: Path, tmp: Path, width: int = 1280, height: int = 800) -> None:
    """The first screen of ``index`` at a ``width`` × ``height`` viewport, to ``png``."""
    from tests.browser import chromium
    with chromium(tmp, width=width, height=height) as driver:
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                               {"width": width, "height": height, "deviceScaleFactor": 1,
                                "mobile": False})
        driver.get(index.resolve().as_uri())
        driver.save_screenshot(str(png))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=60, help="simulated parts (default 60)")
    ap.add_argument("--seed", type=int, default=7, help="seed of the simulated run (default 7)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "img"), help="folder for the PNGs")
    args = ap.parse_args(argv)
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="cell-pictures-"))
    here = os.getcwd()
    try:
        log = tmp / "var" / "cell.sqlite"
        cellctl("run", "--sim", "--cycles", str(args.cycles), "--seed", str(args.seed),
                "--db", str(log), "--json")
        cellctl("report", "--db", str(log), "--png", str(out / "accuracy-trend.png"))
        cellctl("diagnose", str(TIAGO), "--html", str(tmp / "tiago"))
        screenshot(tmp / "tiago" / "index.html", out / "diagnosis-report.png", tmp)
        os.chdir(tmp)                    # the page names the log as given: var/cell.sqlite
        cellctl("diagnose", "var/cell.sqlite", "--html", str(tmp / "sim"))
        screenshot(tmp / "sim" / "index.html", out / "diagnosis-report-sim.png", tmp)
    finally:
        os.chdir(here)
        shutil.rmtree(tmp, ignore_errors=True)
    for name in ("accuracy-trend.png", "diagnosis-report.png", "diagnosis-report-sim.png"):
        print(f"wrote {out / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
