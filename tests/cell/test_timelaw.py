"""Seed 003 time laws: interpolation, rest at the ends, C2 at the knots, peaks, bad input, CLI."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cell import cli
from cell.commands.plan import parse_waypoints
from cell.errors import TrajectoryError
from cell.motion.timelaw import LAWS, continuity_jumps, knot_times, plan_timelaw

RNG = np.random.default_rng(3)
# six joints along a smooth path with noise, like seed 003's m×6 joint matrix (seeded)
WAYPOINTS = np.cumsum(RNG.normal(0, 8, size=(9, 6)), axis=0)
DURATION = 5.0


@pytest.fixture(params=LAWS)
def law(request):
    return request.param


def test_law_passes_through_every_waypoint_at_its_knot(law):
    for timing in ("uniform", "chord"):
        tr = plan_timelaw(WAYPOINTS, DURATION, law, timing)
        np.testing.assert_allclose(tr.pp.x, tr.knots_s)  # pieces join at the way-points
        np.testing.assert_allclose(tr(tr.knots_s), WAYPOINTS, atol=1e-9)


def test_law_starts_and_stops_at_rest(law):
    tr = plan_timelaw(WAYPOINTS, DURATION, law)
    orders = (1, 2, 3) if law == "septic-bspline" else (1, 2)
    scale = np.abs(WAYPOINTS).max()
    for nu in orders:
        np.testing.assert_allclose(tr([0.0, DURATION], nu), 0.0, atol=1e-8 * scale)


def test_laws_are_c2_at_the_knots(law):
    tr = plan_timelaw(WAYPOINTS, DURATION, law)
    jumps = continuity_jumps(tr, max_order=2)
    assert jumps.shape == (len(WAYPOINTS) - 2, 3, 6)
    peaks = tr.peaks()
    scale = np.array([np.abs(WAYPOINTS).max(), peaks.velocity.max(), peaks.acceleration.max()])
    assert np.all(np.abs(jumps).max(axis=(0, 2)) < 1e-9 * scale)


def test_one_sided_limits_agree_independently_of_continuity_jumps(law):
    # left/right limits by evaluating just either side of each knot: the difference shrinks
    # with the step for value, velocity and acceleration (no jump)
    tr = plan_timelaw(WAYPOINTS, DURATION, law)
    for h in (1e-4, 1e-6):
        for nu in (0, 1, 2):
            left, right = tr(tr.knots_s[1:-1] - h, nu), tr(tr.knots_s[1:-1] + h, nu)
            bound = 2 * h * np.abs(tr(tr.sample_times(50), nu + 1)).max() * 1.01 + 1e-9
            assert np.abs(right - left).max() <= bound


def test_jump_check_detects_the_polynomial_jerk_steps():
    # the quintic polynomial is only C2: its jerk jumps at the via points, the B-splines' does not
    poly = continuity_jumps(plan_timelaw(WAYPOINTS, DURATION, "quintic-poly"), max_order=3)
    spl = continuity_jumps(plan_timelaw(WAYPOINTS, DURATION, "quintic-bspline"), max_order=3)
    assert np.abs(poly[:, 3]).max() > 1.0
    assert np.abs(spl[:, 3]).max() < 1e-6


def test_polynomial_via_derivatives_are_finite_differences():
    t = knot_times(WAYPOINTS, DURATION, "chord")
    tr = plan_timelaw(WAYPOINTS, DURATION, "quintic-poly", "chord")
    v = np.gradient(WAYPOINTS, t, axis=0)
    np.testing.assert_allclose(tr(t[1:-1], 1), v[1:-1], atol=1e-8)
    i = 3  # second divided difference = acceleration of the parabola through points 2, 3, 4
    s0 = (WAYPOINTS[i] - WAYPOINTS[i - 1]) / (t[i] - t[i - 1])
    s1 = (WAYPOINTS[i + 1] - WAYPOINTS[i]) / (t[i + 1] - t[i])
    np.testing.assert_allclose(tr(t[i], 2), 2 * (s1 - s0) / (t[i + 1] - t[i - 1]), atol=1e-8)


@pytest.mark.parametrize("law, v_peak, a_peak", [
    # rest-to-rest over one segment (textbook closed forms, τ = t/T): both quintics are
    # 10τ³ − 15τ⁴ + 6τ⁵ (peak velocity 15/8, acceleration 10/√3), the septic is
    # 35τ⁴ − 84τ⁵ + 70τ⁶ − 20τ⁷ (peak velocity 35/16; acceleration from its closed form below)
    ("quintic-poly", 15 / 8, 10 / math.sqrt(3)),
    ("quintic-bspline", 15 / 8, 10 / math.sqrt(3)),
    ("septic-bspline", 35 / 16, None),
])
def test_two_waypoints_give_the_textbook_rest_to_rest_polynomial(law, v_peak, a_peak):
    d, T = 40.0, 2.0
    tr = plan_timelaw([[0.0], [d]], T, law)
    pk = tr.peaks(per_piece=4000)
    assert pk.velocity[0] == pytest.approx(v_peak * d / T, rel=1e-6)
    if a_peak is None:  # septic: a(τ) = 420τ² − 1680τ³ + 2100τ⁴ − 840τ⁵, maximised densely
        tau = np.linspace(0, 1, 200001)
        a_peak = np.abs(420 * tau**2 - 1680 * tau**3 + 2100 * tau**4 - 840 * tau**5).max()
    assert pk.acceleration[0] == pytest.approx(a_peak * d / T**2, rel=1e-6)


def test_peaks_are_per_joint_and_overall():
    tr = plan_timelaw(WAYPOINTS, DURATION, "quintic-bspline")
    pk = tr.peaks()
    t = np.linspace(0, DURATION, 20001)
    np.testing.assert_allclose(pk.acceleration, np.abs(tr(t, 2)).max(axis=0), rtol=1e-3)
    assert pk.overall["jerk"] == pk.jerk.max()
    assert pk.velocity.shape == (6,)


def test_chord_timing_spaces_knots_by_joint_distance():
    q = [[0, 0], [3, 4], [3, 14]]  # chords 5 and 10
    np.testing.assert_allclose(knot_times(q, 3.0, "chord"), [0.0, 1.0, 3.0])
    np.testing.assert_allclose(knot_times(q, 3.0, "uniform"), [0.0, 1.5, 3.0])


@pytest.mark.parametrize("kwargs, words", [
    (dict(waypoints=[[1.0, 2.0]]), "at least 2 way-points"),
    (dict(waypoints=[[0.0, 1.0], [2.0, float("nan")]]), "way-point 1, joint 1"),
    (dict(waypoints=[[0.0, 1.0], [2.0]]), "waypoints"),
    (dict(duration_s=0.0), "duration_s"),
    (dict(duration_s=-1.0), "duration_s"),
    (dict(duration_s=float("inf")), "duration_s"),
    (dict(law="cubic"), "law"),
    (dict(timing="arc"), "timing"),
    (dict(waypoints=[[0.0], [1.0], [1.0], [2.0]], timing="chord"), "way-points 1 and 2 coincide"),
])
def test_bad_input_is_rejected(kwargs, words):
    args = dict(waypoints=WAYPOINTS[:4], duration_s=2.0, law="quintic-bspline", timing="uniform")
    args.update(kwargs)
    with pytest.raises(TrajectoryError, match=words):
        plan_timelaw(**args)


def test_evaluation_outside_the_move_is_rejected():
    tr = plan_timelaw(WAYPOINTS, DURATION, "septic-bspline")
    with pytest.raises(TrajectoryError, match="times must lie"):
        tr(DURATION + 0.1)


def test_a_dwell_is_allowed_with_uniform_timing():
    tr = plan_timelaw([[0.0], [1.0], [1.0], [2.0]], 3.0, "quintic-bspline")
    np.testing.assert_allclose(tr(tr.knots_s)[:, 0], [0, 1, 1, 2], atol=1e-12)


# --------------------------------------------------------------------------- CLI
def test_parse_waypoints():
    np.testing.assert_allclose(parse_waypoints("0,0; 10,5;30,20;"), [[0, 0], [10, 5], [30, 20]])


@pytest.mark.parametrize("text, words", [("0,0;;1,1", "way-point 1 is empty"),
                                         ("0,0;1,a", "way-point 1 '1,a' is not"),
                                         ("0,0;1,1,1", "has 3 joints")])
def test_parse_waypoints_rejects_malformed_text(text, words):
    with pytest.raises(TrajectoryError, match=words):
        parse_waypoints(text)


TL = ["plan", "timelaw", "--waypoints", "0,0;10,5;30,20;45,40", "--duration-s", "4"]


def test_cli_timelaw_table(capsys):
    assert cli.main(TL) == 0
    out = capsys.readouterr().out
    for law in LAWS:
        assert f"{law:<16}   all" in out


def test_cli_timelaw_json_and_plot(capsys, tmp_path):
    png = tmp_path / "laws.png"
    assert cli.main(TL + ["--law", "septic-bspline", "--timing", "chord", "--json", "--plot", str(png)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert list(doc["laws"]) == ["septic-bspline"]
    assert len(doc["laws"]["septic-bspline"]["peak_jerk"]) == 2
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("argv, words", [
    (["plan", "timelaw", "--waypoints", "0,0;1;2,2", "--duration-s", "4"], "way-point 1"),
    (["plan", "timelaw", "--waypoints", "0,0", "--duration-s", "4"], "at least 2"),
    (TL[:-1] + ["0"], "duration_s"),
    (TL + ["--samples", "1"], "--samples"),
])
def test_cli_timelaw_bad_input_exits_2(capsys, argv, words):
    assert cli.main(argv) == 2
    assert words in capsys.readouterr().err


def test_cli_timelaw_unwritable_plot_exits_2(capsys, tmp_path):
    assert cli.main(TL + ["--plot", str(tmp_path / "missing" / "x.png")]) == 2
    assert "--plot" in capsys.readouterr().err


def test_cellctl_parser_does_not_import_scipy():
    """Issue 11: every cellctl call paid ~0.8 s CPU for scipy, imported only to list the
    time laws as choices."""
    import subprocess
    import sys
    code = ("import sys, cell.cli; cell.cli.build_parser(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'cv2', 'matplotlib')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
