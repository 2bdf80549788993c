"""The effect vocabulary: each effect alone, the composition order, bad input, fitter use.

Golden values come from the nominal kinematics (cell.kinematics.Scara, seed 000 eq. 4)
with changed joint angles or link lengths, i.e. from an independent scalar implementation.
"""
import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from cell import effects as fx
from cell.errors import ConfigError, KinematicsError, TrajectoryError
from cell.kinematics import Scara
from cell.robots import PRESETS

G = PRESETS["seed000"]
ROBOT = Scara(G)
RNG = np.random.default_rng(7)
CMD = np.column_stack([RNG.uniform(-120, 120, 25), RNG.uniform(10, 140, 25)])
DIRS = RNG.choice([-1.0, 1.0], (25, 2))
CENTER = (250.0, 930.0)


def nominal(cmd):
    return np.array([ROBOT.fk_planar(a, b) for a, b in cmd])


def sim(effects, cmd=CMD, dirs=DIRS, temp=20.0, center=CENTER):
    return fx.simulate_points(G, effects, cmd, dirs, None, temp, center)


# ------------------------------------------------------------------ the registry
def test_registry_matches_the_measurement_spec_vocabulary():
    spec = {"joint_offset": "kinematics", "link_length": "kinematics",
            "gear_ratio": "transmission", "backlash": "transmission",
            "cyclic_error": "transmission", "thermal_drift": "thermal",
            "camera_scale": "vision", "camera_rotation": "vision", "comm_delay": "comms",
            "motor_cyclic_error": "transmission"}
    assert {n: e.subsystem for n, e in fx.EFFECTS.items()} == spec
    for name in ("joint_offset", "link_length", "gear_ratio", "backlash", "cyclic_error",
                 "motor_cyclic_error"):
        assert fx.EFFECTS[name].joints == ("j1", "j2")
    for name in ("thermal_drift", "camera_scale", "camera_rotation", "comm_delay"):
        assert fx.EFFECTS[name].joints == ()
    assert fx.EFFECTS["backlash"].param_names(["j2"]) == ["j2_backlash_deg"]  # spec's example


def test_the_plant_file_format_lists_every_effect_a_plant_can_hold():
    """deploy/plants/README.md is where a technician reads what a plant may simulate: every
    effect of the vocabulary has its row there, with its parameters (motor_cyclic_error was
    once missing)."""
    from pathlib import Path
    page = (Path(__file__).resolve().parents[2] / "deploy" / "plants" / "README.md").read_text(encoding="utf-8")
    rows = {line.split("|")[1].strip().strip("`"): line for line in page.splitlines() if line.startswith("| `")}
    for name, e in fx.EFFECTS.items():
        assert name in rows, f"deploy/plants/README.md has no row for {name}"
        stems = [p.stem for p in e.params]
        assert all(stem in rows[name] for stem in stems), (name, stems)


def test_every_zero_sized_effect_is_the_nominal_model():
    for name, e in fx.EFFECTS.items():
        inst = e.zero(e.joints[:1])
        assert np.allclose(sim([inst]), nominal(CMD), atol=1e-9), name
        t = np.linspace(0, 1, 25)
        path = fx.simulate_path(G, [inst], CMD, t, 20.0, CENTER)
        assert np.allclose(path, nominal(CMD), atol=1e-9), name


def test_draws_are_seeded_and_within_the_typical_range():
    for name, e in fx.EFFECTS.items():
        a = e.draw(np.random.default_rng(3), e.joints)
        b = e.draw(np.random.default_rng(3), e.joints)
        assert a == b
        for n in a.fit_names:
            lo, hi = e.spec_of(n).typical
            assert lo <= abs(a.params[n]) <= hi, (name, n)


# ------------------------------------------------------------------ each effect alone
def test_joint_offset_adds_a_constant_angle():
    inst = fx.make_effect("joint_offset", ["j1", "j2"], {"j1_offset_deg": 0.1, "j2_offset_deg": -0.05})
    assert np.allclose(sim([inst]), nominal(CMD + [0.1, -0.05]))


def test_gear_ratio_scales_the_angle():
    inst = fx.make_effect("gear_ratio", ["j2"], {"j2_gear_ratio_rel": 1e-3})
    q = fx.true_joints([inst], CMD, DIRS)
    assert np.allclose(q[:, 1], CMD[:, 1] * 1.001)
    assert np.array_equal(q[:, 0], CMD[:, 0])
    assert np.array_equal(fx.true_joints([inst], np.zeros((1, 2)), np.ones((1, 2))), np.zeros((1, 2)))


def test_backlash_depends_on_direction_only():
    inst = fx.make_effect("backlash", ["j2"], {"j2_backlash_deg": 0.04})
    up = fx.true_joints([inst], CMD, np.ones_like(CMD)) - CMD
    down = fx.true_joints([inst], CMD, -np.ones_like(CMD)) - CMD
    rest = fx.true_joints([inst], CMD, np.zeros_like(CMD)) - CMD
    assert np.allclose(up[:, 1], -0.02) and np.allclose(down[:, 1], 0.02)  # same at every angle
    assert np.allclose(down[:, 1] - up[:, 1], 0.04)  # a reversal moves the joint by b
    assert np.array_equal(rest, np.zeros_like(CMD))
    assert np.array_equal(up[:, 0], np.zeros(len(CMD)))  # j1 untouched


def test_cyclic_error_is_periodic_with_the_known_period():
    inst = fx.make_effect("cyclic_error", ["j1"], {"j1_cyclic_amp_deg": 0.05,
                                                   "j1_cyclic_phase_deg": 30.0,
                                                   "j1_cyclic_period_deg": 90.0})
    dq = lambda q: fx.true_joints([inst], q, DIRS) - q  # noqa: E731
    assert np.allclose(dq(CMD)[:, 0], dq(CMD + [90.0, 0])[:, 0])
    assert dq(np.zeros((1, 2)))[0, 0] == pytest.approx(0.05 * math.sin(math.radians(30)))
    assert np.max(np.abs(dq(np.column_stack([np.linspace(0, 90, 361), np.zeros(361)])))) \
        == pytest.approx(0.05, rel=1e-4)
    default = fx.make_effect("cyclic_error", ["j2"], {"j2_cyclic_amp_deg": 0.05,
                                                      "j2_cyclic_phase_deg": 0.0})
    assert default.params["j2_cyclic_period_deg"] == 360.0
    assert default.fit_names == ["j2_cyclic_amp_deg", "j2_cyclic_phase_deg"]


def test_link_length_changes_the_link():
    inst = fx.make_effect("link_length", ["j1", "j2"], {"j1_link_delta_mm": 0.5, "j2_link_delta_mm": -0.3})
    true = Scara(G.model_copy(update={"l1_mm": 500.5, "l2_mm": 499.7}))
    assert np.allclose(sim([inst]), [true.fk_planar(a, b) for a, b in CMD])


def test_thermal_drift_expands_both_links_with_temperature():
    inst = fx.make_effect("thermal_drift", [], {"thermal_expansion_per_k": 20e-6})
    assert np.allclose(sim([inst], temp=20.0), nominal(CMD))  # at the reference temperature
    grow = 1 + 20e-6 * 10.0
    true = Scara(G.model_copy(update={"l1_mm": 500 * grow, "l2_mm": 500 * grow}))
    assert np.allclose(sim([inst], temp=30.0), [true.fk_planar(a, b) for a, b in CMD])
    temps = np.linspace(20, 30, len(CMD))
    links = fx.true_links(G, [inst], temps)
    assert np.allclose(links, 500 * (1 + 20e-6 * (temps - 20))[:, None])


def test_camera_rotation_is_about_the_centre():
    inst = fx.make_effect("camera_rotation", [], {"camera_rotation_deg": 0.1})
    c = np.array(CENTER)
    assert np.allclose(fx.camera_view([inst], c[None, :], c), c[None, :])
    p = nominal(CMD)
    m = fx.camera_view([inst], p, c)
    assert np.allclose(np.hypot(*(m - c).T), np.hypot(*(p - c).T))
    ang = np.degrees(np.arctan2(*(m - c).T[::-1]) - np.arctan2(*(p - c).T[::-1]))
    assert np.allclose((ang + 180) % 360 - 180, 0.1)


def test_camera_scale_is_about_the_centre():
    inst = fx.make_effect("camera_scale", [], {"camera_scale_rel": 1e-3})
    c = np.array(CENTER)
    assert np.allclose(fx.camera_view([inst], c[None, :], c), c[None, :])
    p = nominal(CMD)
    assert np.allclose(fx.camera_view([inst], p, c) - c, 1.001 * (p - c))


def test_comm_delay_with_zero_sigma_is_the_identity():
    inst = fx.make_effect("comm_delay", [], {"comm_delay_sigma_ms": 0.0})
    t = np.linspace(0, 0.5, 51)
    cmd = np.column_stack([np.linspace(60, 70, 51), np.linspace(30, 10, 51)])
    assert np.array_equal(fx.comm_delay(inst.full_vector(), [1, 2], t, cmd), cmd)
    assert np.allclose(fx.simulate_path(G, [inst], cmd, t), nominal(cmd))


def test_comm_delay_runs_station_k_sigma_k_late():
    inst = fx.make_effect("comm_delay", [], {"comm_delay_sigma_ms": 4.0})
    t = np.linspace(0, 1, 101)
    cmd = np.column_stack([60 + 10 * t, 30 - 20 * t])  # 10 and −20 deg/s ramps
    got = fx.comm_delay(inst.full_vector(), fx.station_order(["j1", "j2", "j3"]), t, cmd)
    assert np.allclose(got[10:, 0], 60 + 10 * (t[10:] - 0.004))
    assert np.allclose(got[10:, 1], 30 - 20 * (t[10:] - 0.008))
    assert np.array_equal(got[0], cmd[0])  # held at the first command before it
    swapped = fx.comm_delay(inst.full_vector(), fx.station_order(["j2", "j1"]), t, cmd)
    assert np.allclose(swapped[10:, 0], 60 + 10 * (t[10:] - 0.008))
    path = fx.simulate_path(G, [inst], cmd, t, stations=["j1", "j2"])
    assert np.allclose(path, nominal(got))


# ------------------------------------------------------------------ composition
def test_composition_order_joint_then_link_then_fk_then_camera():
    off = fx.make_effect("joint_offset", ["j1"], {"j1_offset_deg": 0.2})
    link = fx.make_effect("link_length", ["j2"], {"j2_link_delta_mm": 1.0})
    rot = fx.make_effect("camera_rotation", [], {"camera_rotation_deg": 0.5})
    true = Scara(G.model_copy(update={"l2_mm": 501.0}))
    truth = np.array([true.fk_planar(a + 0.2, b) for a, b in CMD])
    a = math.radians(0.5)
    expect = np.array(CENTER) + (truth - CENTER) @ np.array([[math.cos(a), -math.sin(a)],
                                                             [math.sin(a), math.cos(a)]]).T
    for order in ([off, link, rot], [rot, link, off]):  # list order does not matter
        assert np.allclose(sim(order), expect)
    # the camera sees the final true point: a centre on it stays put
    c0 = truth[0]
    assert np.allclose(fx.simulate_points(G, [off, link, rot], CMD[:1], DIRS[:1], None, 20.0, c0), c0)


def test_path_directions_follow_the_delayed_command():
    bl = fx.make_effect("backlash", ["j1"], {"j1_backlash_deg": 0.1})
    t = np.arange(6) * 0.1
    cmd = np.column_stack([[10, 11, 12, 12, 11, 10], [30] * 6]).astype(float)
    xy = fx.simulate_path(G, [bl], cmd, t, dirs0=(-1, 0))
    expect_dirs = np.array([-1, 1, 1, 1, -1, -1])
    assert np.allclose(xy, nominal(cmd + np.column_stack([-0.05 * expect_dirs, np.zeros(6)])))


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("effect, joints, params, loc, words", [
    ("backlush", ["j2"], {}, ("effect",), "unknown effect 'backlush'"),
    ("backlash", [], {}, ("joints",), "joints [] invalid"),
    ("backlash", ["j3"], {"j3_backlash_deg": 0.1}, ("joints",), "j3"),
    ("backlash", ["j2", "j2"], {}, ("joints",), "distinct"),
    ("camera_scale", ["j1"], {}, ("joints",), "acts on no joint"),
    ("backlash", ["j2"], {}, ("params",), "'j2_backlash_deg'"),
    ("backlash", ["j2"], {"j2_backlash_deg": 0.1, "j1_backlash_deg": 0.1},
     ("params", "j1_backlash_deg"), "unknown parameter"),
    ("backlash", ["j2"], {"j2_backlash_deg": -0.02}, ("params", "j2_backlash_deg"), "outside"),
    ("backlash", ["j2"], {"j2_backlash_deg": float("nan")}, ("params", "j2_backlash_deg"), "finite"),
    ("backlash", ["j2"], {"j2_backlash_deg": "0.1"}, ("params", "j2_backlash_deg"), "finite"),
])
def test_bad_effects_are_rejected_naming_the_field(effect, joints, params, loc, words):
    with pytest.raises(ConfigError) as err:
        fx.make_effect(effect, joints, params)
    assert err.value.loc == loc
    assert words in str(err.value)


def test_bad_batches_are_rejected_naming_the_value():
    inst = fx.make_effect("thermal_drift", [], {"thermal_expansion_per_k": 2e-5})
    with pytest.raises(KinematicsError, match=r"cmd_deg must have shape \(N, 2\)"):
        fx.simulate_points(G, [], np.zeros((3, 3)), np.zeros((3, 2)))
    with pytest.raises(KinematicsError, match=r"cmd_deg\[1, 0\] = nan"):
        fx.simulate_points(G, [], [[0, 1], [np.nan, 1]], np.zeros((2, 2)))
    with pytest.raises(KinematicsError, match=r"dirs\[0, 1\] = 2.0"):
        fx.simulate_points(G, [], [[0, 1]], [[1, 2]])
    with pytest.raises(KinematicsError, match=r"dirs must have shape \(1, 2\)"):
        fx.simulate_points(G, [], [[0, 1]], [[1, 1], [1, 1]])
    with pytest.raises(ConfigError, match="temp_c is required"):
        fx.simulate_points(G, [inst], [[0, 1]], [[1, 1]])
    with pytest.raises(TrajectoryError, match=r"temp_c must have shape \(1,\)"):
        fx.simulate_points(G, [inst], [[0, 1]], [[1, 1]], None, [20, 21])
    with pytest.raises(TrajectoryError, match=r"time_s\[2\] = 0.1 after 0.2"):
        fx.simulate_path(G, [], np.zeros((3, 2)), [0.0, 0.2, 0.1])
    with pytest.raises(ConfigError, match="stations"):
        fx.simulate_path(G, [], np.zeros((3, 2)), [0.0, 0.1, 0.2], stations=["j1", "j1", "j2"])
    with pytest.raises(ConfigError, match="camera_center_mm"):
        fx.simulate_points(G, [], [[0, 1]], [[1, 1]], camera_center_mm=(1.0,))
    with pytest.raises(ConfigError, match=r"effects\[0\]"):
        fx.simulate_points(G, [{"effect": "backlash"}], [[0, 1]], [[1, 1]])


# ------------------------------------------------------------------ use by a fitter
def test_vectors_round_trip_and_reject_a_wrong_length():
    effs = [fx.make_effect("backlash", ["j1", "j2"], {"j1_backlash_deg": 0.01, "j2_backlash_deg": 0.02}),
            fx.make_effect("cyclic_error", ["j2"], {"j2_cyclic_amp_deg": 0.03, "j2_cyclic_phase_deg": 10})]
    x, names = fx.stack_vectors(effs)
    assert names == ["j1_backlash_deg", "j2_backlash_deg", "j2_cyclic_amp_deg", "j2_cyclic_phase_deg"]
    assert fx.split_vector(effs, x) == effs
    lo, hi = effs[0].bounds()
    assert np.array_equal(lo, [0, 0]) and np.array_equal(hi, [2, 2])
    with pytest.raises(ConfigError, match="vector of 3 values"):
        fx.split_vector(effs, x[:3])
    with pytest.raises(ConfigError, match="2 finite values"):
        effs[0].with_vector([0.1, np.inf])


def test_least_squares_recovers_a_backlash_and_an_offset():
    truth = [fx.make_effect("backlash", ["j2"], {"j2_backlash_deg": 0.03}),
             fx.make_effect("joint_offset", ["j1"], {"j1_offset_deg": 0.07})]
    meas = sim(truth)
    start = [fx.EFFECTS["backlash"].guess(["j2"]), fx.EFFECTS["joint_offset"].guess(["j1"])]
    x0, _ = fx.stack_vectors(start)
    fit = least_squares(lambda x: (sim(fx.split_vector(start, x)) - meas).ravel(), x0,
                        bounds=(np.r_[start[0].bounds()[0], start[1].bounds()[0]],
                                np.r_[start[0].bounds()[1], start[1].bounds()[1]]))
    assert np.allclose(fit.x, [0.03, 0.07], atol=1e-7)


# ------------------------------------------------------------------ one definition per effect
def test_an_effect_of_an_unknown_stage_is_refused_by_name():
    base = fx.EFFECTS["backlash"]
    with pytest.raises(ValueError, match="'wrist'"):
        fx.Effect(base.name, base.subsystem, "wrist", base.joints, base.per_joint, base.params,
                  base.depends_on, base.summary)
    assert fx.Effect(base.name, base.subsystem, "joint", base.joints, base.per_joint, base.params,
                     base.depends_on, base.summary).stage is fx.Stage.JOINT


def test_every_effect_is_one_complete_definition():
    for name, e in fx.REGISTRY.items():
        assert e.subsystem in fx.SUBSYSTEMS and e.remedy is not None, name
        assert set(e.mimics) <= set(fx.EFFECTS), name
        if e.planar:
            assert e.deriv is not None and isinstance(e.stage, fx.Stage), name
    assert "gravity_compliance" not in fx.EFFECTS                # chain only
    assert list(fx.CHAIN_EFFECTS) == ["joint_offset", "link_length", "gear_ratio", "backlash",
                                      "cyclic_error", "thermal_drift", "camera_scale",
                                      "camera_rotation", "comm_delay", "gravity_compliance",
                                      "motor_cyclic_error"]


def test_the_chain_vocabulary_comes_from_the_registry():
    from cell.diagnosis.chain import fit as chain_fit
    assert chain_fit.EFFECTS == tuple(fx.CHAIN_EFFECTS)
    assert chain_fit.SUBSYSTEM == {"joint_offset": "kinematics", "link_length": "kinematics",
                                   "gear_ratio": "transmission", "backlash": "transmission",
                                   "cyclic_error": "transmission",
                                   "thermal_drift": "thermal", "camera_scale": "vision",
                                   "camera_rotation": "vision", "gravity_compliance": "transmission",
                                   "motor_cyclic_error": "transmission", "comm_delay": "comms"}
    assert chain_fit.DEPENDS_ON == {"joint_offset": "constant", "link_length": "position",
                                    "gear_ratio": "angle", "backlash": "direction",
                                    "cyclic_error": "angle",
                                    "thermal_drift": "temperature", "camera_scale": "position",
                                    "camera_rotation": "position",
                                    "gravity_compliance": "position", "motor_cyclic_error": "angle",
                                    "comm_delay": "speed"}


def test_a_chain_effect_on_a_joint_must_say_how_it_moves_the_joint():
    import pytest
    term = fx.REGISTRY["gear_ratio"].chain.term
    poses = fx.ChainPoses(np.array([[10.0, -20.0], [30.0, 5.0]]), np.zeros((2, 2)),
                          np.array([[1.0, -1.0], [0.0, 1.0]]))
    assert np.array_equal(term(poses, 1), [-20.0, 5.0])          # Δq_k = ε·q_k
    backlash = fx.REGISTRY["backlash"].chain.term
    assert np.array_equal(backlash(poses, 1), [0.5, -0.5])       # Δq_k = −dir_k·b/2
    with pytest.raises(ValueError, match="joint term"):
        fx.OnChain("all", "wobble_deg")                          # a joint effect without a term
    with pytest.raises(ValueError, match="joint term"):
        fx.OnChain("geometric", term=lambda p, k: p.q[:, k])     # the op's own offset needs none


def test_a_ripple_on_a_chain_is_two_coefficients_per_order_and_joint():
    import pytest
    from cell.diagnosis.chain import fit as chain_fit
    from cell.kinematics.chain import dh_chain
    use = fx.REGISTRY["cyclic_error"].chain
    assert [stem for stem, _ in use.terms()] == [f"cyclic{n}_{f}_deg" for n in (1, 2, 3, 4)
                                                 for f in ("sin", "cos")]
    poses = fx.ChainPoses(np.array([[30.0, 90.0]]), np.zeros((1, 2)), np.zeros((1, 2)))
    sin2, cos2 = use.terms()[2][1], use.terms()[3][1]                 # order 2
    assert np.allclose([sin2(poses, 1), cos2(poses, 1)], [[0.0], [-1.0]])   # sin 180°, cos 180°
    assert use.choice == 2 and use.bounds == (-1.0, 1.0)
    rows = [{"name": j, "type": "revolute", "a_mm": a, "alpha_deg": 0.0, "d_mm": 0.0,
             "theta_deg": 0.0} for j, a in (("j1", 325.0), ("j2", 275.0))]
    chain = dh_chain("m.yaml", rows, "standard", [], (0.0, 0.0, 0.0), (0, 0, -1))
    names = [p.name for p in chain_fit.vocabulary(chain) if p.effect == "cyclic_error"]
    assert names[:2] == ["j1_cyclic1_sin_deg", "j1_cyclic1_cos_deg"] and len(names) == 16
    with pytest.raises(ValueError, match="parts replace the stem and the term"):
        fx.OnChain("all", "wobble_deg", parts=use.parts)
    with pytest.raises(ValueError, match="parts replace the stem and the term"):
        fx.OnChain("arm", parts=use.parts)
