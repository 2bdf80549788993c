"""The motor-side cyclic error (cell/effects/motor_cyclic_error.py), the effect added by the
recipe of docs/adding-an-effect.md: its convention against the format document, its
derivative against finite differences, what makes it identifiable, and the diagnosis
recovering it from a campaign the independent truth (cell/truth) measured.

Golden values: the format's convention θ_true = θ_cmd + a·sin(2π·N·θ_cmd/360° + φ), with
N = 50 (its default), evaluated here with math on single angles.
"""
import math

import numpy as np
import pytest

from cell import effects as fx
from cell.diagnosis import jacobian
from cell.diagnosis.answer import diagnose_campaign
from cell.diagnosis.replay import prepare
from cell.effects.base import phase_coverage
from cell.measurements import read_campaign
from cell.sim.campaigns import Design, make_campaign
from cell.truth import campaign as truth_campaign
from cell.truth import parts

EFF = fx.EFFECTS["motor_cyclic_error"]


def inst(a=0.03, phase=40.0, joints=("j2",)):
    return fx.make_effect("motor_cyclic_error", joints,
                          {f"{j}_motor_cyclic_{k}": v for j in joints
                           for k, v in (("amp_deg", a), ("phase_deg", phase))})


def test_convention_phase_at_command_zero_and_fifty_periods_per_turn():
    cmd = np.array([[0.0, 0.0], [0.0, 1.8], [10.0, 7.2], [0.0, 36.0]])
    q = fx.true_joints([inst()], cmd, np.ones_like(cmd))
    want = [c + 0.03 * math.sin(math.radians(50 * c + 40.0)) for c in cmd[:, 1]]
    assert np.allclose(q[:, 1], want, atol=1e-12)
    assert np.array_equal(q[:, 0], cmd[:, 0])
    assert q[2, 1] - 7.2 == pytest.approx(q[0, 1], abs=1e-12)   # one period = 360°/50 = 7.2°
    assert EFF.spec_of("j1_motor_gear_ratio").default == 50.0 and not \
        EFF.spec_of("j1_motor_gear_ratio").fitted


def test_derivative_matches_finite_differences():
    d = prepare(make_campaign([], 5, Design(n_points=40, n_moves=2)))
    rows = jacobian.rows_of(d)
    effs = [inst(0.02, 70.0, ("j1", "j2")),
            fx.make_effect("gear_ratio", ("j2",), {"j2_gear_ratio_rel": 1e-3})]
    x0, names = fx.stack_vectors(effs)
    _, J = jacobian.evaluate(rows, effs, None, jac=True)
    for i, name in enumerate(names):
        h = 1e-6 * max(1.0, abs(x0[i]))
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        fd = (jacobian.evaluate(rows, fx.split_vector(effs, xp))[0]
              - jacobian.evaluate(rows, fx.split_vector(effs, xm))[0]) / (2 * h)
        assert np.abs(fd - J[:, :, i]).max() < 1e-6 * np.abs(fd).max(), name
    _, Jl = jacobian.evaluate(rows, effs[:1], None, jac=True, lags_ms=np.array([1.5, 2.5]))
    fdl = (jacobian.evaluate(rows, effs[:1], None, lags_ms=np.array([1.5 + 1e-6, 2.5]))[0]
           - jacobian.evaluate(rows, effs[:1], None, lags_ms=np.array([1.5 - 1e-6, 2.5]))[0]) / 2e-6
    assert np.abs(fdl - Jl[:, :, -2]).max() < 1e-5 * max(np.abs(fdl).max(), 1e-9)


def coverage(angles_j1) -> str:
    """What the chain diagnosis's rule (``OnChain.coverage``: :func:`phase_coverage` at the
    joint's motor gear ratio) says of j1 at these angles, all at one place."""
    return phase_coverage(np.asarray(angles_j1, float), EFF.params[2].default, None, "j1")


def test_identifiable_only_when_the_angles_sample_the_short_period():
    rng = np.random.default_rng(0)
    assert coverage(rng.uniform(-90, 90, 60)) == ""
    # a stepped sweep (seed 004) with a whole or a half period as step: one or two phases
    for step in (7.2, 3.6, 36.0):
        assert "sample the 7.2° period too sparsely" in coverage(np.arange(60) * step), step
    assert coverage(np.full(60, 10.0)).startswith("j1's angles")
    assert coverage(np.arange(60) * 2.5) == ""                  # 2.5° steps: dense
    assert coverage([1.0, 2.0]) == "j1 has 2 fit rows: a period of 7.2° needs 3"
    assert EFF.mimics == () and EFF.remedy.kind == "calibrate_joint"
    assert EFF.chain.joints == "geared" and EFF.chain.coverage is not None   # chains: N stated


def test_the_diagnosis_recovers_it_from_the_independent_truth(tmp_path):
    """Campaign measured on cell/truth's model, written as files, read back, diagnosed."""
    part = parts.Part("motor_cyclic_error", 2, {"cycles": 50, "cos_deg": 0.02, "sin_deg": -0.025})
    d = truth_campaign.write_campaign(tmp_path / "c", [part], 11,
                                      truth_campaign.Design(n_points=150))
    rep = diagnose_campaign(read_campaign(d)).report
    cause = rep["cause"]
    assert (cause["effect"], cause["joints"]) == ("motor_cyclic_error", ["j2"]), cause
    want = parts.answer(part).params
    for p in ("j2_motor_cyclic_amp_deg", "j2_motor_cyclic_phase_deg"):
        lo, hi = cause["ci95"][p]
        half = (hi - lo) / 2 * 3.2905 / 1.96          # the 95 % interval widened to 99.9 %
        assert abs((want[p] - (lo + hi) / 2 + 180.0) % 360.0 - 180.0) <= half, (p, want[p], lo, hi)
    assert cause["confidence"] == "high" and rep["unexplained"] is False
    assert rep["holdout"]["shrink"] > 0.6
