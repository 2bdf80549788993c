"""The independent forward model (cell/truth) against cell/effects/: the two must agree to
1e-9 mm for every vocabulary effect, on both joints, every cyclic order, alone and all
together, on static points and on paths (comm delay, reversals, station orders). Golden
values from seed 000 and the definitions of the four effects outside the vocabulary."""
import ast
import math
from pathlib import Path

import numpy as np
import pytest

from cell import effects as fx
from cell.robots import Geometry
from cell.measurements import read_campaign
from cell.truth import campaign, model, parts
from cell.truth.campaign import Design

TOL_MM = 1e-9
GEOM = Geometry(name="agreement", l1_mm=325.0, l2_mm=275.0)
STATIONS = ("j2", "j4", "j1", "j3")         # j1 is station 3, j2 station 1
CELL = model.Cell(GEOM.l1_mm, GEOM.l2_mm, (210.0, -140.0), STATIONS)


def _instances(ps):
    return [fx.make_effect(a.effect, a.joints, a.params) for a in map(parts.answer, ps)]


def _points(seed, n=400):
    rng = np.random.default_rng(seed)
    cmd = np.column_stack([rng.uniform(-170, 170, n), rng.uniform(-150, 150, n)])
    dirs = rng.choice((-1.0, 0.0, 1.0), (n, 2))
    return cmd, dirs, np.sort(rng.uniform(0, 3600, n)), rng.uniform(5.0, 45.0, n)


def _path(seed, n=300):
    """A wavy move with reversals on both joints and uneven sampling."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5e-3, 4e-3, n))
    t -= t[0]
    cmd = np.column_stack([rng.uniform(-90, 90) + 40 * np.sin(7 * t + rng.uniform(0, 6)),
                           rng.uniform(-90, 90) + 30 * np.sin(11 * t + rng.uniform(0, 6))])
    cmd[40:60, 0] = cmd[40, 0]                 # joint 1 at rest for a while
    return cmd, t, rng.uniform(15.0, 35.0, n), rng.choice((-1.0, 0.0, 1.0), 2)


def _agree_points(ps, seed):
    cmd, dirs, t, temp = _points(seed)
    ours = model.measure_points(CELL, parts.compose(ps), cmd, dirs, t, temp)
    theirs = fx.simulate_points(GEOM, _instances(ps), cmd, dirs, t, temp, CELL.camera_center_mm)
    return float(np.max(np.abs(ours - theirs))), float(np.max(np.abs(ours - fx.simulate_points(
        GEOM, [], cmd, dirs, t, temp, CELL.camera_center_mm))))


def _agree_path(ps, seed):
    cmd, t, temp, d0 = _path(seed)
    ours = model.measure_path(CELL, parts.compose(ps), cmd, t, t, temp, d0)
    theirs = fx.simulate_path(GEOM, _instances(ps), cmd, t, temp, CELL.camera_center_mm,
                              STATIONS, d0)
    nominal = fx.simulate_path(GEOM, [], cmd, t, temp, CELL.camera_center_mm, STATIONS, d0)
    return float(np.max(np.abs(ours - theirs))), float(np.max(np.abs(ours - nominal)))


CASES = [(k, j) for k in parts.VOCABULARY for j in (parts.KINDS[k].joints or (None,))]


@pytest.mark.parametrize("kind,joint", CASES, ids=[f"{k}-j{j}" for k, j in CASES])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_each_vocabulary_effect_agrees_with_effects_py(kind, joint, seed):
    p = parts.draw(np.random.default_rng([seed, CASES.index((kind, joint))]), kind, joint)
    gap, size = _agree_points([p], seed)
    assert gap < TOL_MM, (p, gap)
    if kind != "comm_delay":                   # comm_delay leaves static points alone
        assert size > 1e-3                     # the effect did move the points
    gap, size = _agree_path([p], seed)
    assert gap < TOL_MM, (p, gap)
    assert size > 1e-4


@pytest.mark.parametrize("cycles", parts.CYCLIC_ORDERS)
@pytest.mark.parametrize("joint", [1, 2])
def test_cyclic_error_of_every_order_agrees(cycles, joint):
    rng = np.random.default_rng(10 * cycles + joint)
    for _ in range(5):
        p = parts.draw(rng, "cyclic_error", joint)
        p = parts.Part(p.kind, p.joint, {**p.values, "cycles": cycles})
        assert _agree_points([p], cycles)[0] < TOL_MM
        assert _agree_path([p], cycles)[0] < TOL_MM


def test_every_effect_at_once_agrees():
    """The composition order: all nine effects (per-joint ones on both joints) together,
    five times the typical sizes (inside every bound) so a wrong order of terms would not
    hide under 1e-9 mm."""
    rng = np.random.default_rng(77)
    ps = [parts.scaled(parts.draw(rng, k, j), 5.0) for k, j in CASES]
    gap, size = _agree_points(ps, 5)
    assert gap < TOL_MM and size > 1.0
    gap, size = _agree_path(ps, 6)
    assert gap < TOL_MM and size > 1.0


def test_the_model_imports_nothing_from_the_project():
    """The per-point model is plain ``math``; every module of cell/truth is held apart from
    the fitter by tests/cell/test_truth_independence.py."""
    tree = ast.parse(Path(model.__file__).read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not {m for m in names if m and m.startswith("cell")}, names


# ------------------------------------------------------------------ first principles
def test_seed_000_start_pose():
    # seed 000: l1 = l2 = 500 mm, (60°, 30°) -> (250.0000, 933.0127) (Table 1, group c)
    cell = model.Cell(500.0, 500.0, (0.0, 0.0))
    xy = model.measure_points(cell, model.Truth(), [[60.0, 30.0]], [[0, 0]], [0.0], [20.0])
    assert xy[0] == pytest.approx([250.0, 933.0127], abs=5e-5)


def test_answers_in_vocabulary_units():
    a = parts.answer(parts.Part("gear_ratio", 2, {"teeth_excess": 1e-3}))
    assert (a.effect, a.joints) == ("gear_ratio", ("j2",))
    assert a.params["j2_gear_ratio_rel"] == pytest.approx(1 / 1.001 - 1, rel=1e-12)
    a = parts.answer(parts.Part("cyclic_error", 1, {"cycles": 3, "cos_deg": 0.03, "sin_deg": 0.0}))
    assert a.params == pytest.approx({"j1_cyclic_amp_deg": 0.03, "j1_cyclic_phase_deg": 90.0,
                                      "j1_cyclic_period_deg": 120.0})
    a = parts.answer(parts.Part("comm_delay", None, {"frame_delay_s": 2e-3}))
    assert a.params == {"comm_delay_sigma_ms": 2.0} and a.joints == ()
    assert all(parts.answer(parts.draw(np.random.default_rng(0), k)) is None for k in parts.OUTSIDE)


def _one(truth, q, cell=CELL, clock=0.0):
    return model.measure_points(cell, truth, [q], [[1, 1]], [clock], [20.0])[0]


def test_radial_distortion_moves_points_radially_by_k_d_cubed():
    k = 4e-10
    for q in ([30.0, 60.0], [-100.0, 45.0], [150.0, -120.0]):
        p0, p1 = _one(model.Truth(), q), _one(model.Truth(lens_k_per_mm2=k), q)
        d0 = p0 - CELL.camera_center_mm
        r = math.hypot(*d0)
        assert np.allclose(p1 - p0, d0 / r * k * r ** 3, atol=1e-12)


def test_sag_droops_in_minus_y_with_reach_squared():
    truth = model.Truth(sag_mm_at_1m=0.4)
    for q in ([0.0, 60.0], [90.0, 20.0]):
        p0, p1 = _one(model.Truth(), q), _one(truth, q)
        r = math.hypot(*p0)          # camera centre only shifts; the sag is in the base frame
        assert p1 - p0 == pytest.approx([0.0, -0.4 * (r / 1000) ** 2], abs=1e-12)


def test_bump_moves_a_joint_zero_from_its_time_on():
    truth = model.Truth(bump=model.Bump(joint=1, step_deg=0.1, at_s=100.0))
    q = [20.0, 70.0]
    assert np.array_equal(_one(truth, q, clock=99.9), _one(model.Truth(), q))
    assert np.allclose(_one(truth, q, clock=100.0), _one(model.Truth(zero_deg=(0.1, 0.0)), q),
                       atol=1e-12)


def test_coupling_adds_kappa_theta1_to_joint_2():
    q = [120.0, 40.0]
    got = _one(model.Truth(coupling_21=1e-3), q)
    assert np.allclose(got, _one(model.Truth(), [120.0, 40.0 + 0.12]), atol=1e-12)


def test_rows_are_shared_and_noise_is_optional():
    d = Design(n_points=40, n_moves=2)
    rows = campaign.draw_rows(5, d)
    p = parts.Part("joint_offset", 1, {"zero_deg": 0.1})
    a = campaign.make_campaign([p], 5, d)
    b = campaign.make_campaign([p], 5, d, rows=rows)
    assert np.array_equal(a.points["x_mm"], b.points["x_mm"])
    clean, _ = campaign.measured([p], rows, d, noise=False)
    noisy = np.column_stack([a.points["x_mm"], a.points["y_mm"]])
    assert 0 < np.std(noisy - clean) < 0.05          # repeatability 0.01 + camera 0.005 mm
    assert campaign.rms_displacement([], rows, d) == 0.0
    assert campaign.bump_time(rows) == pytest.approx((rows.t[0] + rows.t[-1]) / 2)


# ------------------------------------------------------------------ files and layouts
def test_written_files_read_back_as_the_tables(tmp_path):
    """The truth's own writer against the project's reader: every column the design asks
    for, the same values, optional columns left out when the design says so."""
    p = [parts.Part("joint_offset", 2, {"zero_deg": 0.05})]
    for d in (Design(n_points=40, n_moves=2),
              Design(n_points=40, n_moves=2, places=4, directions=False, temperature=False,
                     split_column=False, outliers=2)):
        c = read_campaign(campaign.write_campaign(tmp_path / f"c{d.places}", p, 9, d))
        mem = campaign.make_campaign(p, 9, d)
        assert set(c.points) == set(mem.points) and set(c.paths) == set(mem.paths)
        for k in mem.points:
            assert np.array_equal(c.points[k], mem.points[k]), k
        for k in mem.paths:
            assert np.array_equal(c.paths[k], mem.paths[k]), k
        assert ("j1_dir" in c.points) == d.directions and ("temp_c" in c.points) == d.temperature
        assert ("split" in c.points) == d.split_column
        assert (c.model.l1_mm, c.model.l2_mm, c.model.command_unit_deg) == (500.0, 500.0, 0.01)
        assert tuple(c.model.camera.center_mm) == d.camera_center_mm


def test_clustered_layout_visits_its_stations_with_sequence_directions():
    d = Design(n_points=120, n_moves=3, places=5, place_jitter_deg=1.0, outliers=3)
    rows = campaign.draw_rows(4, d)
    assert sorted(set(rows.place.tolist())) == [0, 1, 2, 3, 4]
    for k in range(5):
        q = rows.q[rows.place == k]
        assert np.ptp(q, axis=0).max() <= 2.0 + 1e-9          # ±1° around the station
    step = np.diff(rows.q, axis=0)
    moved = step != 0
    assert np.array_equal(rows.dirs[1:][moved], np.sign(step[moved]))
    assert (np.hypot(*rows.outlier.T) > 0).sum() == 3
    assert np.all(np.abs(rows.q / 0.01 - np.round(rows.q / 0.01)) < 1e-6)   # whole units


def test_moves_start_at_rest_and_take_the_first_motion_as_approach():
    """The format's convention for paths without directions: each joint approached the
    start in the direction of its own first commanded motion; the recording starts before
    the motion (pre_s), so the approach direction is what the first samples show."""
    d = Design(n_points=10, n_moves=4)
    for mv in campaign.draw_rows(2, d).moves:
        pre = int(round(d.pre_s / d.path_dt_s))
        assert np.all(mv.q[:pre + 1] == mv.q[0])
        first = mv.q[pre + 1] - mv.q[0]
        assert np.array_equal(mv.dirs0, np.sign(first))
    assert campaign.approach_dirs(np.array([[0.0, 5.0], [0.0, 4.0], [1.0, 4.5]])).tolist() == [1.0, -1.0]
    assert campaign.approach_dirs(np.zeros((3, 2))).tolist() == [0.0, 0.0]


def test_backlash_at_a_move_start_follows_the_approach_direction():
    """With the approach taken as the first motion, a joint with play sits at −dir·b/2
    from the first sample on: the measured start differs from the nominal start by the
    play's half, in the direction opposite the motion (cell/measurements.md, backlash)."""
    d = Design(n_points=10, n_moves=1)
    rows = campaign.draw_rows(6, d)
    mv = rows.moves[0]
    b = 0.2
    _, (with_play,) = campaign.measured([parts.Part("backlash", 1, {"play_deg": b})], rows, d, False)
    cell = campaign.nominal_cell(d)
    want = model.camera_sees(cell, model.Truth(), *model.tool_xy(
        500.0, 500.0, mv.q[0, 0] - mv.dirs0[0] * b / 2, mv.q[0, 1]))
    assert with_play[0] == pytest.approx(want, abs=1e-9)
