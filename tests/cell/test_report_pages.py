"""The diagnosis page (``cellctl diagnose --html``) in a real headless Chromium, for a planar
campaign and for the TIAGo chain campaign: no sideways overflow at 1280 and 1024 px, the
cause, the holdout shrink and the action on the first screen at 1280 × 800, plots loaded,
the ranking a table; and the page's escaping, without a browser."""
import json
import math
from pathlib import Path

import pytest

from cell import effects as fx
from cell.cli import main
from cell.diagnosis import page
from cell.sim.campaigns import Design, make_campaign
from cell.robots import PRESETS
from cell.measurements import write_campaign
from tests.browser import chromium

TIAGO = Path(__file__).resolve().parents[1] / "data" / "real" / "tiago-mocap-train"


BACKLASH_DEG = 0.04             #: the planar campaign's truth: backlash of j2
PLANAR = Design(n_points=100, n_moves=3)


def planar_holdout_by_hand(n_points: int, n_paths: int) -> tuple[float, float]:
    """The planar campaign's holdout rms (2-D, mm) before and after the fit, by hand.

    Before: backlash b on j2 puts θ2 off by b/2 one way or the other at every sample, so the
    tool is off by (b/2 in rad)·l2 everywhere: 0.02° of 500 mm = 0.1745 mm, plus the noise.
    After: the noise alone. Static points carry the arm's repeatability and the camera's
    noise, σ per axis each (2-D: √2·σ); path samples only the camera's (Design's defaults)."""
    d, l2 = PLANAR, PRESETS[PLANAR.robot].l2_mm                 # seed 000: l1 = l2 = 500 mm
    points_var = 2 * (d.repeatability_mm ** 2 + d.measurement_noise_mm ** 2)
    paths_var = 2 * d.measurement_noise_mm ** 2
    noise_var = (n_points * points_var + n_paths * paths_var) / (n_points + n_paths)
    lost = math.radians(BACKLASH_DEG / 2) * l2
    return math.sqrt(lost ** 2 + noise_var), math.sqrt(noise_var)


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    """{kind: index.html} written by the command for a planar and a chain campaign."""
    root = tmp_path_factory.mktemp("pages")
    truth = fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": BACKLASH_DEG})
    camp = write_campaign(make_campaign([truth], 21, PLANAR), root / "camp")
    out = {}
    for kind, src in (("planar", camp), ("chain", TIAGO)):
        assert main(["diagnose", str(src), "--html", str(root / kind)]) == 0
        out[kind] = root / kind / "index.html"
    return out


def _viewport(driver, width: int, height: int) -> None:
    """The page's viewport exactly ``width`` × ``height`` CSS px (the window has chrome)."""
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                           {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})


GEOMETRY = """
const r = id => document.getElementById(id).getBoundingClientRect();
const imgs = [...document.images];
return {scrollW: document.documentElement.scrollWidth, clientW: document.documentElement.clientWidth,
        innerH: window.innerHeight, innerW: window.innerWidth,
        cause: r('cause').bottom, shrink: r('shrink').bottom, action: r('action').bottom,
        wide: [...document.querySelectorAll('body *')].filter(e => {
                 const b = e.getBoundingClientRect();
                 return b.width > 0 && b.right > document.documentElement.clientWidth + 0.5
                        && !e.closest('.scroll');}).map(e => e.tagName),
        images: imgs.length, broken: imgs.filter(i => !i.complete || i.naturalWidth === 0).length,
        rankingRows: document.querySelectorAll('table#ranking tbody tr').length,
        visiblePre: [...document.querySelectorAll('pre')].filter(p => !p.closest('details:not([open])')).length,
        actionText: document.getElementById('action').innerText,
        shrinkText: document.getElementById('shrink').innerText,
        causeText: document.getElementById('cause').innerText};
"""


@pytest.mark.parametrize("kind", ["planar", "chain"])
def test_page_answers_on_the_first_screen_without_sideways_overflow(pages, kind, tmp_path):
    with chromium(tmp_path) as driver:
        for width in (1280, 1024):
            _viewport(driver, width, 800)
            driver.get(pages[kind].as_uri())
            g = driver.execute_script(GEOMETRY)
            assert g["innerW"] == width and g["innerH"] == 800
            assert g["scrollW"] <= g["clientW"], (width, g["wide"])
            assert g["wide"] == []
            if width == 1280:
                assert max(g["cause"], g["shrink"], g["action"]) <= g["innerH"], g
                shot = tmp_path / f"{kind}.png"
                assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 20_000
        assert g["images"] == 3 + (kind == "planar") and g["broken"] == 0   # planar: its moves
        assert 3 <= g["rankingRows"] <= page.TABLE_ROWS + 1 and g["visiblePre"] == 0
        assert "HOLDOUT rms" in g["shrinkText"] and "FIT rms" in g["shrinkText"]
    # the first screen shows the report's own holdout figures (report.json beside the page)
    held = json.loads((pages[kind].parent / "report.json").read_text())["holdout"]
    before, after = held["rms_before_mm"], held["rms_after_mm"]
    assert f"HOLDOUT rms {before:.4f} → {after:.4f} mm" in g["shrinkText"], g["shrinkText"]
    assert f"shrink {round(100 * (1 - after / before))} %" in g["shrinkText"], g["shrinkText"]
    if kind == "planar":
        assert "backlash on j2" in g["causeText"] and "confidence high" in g["causeText"]
        assert "cellctl calibrate joint j2" in g["actionText"]
        # and those figures are what the campaign holds, by hand (see PLANAR_HOLDOUT)
        want_before, want_after = planar_holdout_by_hand(held["points"]["n"], held["paths"]["n"])
        assert before == pytest.approx(want_before, rel=0.05)
        assert after == pytest.approx(want_after, rel=0.25)
    else:
        assert "Unexplained" in g["causeText"] and "link_length" in g["causeText"]
        assert g["actionText"].startswith("WHAT TO DO\nInvestigate") or "Investigate" in g["actionText"]
        # the data's README: registration alone leaves 4.09 mm rms over all 37 postures; the
        # 11 held out are a sample of them
        assert before == pytest.approx(4.09, rel=0.15)


def test_chain_page_files_and_unchanged_json(pages, capsys):
    out = pages["chain"].parent
    for png in ("poses.png", "residuals.png", "joints.png"):
        assert (out / png).stat().st_size > 5000
    assert main(["diagnose", str(TIAGO), "--json"]) == 0
    assert json.loads((out / "report.json").read_text()) == json.loads(capsys.readouterr().out)


def test_every_report_text_is_escaped():
    rep = {"format": "cell-diagnosis/1", "source": "<script>alert(1)</script>", "unexplained": False,
           "gap": {"rms_mm": 1.0, "where": {"summary": "a < b & c"}},
           "cause": {"effect": "joint_offset", "joints": ["<j1>"], "subsystem": "kinematics",
                     "params": {"<pp>": 1.0}, "ci95": {"<pp>": [0.5, 1.5]},
                     "test": {"p_value": 0.001, "alpha": 0.01}, "confidence": "high"},
           "holdout": {"n": 3, "rms_before_mm": 1.0, "rms_after_mm": 0.5, "shrink": 0.5},
           "registration": {"rms_mm": 1.0, "condition": 2.0},
           "ranking": [{"label": "<b>x</b>", "joints": ["<i>y</i>"], "k": 1, "cv_rms_mm": 0.6,
                        "fit_rms_mm": 0.5, "holdout_rms_mm": 0.5, "condition": 2.0}],
           "remainder": {"reasons": [], "notes": ["<u>n</u>"]}, "not_identifiable": {"<k>": "<v>"},
           "noise": {"sigma_mm": None}}
    text = page.render(rep, [page.Figure("a.png", "<t>", "<c>")], page.FitRms(1.0, 0.5, "3 rows"),
                       "<pre-text>")
    for raw in ("<script>", "<j1>", "<pp>", "<b>x", "<i>y", "<u>n", "<k>", "<v>", "<t>", "<c>",
                "<pre-text>", "a < b"):
        assert raw not in text
    assert "&lt;script&gt;" in text and "a &lt; b &amp; c" in text


def test_chain_page_for_a_campaign_with_no_cause(tmp_path):
    """No cause: the plots draw 'after' as registration only; the action is no action."""
    from tests.cell.chain import chainsim
    camp = chainsim.make(tmp_path / "c", {}, seed=4)
    assert main(["diagnose", str(camp), "--noise-mm", "0.03", "--html", str(tmp_path / "p")]) == 0
    text = (tmp_path / "p" / "index.html").read_text()
    assert 'data-kind="none"' in text and "No action: the gap is within noise." in text
    assert "None: within noise" in text and "class=chosen" not in text
