"""Seed 004's joint terms in the robot calibration: the calibrated robot turns its joints as
the effect vocabulary says, the file refuses terms that do not fit the robot, the backlash
widens the via margin, and a gear-ratio or cyclic term is applied only when it predicts the
held-out poses better.

Golden values: the conventions of cell/measurements.md (gear_ratio θ_true = θ_cmd·(1 + ε),
cyclic_error θ_true = θ_cmd + a·sin(2π·θ_cmd/P + φ)), worked out by hand below; the seed 000
SCARA (l1 = l2 = 500 mm, command unit 0.01°). The synthetic robot of the weighing tests is
nominal + known zeros, links, board place and a j1 ripple of 0.03° every 4.5°, noise 5 µm.
"""
import math
import re

import numpy as np
import pytest

from cell.calibration import calfile, dh
from cell.calibration import joint_terms as jt
from cell.calibration.service import load_active
from cell.compensation.lattice import margin_units
from cell.config import CellConfig, SimSection
from cell.effects.instances import make_effect
from cell.errors import CalibrationError
from cell.kinematics import Scara
from tests.cell.calibration.test_calfile import PARAMS

SEED000 = Scara.preset("seed000")


def entry(gear=(0.0, -1e-4, 1e-4), harmonics=(), applied=(), backlash=(0.02, 0.019, 0.021), sweep=(-1.1, 1.1)):
    return {"backlash_deg": dict(zip(("value", "low", "high"), backlash)),
            "gear_ratio_rel": dict(zip(("value", "low", "high"), gear)),
            "harmonics": [dict(zip(("period_deg", "amplitude_deg", "phase_deg"), h)) for h in harmonics],
            "sweep_deg": list(sweep), "applied": list(applied), "why": ""}


def doc(joints=None):
    return calfile.new_document(SEED000, "cell-1", PARAMS, {}, {}, "2026-11-26T00:00:00+00:00",
                                joints=joints)


TERMS = {"j1": entry(gear=(1e-3, 9e-4, 1.1e-3), applied=["gear_ratio"]),
         "j2": entry(harmonics=[(7.2, 0.02, -60.0)], applied=["cyclic_error"])}


def test_the_calibrated_robot_turns_its_joints_as_the_vocabulary_says(tmp_path):
    robot = calfile.calibrated_robot(SEED000, calfile.write(tmp_path / "c.json", doc(TERMS)))
    links = Scara(SEED000.g.model_copy(update={"l1_mm": 500.3, "l2_mm": 499.75}))
    t1, t2 = 60.0, 30.0
    turned = (t1 * 1.001 + 0.04, t2 - 0.05 + 0.02 * math.sin(2 * math.pi * t2 / 7.2 - math.radians(60.0)))
    assert np.allclose(robot.fk_planar(t1, t2), links.fk_planar(*turned), atol=1e-12)
    q = np.array([[60.0, 30.0], [-45.0, 120.0], [10.0, -80.0]])
    assert np.allclose(robot.fk_planar_batch(q), [robot.fk_planar(*p) for p in q], atol=1e-12)
    assert robot.backlash_deg == (0.021, 0.021)


@pytest.mark.parametrize("q", [(60.0, 30.0), (-45.0, 120.0), (10.0, -80.0)])
def test_its_inverse_and_jacobian_hold_through_the_terms(tmp_path, q):
    robot = calfile.calibrated_robot(SEED000, calfile.write(tmp_path / "c.json", doc(TERMS)))
    elbow = "right" if q[1] > 0 else "left"
    assert np.allclose(robot.ik_planar(*robot.fk_planar(*q), elbow=elbow), q, atol=1e-9)
    eps = 1e-6
    num = np.column_stack([(robot.fk_planar(q[0] + eps, q[1]) - robot.fk_planar(q[0] - eps, q[1])) / (2 * eps),
                           (robot.fk_planar(q[0], q[1] + eps) - robot.fk_planar(q[0], q[1] - eps)) / (2 * eps)])
    assert np.allclose(robot.jacobian(*q), num, atol=1e-6)


def test_terms_measured_but_not_applied_leave_the_model_as_it_was(tmp_path):
    measured = {j: {**e, "applied": []} for j, e in TERMS.items()}
    with_terms = calfile.calibrated_robot(SEED000, calfile.write(tmp_path / "a.json", doc(measured)))
    without = calfile.calibrated_robot(SEED000, calfile.write(tmp_path / "b.json", doc()))
    q = np.array([[60.0, 30.0], [-45.0, 120.0]])
    assert np.array_equal(with_terms.fk_planar_batch(q), without.fk_planar_batch(q))
    assert without.joint_effects == () and without.backlash_deg == (0.0, 0.0)
    assert with_terms.backlash_deg == (0.021, 0.021)


@pytest.mark.parametrize("joints, message", [
    ({"j5": entry()}, r"joints\.j5: not a joint seed 004 calibrates \(j1, j2, j4\)"),
    ({"j3": entry()}, r"joints\.j3: not a joint seed 004 calibrates"),
    ({"j1": entry(gear=(0.09, 0.08, 0.1))}, r"joints\.j1\.gear_ratio_rel\.value = 0\.09: outside \[-0\.05, 0\.05\]"),
    ({"j1": entry(gear=(float("nan"), 0, 1))}, r"joints\.j1\.gear_ratio_rel\.value = nan: must be a finite number"),
    ({"j2": entry(backlash=(-0.01, -0.02, 0.0))}, r"joints\.j2\.backlash_deg\.value = -0\.01: outside \[0, 2\]"),
    ({"j2": entry(backlash=(0.03, 0.019, 0.021))}, r"joints\.j2\.backlash_deg: value 0\.03 outside its interval"),
    ({"j2": entry(harmonics=[(0.0, 0.01, 0.0)])}, r"joints\.j2\.harmonics\[0\]\.period_deg = 0\.0: outside"),
    ({"j2": entry(harmonics=[(7.2, 1.5, 0.0)])}, r"joints\.j2\.harmonics\[0\]\.amplitude_deg = 1\.5: outside \[0, 1\]"),
    ({"j2": entry(applied=["friction"])}, r"joints\.j2\.applied = \['friction'\]: terms must be among"),
    ({"j2": entry(applied=["cyclic_error"])}, r"joints\.j2\.applied: cyclic_error applied but no harmonic"),
    ({"j4": entry(applied=["gear_ratio"])}, r"joints\.j4\.applied = .*: j4 does not move the tool's x, y"),
    ({"j1": entry(sweep=(1.0, -1.0))}, r"joints\.j1\.sweep_deg = \[1\.0, -1\.0\]: must be \[low, high\]"),
    ({"j1": "0.02"}, r"joints\.j1: must be a mapping"),
    ([1, 2], r"joints: must be a mapping of joint"),
])
def test_joint_terms_that_do_not_fit_the_robot_are_refused_and_nothing_moves(tmp_path, joints, message):
    """Checksummed like every file (a writer's bug, not a damaged file): the load refuses,
    naming the file and the key, and the cell does not start on it."""
    path = tmp_path / "robot.json"
    calfile.write(path, doc(joints))
    with pytest.raises(CalibrationError, match=message) as info:
        calfile.load(path, SEED000, "cell-1")
    assert str(path) in str(info.value) and "do not fit the robot 'seed000'" in str(info.value)
    cfg = CellConfig(sim=SimSection())
    cfg = cfg.model_copy(update={"calibration": cfg.calibration.model_copy(update={"file": str(path)})})
    with pytest.raises(CalibrationError, match=message):
        load_active(cfg, SEED000)


def test_the_via_margin_clears_the_measured_backlash(tmp_path):
    wide = {"j2": entry(backlash=(0.05, 0.048, 0.052))}
    robot = calfile.calibrated_robot(SEED000, calfile.write(tmp_path / "c.json", doc(wide)))
    assert margin_units(robot, 5) == math.ceil(1.5 * 0.052 / 0.01) == 8
    assert margin_units(robot, 12) == 12                 # the recipe's wider margin stands
    assert margin_units(robot, 0) == 0                   # via points off stay off
    assert margin_units(SEED000, 5) == 5                 # nothing measured: the recipe's


# ---------------------------------------------------------------- weighing
CHAIN = dh.scara_chain(SEED000.g)
TRUE = CHAIN.errors({"j1.theta": 0.05, "j2.theta": -0.04, "j1.a": 0.3, "j2.a": -0.25,
                     "base.x": 3.0, "base.y": -2.0, "base.rz": 0.1})
ROBOT_ONLY = CHAIN.errors({"j1.theta": 0.05, "j2.theta": -0.04, "j1.a": 0.3, "j2.a": -0.25})
RIPPLE = [make_effect("cyclic_error", ["j1"], {"j1_cyclic_amp_deg": 0.03, "j1_cyclic_phase_deg": 30.0,
                                               "j1_cyclic_period_deg": 4.5})]


def campaign(seed=1, n_fit=30, n_hold=12, anchors=4, truth=None):
    """Board poses (and ``anchors`` poses in the base frame) of the synthetic robot, whose
    joints turn by ``truth`` (default the j1 ripple) beyond their commands."""
    truth = RIPPLE if truth is None else truth
    rng = np.random.default_rng(seed)

    def poses(n):
        return np.column_stack([rng.uniform(-120, 120, n), rng.choice([-1.0, 1.0], n) * rng.uniform(20, 140, n),
                                np.full(n, -100.0), rng.uniform(-180, 180, n)])

    def measure(q, p):
        m = CHAIN.predict(jt.corrected(truth, q), p)[:, :2]
        return m + rng.normal(0.0, 0.005, m.shape)
    qf, qh = poses(n_fit), poses(n_hold)
    in_base = np.arange(n_fit) < anchors
    mf = np.where(in_base[:, None], measure(qf, ROBOT_ONLY), measure(qf, TRUE))
    return jt.FitData(qf, mf, in_base, qh, measure(qh, TRUE))


def ripple(phase_deg, gear=(0.0, -1e-4, 1e-4)):
    return {"j1": entry(gear=gear, harmonics=[(4.5, 0.03, phase_deg)])}


def test_a_term_that_predicts_the_held_out_poses_is_applied():
    data = campaign()
    w = jt.weigh(SEED000, data, ripple(30.0), min_gain=0.1)
    base = jt.weigh(SEED000, data, None, min_gain=0.1)
    assert w.applied == {"j1": ["cyclic_error"]} and w.why == {}
    assert base.holdout.rms_xy_after_mm > 0.2            # the ripple left in: 0.03° at ~1 m
    assert w.holdout.rms_xy_after_mm < 0.012 and w.holdout.passed
    assert abs(w.identification.value("j1.theta") - 0.05) < 0.002     # the zero does not absorb it


@pytest.mark.parametrize("phase", [210.0, -30.0])
def test_a_term_that_predicts_worse_is_kept_out_and_says_by_how_much(phase):
    data = campaign()
    w = jt.weigh(SEED000, data, ripple(phase), min_gain=0.1)
    assert w.applied == {}
    why = w.why["j1.cyclic_error"]
    assert why.startswith("held-out poses with it alone: rms ") and "(measured over ±1.1° only)" in why
    before, after = map(float, re.search(r"rms ([\d.]+) → ([\d.]+) mm", why).groups())
    assert after > before
    note = jt.annotate(ripple(phase), w)["j1"]
    assert note["applied"] == [] and "cyclic_error: held-out poses" in note["why"]


def test_only_significant_terms_are_tried():
    assert jt.candidates({"j1": entry(gear=(2e-4, -3e-4, 7e-4))}) == []
    assert jt.candidates({"j1": entry(gear=(2e-4, 1e-4, 3e-4))}) == [("j1", "gear_ratio")]
    assert jt.candidates({"j4": entry(gear=(2e-4, 1e-4, 3e-4), harmonics=[(7.2, 0.01, 0.0)])}) == []
    note = jt.annotate({"j1": entry(gear=(2e-4, -3e-4, 7e-4)), "j4": entry()},
                       jt.weigh(SEED000, campaign(), None, min_gain=0.1))
    assert "gear_ratio: its 95 % interval holds 0" in note["j1"]["why"]
    assert note["j4"]["why"].endswith("j4 does not move the tool's x, y")


# ---------------------------------------------------------------- seed 001's gear ratios
GEARS = [make_effect("gear_ratio", ["j1"], {"j1_gear_ratio_rel": 3e-4}),
         make_effect("gear_ratio", ["j2"], {"j2_gear_ratio_rel": -5e-4})]


def test_seed_001_fits_a_gear_ratio_seed_004_cannot_carry_and_applies_it():
    """Over the kinematic poses (θ1 ±120°, θ2 ±[20, 140]°) the fit sees ε·θ directly; the
    estimates hold the truths and the held-out poses come down to the noise."""
    data = campaign(seed=3, truth=GEARS)
    w = jt.weigh(SEED000, data, None, min_gain=0.1)
    g = w.gear_ratio
    assert g["applied"] == ["j1", "j2"] and g["why"] == ""
    for j, truth in (("j1", 3e-4), ("j2", -5e-4)):
        assert g[j]["low"] <= truth <= g[j]["high"] and g[j]["high"] - g[j]["low"] < 1e-4
    assert w.holdout.rms_xy_after_mm < 0.012 and w.holdout.rms_xy_before_mm > 0.2
    assert abs(w.identification.value("j1.theta") - 0.05) < 0.002       # the zero does not absorb it


def test_no_gear_ratio_is_applied_where_there_is_none():
    w = jt.weigh(SEED000, campaign(seed=4), ripple(30.0), min_gain=0.1)
    g = w.gear_ratio
    assert g["applied"] == [] and "told from 0" in g["why"]
    assert all(g[j]["low"] <= 0.0 <= g[j]["high"] for j in ("j1", "j2"))
    assert w.applied == {"j1": ["cyclic_error"]}


def test_the_calibrated_robot_applies_seed_001s_gear_ratio(tmp_path):
    gear = {"j1": {"value": 1e-3, "low": 9e-4, "high": 1.1e-3}, "j2": {"value": 0.0, "low": -1e-4, "high": 1e-4},
            "applied": ["j1"], "why": ""}
    d = {**doc(), "gear_ratio": gear}
    robot = calfile.calibrated_robot(SEED000, calfile.write(tmp_path / "c.json", d))
    links = Scara(SEED000.g.model_copy(update={"l1_mm": 500.3, "l2_mm": 499.75}))
    assert np.allclose(robot.fk_planar(60.0, 30.0), links.fk_planar(60.06 + 0.04, 30.0 - 0.05), atol=1e-12)


@pytest.mark.parametrize("gear, message", [
    ({"j3": {"value": 0.0, "low": 0.0, "high": 0.0}}, r"gear_ratio\.j3: not a joint the kinematic fit"),
    ({"j1": {"value": 0.09, "low": 0.08, "high": 0.1}}, r"gear_ratio\.j1\.value = 0\.09: outside"),
    ({"j1": {"value": 1e-4, "low": 0.0, "high": 2e-4}, "applied": ["j2"]}, r"gear_ratio\.applied = \['j2'\]"),
    ({"j1": [1, 2]}, r"gear_ratio\.j1: must be \{value, low, high\}"),
])
def test_a_gear_ratio_section_that_does_not_fit_is_refused(tmp_path, gear, message):
    path = tmp_path / "robot.json"
    calfile.write(path, {**doc(), "gear_ratio": gear})
    with pytest.raises(CalibrationError, match=message) as info:
        calfile.load(path, SEED000, "cell-1")
    assert str(path) in str(info.value)
