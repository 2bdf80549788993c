"""The plant: the plant file, the true state, campaigns, determinism, PlantArm on a clock."""
import math
from pathlib import Path

import numpy as np
import pytest

from cell import effects as fx
from cell.clock import ManualClock
from cell.compensation.lattice import run_lattice
from cell.errors import ConfigError, KinematicsError, TrajectoryError
from cell.kinematics import Scara
from cell.sim.plant import Plant, PlantArm, PlantConfig

DEFAULT = Path(__file__).resolve().parents[2] / "deploy" / "plants" / "default.yaml"
RNG = np.random.default_rng(11)
CMD = np.column_stack([RNG.uniform(40, 80, 30), RNG.uniform(20, 60, 30)])
DIRS = RNG.choice([-1.0, 1.0], (30, 2))


def plant(**over) -> Plant:
    data = {"robot": "seed000", "camera_center_mm": [250.0, 930.0]}
    data.update(over)
    return Plant.from_config(data)


def write(tmp_path, text: str) -> Path:
    p = tmp_path / "plant.yaml"
    p.write_text(text)
    return p


# ------------------------------------------------------------------ the default plant file
def test_default_plant_file_loads_with_the_documented_mix():
    p = Plant.from_yaml(DEFAULT)
    assert p.robot.g.name == "seed000"
    assert {e.effect for e in p.effects} == {"joint_offset", "link_length", "backlash",
                                            "thermal_drift"}
    assert p.config.repeatability_mm == 0.01 and p.config.measurement_noise_mm == 0.005
    assert p.temperature(1e6) > p.temperature(0.0)  # warms up
    # cold error at seed 000 Table 2 target 1 is a few tenths of a mm, as the yaml says
    q = p.robot.ik_planar(243.457, 932.466)
    truth = fx.simulate_points(p.robot.g, p.effects, [q], [[1, 1]], None, 20.0, (250.0, 930.0))[0]
    assert 0.1 < math.hypot(*(truth - [243.457, 932.466])) < 0.6


# ------------------------------------------------------------------ truth and state
def test_zero_noise_campaign_is_the_effect_model():
    eff = [{"effect": "backlash", "joints": ["j2"], "params": {"j2_backlash_deg": 0.05}},
           {"effect": "camera_rotation", "params": {"camera_rotation_deg": 0.05}},
           {"effect": "thermal_drift", "params": {"thermal_expansion_per_k": 2e-5}}]
    p = plant(effects=eff, temperature={"ambient_c": 20, "rise_c": 5, "tau_s": 100})
    t = np.linspace(0, 500, len(CMD))
    got = p.campaign_points(CMD, DIRS, t)
    want = fx.simulate_points(p.robot.g, p.effects, CMD, DIRS, t, 20 + 5 * (1 - np.exp(-t / 100)),
                              (250.0, 930.0))
    assert np.allclose(got, want, atol=1e-12)


def test_campaign_noise_has_the_configured_size():
    p = plant(repeatability_mm=0.01, measurement_noise_mm=0.005)
    cmd = np.tile([60.0, 30.0], (4000, 1))
    xy = p.campaign_points(cmd, np.ones_like(cmd), np.zeros(4000))
    resid = xy - Scara.preset("seed000").fk_planar(60, 30)
    assert np.std(resid, axis=0) == pytest.approx([math.hypot(0.01, 0.005)] * 2, rel=0.06)
    assert np.all(np.abs(resid.mean(axis=0)) < 0.001)


def test_temperature_follows_the_warm_up_model():
    p = plant(temperature={"ambient_c": 21.0, "rise_c": 4.0, "tau_s": 600.0})
    assert p.temperature(0.0) == 21.0
    assert p.temperature(600.0) == pytest.approx(21.0 + 4.0 * (1 - math.exp(-1)))
    assert p.temperature(1e7) == pytest.approx(25.0)
    assert p.temperature(-5.0) == 21.0  # before the cold start: ambient


def test_update_drive_tracks_direction_and_backlash_shows_it():
    p = plant(effects=[{"effect": "backlash", "joints": ["j2"], "params": {"j2_backlash_deg": 0.1}}],
              start_dirs=[0, 0])
    p.update_drive(1, 29.0, 1.0)
    p.update_drive(1, 30.0, 2.0)           # arrive at 30° from below
    from_below = p.true_tool_xy(2.0)
    assert p.directions()[1] == 1
    p.update_drive(1, 31.0, 3.0)
    p.update_drive(1, 30.0, 4.0)           # arrive at 30° from above
    from_above = p.true_tool_xy(4.0)
    assert p.directions()[1] == -1
    robot = Scara.preset("seed000")
    assert np.allclose(from_below, robot.fk_planar(60, 30 - 0.05))
    assert np.allclose(from_above, robot.fk_planar(60, 30 + 0.05))
    p.update_drive(1, 30.0, 5.0)           # no motion keeps the direction
    assert p.directions()[1] == -1
    p.update_drive(2, -10.0, 6.0)          # z moves; x, y do not
    assert np.allclose(p.true_tool_xy(6.0), from_above)
    assert np.array_equal(p.drive_positions(), [60.0, 30.0, -10.0, 0.0])


def test_repeatability_is_one_draw_per_arrival():
    p = plant(repeatability_mm=0.02)
    a, b = p.true_tool_xy(0.0), p.true_tool_xy(1.0)
    assert np.array_equal(a, b)            # standing still: same truth
    p.update_drive(0, 60.5, 2.0)
    p.update_drive(0, 60.0, 3.0)
    assert not np.allclose(p.true_tool_xy(3.0), a)  # back at the same command, new arrival


def test_measured_xy_sees_the_truth_through_the_camera():
    p = plant(effects=[{"effect": "camera_scale", "params": {"camera_scale_rel": 1e-3}}])
    truth = p.true_tool_xy(0.0)
    c = np.array([250.0, 930.0])
    assert np.allclose(p.measured_xy(0.0), c + 1.001 * (truth - c))


@pytest.mark.parametrize("args, err, words", [
    ((4, 1.0, 0.0), KinematicsError, "joint_index = 4"),
    ((True, 1.0, 0.0), KinematicsError, "joint_index = True"),
    ((0, float("nan"), 0.0), KinematicsError, "j1 drive position = nan"),
    ((1, 1.0, float("inf")), TrajectoryError, "t_s = inf"),
])
def test_bad_drive_updates_change_nothing(args, err, words):
    p = plant()
    before = (p.drive_positions(), p.directions())
    with pytest.raises(err, match=words):
        p.update_drive(*args)
    assert np.array_equal(p.drive_positions(), before[0])
    assert np.array_equal(p.directions(), before[1])


def test_bad_campaign_input_is_rejected():
    p = plant()
    with pytest.raises(TrajectoryError, match="times"):
        p.campaign_points(CMD, DIRS, np.zeros(3)[:, None])
    times = np.zeros(30)
    times[4] = np.nan
    with pytest.raises(TrajectoryError, match=r"times\[4\] = nan"):
        p.campaign_points(CMD, DIRS, times)
    with pytest.raises(KinematicsError, match="dirs"):
        p.campaign_points(CMD, DIRS[:3], np.zeros(30))
    with pytest.raises(TrajectoryError, match="strictly"):
        p.campaign_path(CMD, np.zeros(30))
    with pytest.raises(TrajectoryError, match="start_s = nan"):
        p.campaign_path(CMD, np.arange(30.0), start_s=float("nan"))
    with pytest.raises(TrajectoryError, match="t_s = nan"):
        p.true_tool_xy(float("nan"))


def test_campaign_path_applies_the_comm_delay_in_station_order():
    eff = [{"effect": "comm_delay", "params": {"comm_delay_sigma_ms": 4.0}}]
    t = np.linspace(0, 0.5, 51)
    cmd = np.column_stack([60 + 20 * t, 30 - 40 * t])
    delayed = plant(effects=eff, stations=["j2", "j1", "j3", "j4"]).campaign_path(cmd, t)
    want = fx.simulate_path(Scara.preset("seed000").g, [fx.make_effect(**eff[0])], cmd, t,
                            stations=["j2", "j1"])
    assert np.allclose(delayed, want)
    assert np.max(np.hypot(*(delayed - plant().campaign_path(cmd, t)).T)) > 0.1


# ------------------------------------------------------------------ determinism
def _run(seed: int) -> np.ndarray:
    p = Plant.from_config({"robot": "seed000", "seed": seed, "repeatability_mm": 0.01,
                           "measurement_noise_mm": 0.005})
    arm = PlantArm(p, ManualClock())
    pts = [arm.move_and_measure(np.array([6000 + 7 * i, 3000 - 5 * i])) for i in range(5)]
    return np.vstack(pts + [p.campaign_points(CMD, DIRS, np.zeros(30))])


def test_same_seed_same_run_other_seed_other_run():
    assert np.array_equal(_run(3), _run(3))
    assert not np.allclose(_run(3), _run(4))


def test_campaigns_do_not_disturb_the_live_measurements():
    a, b = plant(measurement_noise_mm=0.01), plant(measurement_noise_mm=0.01)
    b.campaign_points(CMD, DIRS, np.zeros(30))
    assert np.array_equal(a.measured_xy(0.0), b.measured_xy(0.0))


# ------------------------------------------------------------------ PlantArm
def test_plant_arm_takes_simulated_time_and_lands_within_noise_of_the_truth():
    p = Plant.from_yaml(DEFAULT)
    clock = ManualClock(100.0)
    arm = PlantArm(p, clock)
    got = arm.move_and_measure(np.array([6300, 2800]))   # from (60°, 30°): Δ = 3°, −2°
    assert clock.now() == pytest.approx(100.0 + 3.0 / 90.0)
    assert np.array_equal(p.drive_positions()[:2], [63.0, 28.0])
    assert np.array_equal(p.directions()[:2], [1.0, -1.0])
    assert np.hypot(*(got - arm.true_point)) < 5 * 0.005 * math.sqrt(2)
    noiseless = fx.simulate_points(p.robot.g, p.effects, [[63.0, 28.0]], [[1, -1]], None,
                                   p.temperature(clock.now()), p.config.camera_center_mm)[0]
    assert np.hypot(*(arm.true_point - noiseless)) < 5 * 0.01 * math.sqrt(2)
    arm.move_and_measure(np.array([6300, 2800]))   # no motion: no time
    assert clock.now() == pytest.approx(100.0 + 3.0 / 90.0)


def test_plant_arm_passes_a_via_point_so_backlash_is_taken_up_from_its_side():
    """From above, a via point below the command makes both joints arrive moving up; the
    true point is then what true_points predicts for that side, and time counts both legs."""
    p = Plant.from_yaml(DEFAULT)                   # j2 backlash 0.02°
    clock = ManualClock(0.0)
    arm = PlantArm(p, clock)
    arm.move_and_measure(np.array([6100, 3100]))   # from (60°, 30°): up to (61°, 31°)
    t0 = clock.now()
    arm.move_and_measure(np.array([6050, 3050]), via_units=np.array([6045, 3045]))
    assert np.array_equal(p.directions()[:2], [1.0, 1.0])
    assert clock.now() - t0 == pytest.approx((0.55 + 0.05) / 90.0)
    want = p.true_points([[60.5, 30.5]], [1, 1], clock.now())[0]
    assert np.hypot(*(arm.true_point - want)) < 5 * 0.01 * math.sqrt(2)
    down = p.true_points([[60.5, 30.5]], [-1, -1], clock.now())[0]
    assert np.hypot(*(want - down)) > 0.1                 # the side matters by the band
    assert p.drive_positions()[:2].tolist() == [60.5, 30.5]   # true_points moved nothing


def test_plant_arm_rejects_bad_commands_without_moving():
    p = plant()
    clock = ManualClock()
    arm = PlantArm(p, clock)
    for bad, words in (([20000, 0], "outside its limits"), ([6000.5, 3000], "whole numbers"),
                       ([6000], "whole numbers")):
        with pytest.raises(KinematicsError, match=words):
            arm.move_and_measure(np.array(bad))
        with pytest.raises(KinematicsError, match=words):       # a bad via point: not a step
            arm.move_and_measure(np.array([6010, 3010]), via_units=np.array(bad))
    assert clock.now() == 0.0 and arm.moves == 0
    assert np.array_equal(p.drive_positions()[:2], [60.0, 30.0])


def test_lattice_compensation_runs_on_the_plant():
    p = Plant.from_yaml(DEFAULT)
    arm = PlantArm(p, ManualClock())
    res = run_lattice(p.robot, arm, (243.457, 932.466))
    assert res.initial_error_mm > 0.1 and res.final_error_mm < 0.06


# ------------------------------------------------------------------ bad plant files
GOOD = """\
robot: seed000
seed: 1
repeatability_mm: 0.01
effects:
  - effect: backlash
    joints: [j2]
    params: {j2_backlash_deg: 0.02}
  - effect: thermal_drift
    params:
      thermal_expansion_per_k: 2.3e-5
"""


def test_the_good_file_loads(tmp_path):
    p = Plant.from_yaml(write(tmp_path, GOOD))
    assert [e.effect for e in p.effects] == ["backlash", "thermal_drift"]


@pytest.mark.parametrize("old, new, line, field, words", [
    ("seed: 1", "seed: 1\ncolour: red", 3, "colour", "unknown field"),
    ("effect: backlash", "effect: backlush", 5, "effects[0].effect", "unknown effect 'backlush'"),
    ("0.02}", "-0.02}", 7, "effects[0].params.j2_backlash_deg", "outside [0.0, 2.0]"),
    ("repeatability_mm: 0.01", "repeatability_mm: -0.01", 3, "repeatability_mm",
     "greater than or equal to 0"),
    ("repeatability_mm: 0.01", "repeatability_mm: lots", 3, "repeatability_mm", "valid number"),
    ("2.3e-5", "warm", 10, "effects[1].params.thermal_expansion_per_k", "valid number"),
    ("    joints: [j2]", "    joints: [j2]\n    speed: 3", 7, "effects[0].speed", "unknown field"),
    ("joints: [j2]", "joints: [j5]", 6, "effects[0].joints", "joints ['j5'] invalid"),
    ("robot: seed000", "robot: seed999", 1, "robot", "unknown robot preset 'seed999'"),
    ("seed: 1", "seed: 1\ngeometry: {l1_mm: 300, l2_mm: 200}", 1, "robot", "exactly one"),
    ("seed: 1", "seed: 1\nstart_deg: [60, 200]", 3, "start_deg[1]", "outside its limits"),
    ("seed: 1", "seed: 1\nstations: [j1, j1, j2]", 3, "stations", "distinct"),
    ("  - effect: thermal_drift", "  - effect: backlash\n    joints: [j2]\n"
     "    params: {j2_backlash_deg: 0.03}\n  - effect: thermal_drift", 8, "effects[1]", "given twice"),
    ("seed: 1", "seed: 1\nseed: 2", 3, "seed", "key given twice"),
])
def test_bad_plant_files_name_file_line_and_field(tmp_path, old, new, line, field, words):
    assert old in GOOD
    path = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        Plant.from_yaml(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:{line}: {field}: "), msg
    assert words in msg


def test_malformed_yaml_names_file_and_line(tmp_path):
    path = write(tmp_path, GOOD.replace("params: {j2_backlash_deg: 0.02}",
                                        "params: {j2_backlash_deg: 0.02"))
    with pytest.raises(ConfigError, match=rf"^{path}:\d+: malformed YAML"):
        Plant.from_yaml(path)


def test_missing_empty_and_non_mapping_files(tmp_path):
    with pytest.raises(ConfigError, match=rf"^{tmp_path / 'nope.yaml'}: plant file not found"):
        Plant.from_yaml(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match=r":1: \(top level\): the plant file is empty"):
        Plant.from_yaml(write(tmp_path, "# nothing\n"))
    with pytest.raises(ConfigError, match=r":1: \(top level\): the plant file must be a mapping"):
        Plant.from_yaml(write(tmp_path, "- robot\n- seed000\n"))


def test_from_config_names_the_source_and_plant_needs_a_config():
    with pytest.raises(ConfigError, match=r"^cell.yaml\[plant\]: seed: "):
        Plant.from_config({"robot": "seed000", "seed": -1}, source="cell.yaml[plant]")
    with pytest.raises(ConfigError, match="needs a PlantConfig"):
        Plant({"robot": "seed000"})
    assert isinstance(plant().config, PlantConfig)
