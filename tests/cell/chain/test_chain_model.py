"""Chain models: forward kinematics against closed forms and the independent per-pose
model, exact Jacobians against finite differences, identifiability."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cell.diagnosis.chain import fit as F
import cell.kinematics as kin
from cell.kinematics.chain import dh_chain, matrix_rpy, rpy_matrix
from cell.measurements import read_campaign
from cell.truth import chain as truth
from tests.cell.chain import chainsim

TIAGO = Path(__file__).resolve().parents[2] / "data" / "real" / "tiago-mocap-train"  # copy of shared/data/real


def _planar(convention):
    # seed 000 eq. 4: x = l1 cos q1 + l2 cos(q1 + q2), l1 = 325, l2 = 275 mm
    if convention == "standard":
        rows = [{"name": "j1", "type": "revolute", "a_mm": 325.0, "alpha_deg": 0.0, "d_mm": 0.0, "theta_deg": 0.0},
                {"name": "j2", "type": "revolute", "a_mm": 275.0, "alpha_deg": 0.0, "d_mm": 0.0, "theta_deg": 0.0}]
        tool = (0.0, 0.0, 0.0)
    else:
        rows = [{"name": "j1", "type": "revolute", "a_mm": 0.0, "alpha_deg": 0.0, "d_mm": 0.0, "theta_deg": 0.0},
                {"name": "j2", "type": "revolute", "a_mm": 325.0, "alpha_deg": 0.0, "d_mm": 0.0, "theta_deg": 0.0}]
        tool = (275.0, 0.0, 0.0)
    return dh_chain(Path("m.yaml"), rows, convention, [], tool, (0, 0, -1)), tool


@pytest.mark.parametrize("convention", ["standard", "modified"])
def test_planar_dh_chain_matches_the_scara_closed_form(convention):
    chain, tool = _planar(convention)
    q = np.array([[10.0, 20.0], [-75.0, 130.0], [0.0, 0.0]])
    tips, _ = kin.forward(chain, q)
    x = kin.points(tips, np.arange(3), np.tile(tool, (3, 1)))
    a, b = np.radians(q[:, 0]), np.radians(q[:, 0] + q[:, 1])
    assert np.allclose(x[:, 0], 325 * np.cos(a) + 275 * np.cos(b), atol=1e-9)
    assert np.allclose(x[:, 1], 325 * np.sin(a) + 275 * np.sin(b), atol=1e-9)


@pytest.mark.parametrize("modified", [False, True])
def test_chain_model_agrees_with_the_independent_forward_model(tmp_path, modified):
    eff = {"offset": {"j2": 0.3, "j5": -0.2}, "a": {"j3": 1.5}, "d": {"j4": -0.7},
           "alpha": {"j2": 0.05}, "ratio": {"j3": 0.002}, "sag": {"j2": 0.4, "j3": 0.2}}
    rows = chainsim.UR5
    d = chainsim.make(tmp_path / "c", None, poses=8, noise_mm=0.0, sensor=False, modified=modified,
                      model_extra={"motor_gear_ratio": {"j5": 80.0}})
    cc = read_campaign(d)
    voc = {p.name: p for p in F.vocabulary(cc.chain)}
    names = {"offset": "{j}_offset_deg", "a": "{j}_a_mm", "d": "{j}_d_mm", "alpha": "{j}_alpha_deg",
             "ratio": "{j}_gear_ratio_rel", "sag": "{j}_compliance_deg_per_m"}
    params, values = [], []
    for kind, per in eff.items():
        for j, v in per.items():
            params.append(voc[names[kind].format(j=j)])
            values.append(v)
    # a ripple a·sin(3q + φ) on j4 is the coefficients a·cos φ, a·sin φ of order 3 (format)
    eff["cyclic"] = {"j4": (0.05, 3, 40.0)}
    params += [voc["j4_cyclic3_sin_deg"], voc["j4_cyclic3_cos_deg"]]
    values += [0.05 * math.cos(math.radians(40.0)), 0.05 * math.sin(math.radians(40.0))]
    # a motor-side ripple a·sin(N·q + φ) on j5, N = 80 as model.yaml states: likewise
    eff["motor"] = {"j5": (0.03, 80.0, -120.0)}
    params += [voc["j5_motor_cyclic_sin_deg"], voc["j5_motor_cyclic_cos_deg"]]
    values += [0.03 * math.cos(math.radians(-120.0)), 0.03 * math.sin(math.radians(-120.0))]
    assert not any("motor" in n for n in voc if not n.startswith("j5_"))   # N stated for j5 only
    data = F.Data.of(cc)
    reg = F.Registration(np.eye(3), np.zeros(3), np.array(chainsim.MARKERS))
    got, _ = F.model(data, reg, params, np.array(values))
    want = np.vstack([truth.tool_points(rows, q, modified, (0, 0, 0), chainsim.MARKERS, eff, p, 8)
                      for p, q in enumerate(cc.readings)])
    assert np.max(np.abs(got - want)) < 1e-9


def test_every_jacobian_column_matches_finite_differences(tmp_path):
    # every parameter of the vocabulary at once, the sensor's scale and rotation about a
    # centre among them: each column is taken through the others' maps
    d = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.1}}, poses=6, sensor=True, temps=True,
                      model_extra={"sensor_center_mm": [120.0, -80.0, 400.0],
                                   "motor_gear_ratio": {"j2": 50.0, "j3": 101.0}})
    cc = read_campaign(d)
    data = F.Data.of(cc)
    params = F.vocabulary(cc.chain)
    assert {p.name for p in params if p.sensor} == {"camera_scale_rel", "camera_rotation_deg"}
    assert {p.name for p in params if p.effect == "motor_cyclic_error"} == {
        f"j{k}_motor_cyclic_{f}_deg" for k in (2, 3) for f in ("sin", "cos")}
    v0 = np.linspace(-0.01, 0.01, len(params))
    reg = F.initial_registration(data)
    y0, J = F.model(data, reg, params, v0, jac=True)
    nr = F.n_registration(data)
    h = 1e-6
    for i in range(len(params)):              # central differences: a gear ratio's curvature
        v = v0.copy()                         # (q² · the arm's reach) spoils a one-sided one
        v[i] += h
        y1, _ = F.model(data, reg, params, v)
        v[i] -= 2 * h
        y2, _ = F.model(data, reg, params, v)
        assert np.allclose((y1 - y2).ravel() / (2 * h), J[:, nr + i], atol=1e-4, rtol=1e-4), \
            params[i].name
    # registration columns: translation and markers exactly, the rotation as a left twist
    for i in range(nr):
        step = np.zeros(nr + len(params))
        step[i] = h
        r2, _ = F._apply(data, reg, v0, step)
        y1, _ = F.model(data, r2, params, v0)
        assert np.allclose((y1 - y0).ravel() / h, J[:, i], atol=1e-3, rtol=1e-4), i


def test_urdf_rpy_round_trips():
    T = rpy_matrix([1.0, -2.0, 3.0], [0.3, -1.2, 2.9])
    xyz, rpy = matrix_rpy(T)
    assert np.allclose(rpy_matrix(xyz, rpy), T, atol=1e-12)


@pytest.mark.skipif(not TIAGO.is_dir(), reason="real data not present")
def test_tiago_registration_and_offsets_match_the_data_readme():
    # shared/data/real/tiago-mocap-train/README.md: registration only, all 4 points 4.09 mm;
    # with constant offsets of arm_2 … arm_6 3.23 mm; torso, arm_1, arm_7 not visible
    cc = read_campaign(TIAGO)
    d = F.Data.of(cc)
    f0 = F.fit(d, [])
    assert f0.rms == pytest.approx(4.09, abs=0.005)
    offs = [p for p in F.vocabulary(cc.chain) if p.effect == "joint_offset"]
    idf = F.identifiability(d, offs, f0.reg)
    assert [p.name for p in idf.kept] == [f"j{k}_offset_deg" for k in range(3, 8)]
    assert set(idf.dropped) == {"j1_offset_mm", "j2_offset_deg", "j8_offset_deg"}
    assert all("registration" in why for why in idf.dropped.values())
    f1 = F.fit(d, idf.kept, f0.reg)
    assert f1.rms == pytest.approx(3.23, abs=0.005)
    # FIGAROH's arm_5 offset on this set: -49.8 mrad = -2.85 deg (point 1 only)
    lo, hi = f1.ci95[[p.name for p in idf.kept].index("j6_offset_deg")]
    assert lo < math.degrees(-0.0498) < hi


def test_identifiability_keeps_the_registrations_basis_and_answers_as_without_it(tmp_path):
    # the registration's columns are the same for every pool: their basis is found once
    # per registration; each pool's answer is the one a Data that never kept it gives
    d = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.1}}, poses=8, sensor=True)
    cc = read_campaign(d)
    data = F.Data.of(cc)
    f0 = F.fit(data, [])
    voc = F.vocabulary(cc.chain)
    pools = [[p for p in voc if p.effect == e] for e in ("joint_offset", "link_length", "gear_ratio")]
    for pool in pools + pools[:1]:
        got = F.identifiability(data, pool, f0.reg)
        fresh = F.Data.of(cc)
        want = F.identifiability(fresh, pool, f0.reg)
        assert (got.kept, got.dropped, got.warnings, got.lacking) == \
            (want.kept, want.dropped, want.warnings, want.lacking)
        assert np.array_equal(data.zero_blocks(f0.reg)[F.NUISANCE_BASIS],
                              fresh.zero_blocks(f0.reg)[F.NUISANCE_BASIS])
    assert not data.zero_blocks(f0.reg)[F.NUISANCE_BASIS].flags.writeable


def test_a_sensor_seeing_two_axes_gets_the_3d_jacobians_rows_from_kept_and_fresh_blocks(tmp_path):
    # model keeps its blocks with only the rows the sensor sees: the Jacobian is the
    # 3-D one's rows of those axes, bit for bit, at zero (blocks kept, asked twice) and
    # at other values (blocks fresh), through a camera's maps about a centre
    import dataclasses
    d = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.1}}, poses=6, sensor=True,
                      model_extra={"sensor_center_mm": [120.0, -80.0, 400.0]})
    cc = read_campaign(d)
    d3 = F.Data.of(cc)
    params = F.vocabulary(cc.chain)
    reg = F.initial_registration(d3)
    for axes in [(0, 1), (0, 2), (1, 2)]:
        d2 = dataclasses.replace(d3, xyz=d3.xyz[:, list(axes)], axes=axes)
        for v in (np.zeros(len(params)), np.linspace(-0.01, 0.01, len(params))):
            y3, J3 = F.model(d3, reg, params, v, jac=True)
            want = J3.reshape(len(y3), 3, -1)[:, list(axes)].reshape(-1, J3.shape[1])
            for _ in range(2):
                y2, J2 = F.model(d2, reg, params, v, jac=True)
                assert np.array_equal(J2, want) and np.array_equal(y2, y3[:, list(axes)])


def test_a_terms_size_is_found_once_and_is_the_terms_own(tmp_path):
    # identifiability asks every pool for each parameter's term size: kept per Data, it
    # must be the term's (nonzero anywhere, largest magnitude) for each parameter, bus,
    # arm and joint ones alike, and a zero term has size 0
    d = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.1}}, poses=6, sensor=True, temps=True,
                      model_extra={"motor_gear_ratio": {"j2": 50.0}})
    cc = read_campaign(d)
    data = F.Data.of(cc)
    for p in F.vocabulary(cc.chain):
        if p.term is None:
            continue
        v = p.joint_terms(F._poses(data)) if p.bus else p.term(F._poses(data), p.joint)
        want = (bool(np.any(v)), float(np.max(np.abs(v))) if np.any(v) else 0.0)
        assert F._term_size(data, p) == want and F._term_size(data, p) == want, p.name
