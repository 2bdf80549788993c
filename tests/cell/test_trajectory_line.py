"""Straight lines with seed 002's CAN delay correction: formula, station order, simulation, CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cell import cli
from cell.errors import CellError, TrajectoryError
from cell.kinematics import Scara
from cell.motion.line import (delay_corrected_velocities, joint_delays, joint_positions_at, line_joints,
                                  max_line_deviation, plan_line, simulate_line, station_delays,
                                  tool_positions)

ROBOT = Scara.preset("seed002")          # seed 002: l1 = l2 = 200 mm, tool (0, 0, −50)
A = (300.0, -60.0, -30.0, 0.0)           # a planar line well inside the workspace
B = (300.0, 60.0, -30.0, 20.0)
T = 0.010


# --------------------------------------------------------------------------- delays
def test_station_delays_are_sigma_times_bus_position():
    np.testing.assert_allclose(station_delays(0.001, 4), [0.001, 0.002, 0.003, 0.004])
    np.testing.assert_allclose(station_delays(0.0, 2), [0.0, 0.0])


@pytest.mark.parametrize("sigma, n, words", [
    (-0.001, 4, "sigma_s"), (float("nan"), 4, "sigma_s"), (float("inf"), 4, "sigma_s"),
    (0.001, 0, "n_stations"), (0.001, 2.5, "n_stations"), (0.001, True, "n_stations"),
])
def test_station_delays_rejects_bad_input(sigma, n, words):
    with pytest.raises(TrajectoryError, match=words):
        station_delays(sigma, n)


def test_joint_delays_follow_station_order():
    np.testing.assert_allclose(joint_delays(0.001), [0.001, 0.002, 0.003, 0.004])
    # j3 is first on the bus, then j1, j4, j2
    np.testing.assert_allclose(joint_delays(0.001, ("j3", "j1", "j4", "j2")),
                               [0.002, 0.004, 0.001, 0.003])


@pytest.mark.parametrize("order", [("j1", "j1", "j2", "j3"), ("j1", "j2", "j3"), ("j1", "j2", "j3", "j5")])
def test_joint_delays_rejects_bad_order(order):
    with pytest.raises(TrajectoryError, match="station_order"):
        joint_delays(0.001, order)


def test_corrected_velocity_covers_the_increment_in_the_time_left():
    rng = np.random.default_rng(2)
    delta = rng.normal(0, 5, size=(30, 4))
    lam = np.array([0.5, 1.0, 1.5, 2.0]) * 1e-3
    w = delay_corrected_velocities(delta, T, lam)
    np.testing.assert_allclose(w * (T - lam), delta, rtol=1e-12, atol=1e-12)
    assert np.all(np.sign(w) == np.sign(delta))


def test_zero_delay_is_the_uncorrected_velocity():
    delta = np.array([1.0, -2.0, 0.5, 0.0])
    np.testing.assert_allclose(delay_corrected_velocities(delta, T, np.zeros(4)), delta / T)


@pytest.mark.parametrize("lam, words", [
    ([0.001, 0.002, 0.003, 0.010], "j4"),            # T == λ
    ([0.001, 0.012, 0.003, 0.004], "j2"),            # T < λ
    ([0.001, -0.001, 0.0, 0.0], "j2 .* ≥ 0"),
    ([0.001, float("nan"), 0.0, 0.0], "delays_s"),
    ([0.001, 0.002], "shape"),
])
def test_delay_correction_rejects_bad_delays(lam, words):
    with pytest.raises(TrajectoryError, match=words):
        delay_corrected_velocities([1.0, 1.0, 1.0, 1.0], T, lam)


@pytest.mark.parametrize("delta, seg, words", [
    ([1.0, float("inf"), 0, 0], T, "delta_deg"), ([1.0, 1, 0, 0], 0.0, "segment_s"),
    ([1.0, 1, 0, 0], float("nan"), "segment_s"), ([1.0, 1, 0, 0], -0.01, "segment_s"),
])
def test_delay_correction_rejects_bad_numbers(delta, seg, words):
    with pytest.raises(TrajectoryError, match=words):
        delay_corrected_velocities(delta, seg, np.zeros(4))


# --------------------------------------------------------------------------- planning
def test_plan_has_equal_cartesian_steps_converted_by_ik():
    plan = plan_line(ROBOT, A, B, 12, T)
    assert plan.joints_deg.shape == (13, 4) and plan.poses.shape == (13, 4)
    np.testing.assert_allclose(np.diff(plan.poses, axis=0), np.tile((np.array(B) - A) / 12, (12, 1)),
                               atol=1e-12)
    for pose, q in zip(plan.poses, plan.joints_deg):
        np.testing.assert_allclose(ROBOT.fk(q), pose, atol=1e-9)
        assert q[1] > 0  # right elbow throughout
    assert [s.index for s in plan.segments] == list(range(1, 13))
    np.testing.assert_allclose([s.start_s for s in plan.segments], np.arange(12) * T)
    np.testing.assert_allclose(plan.velocities_deg_s, np.diff(plan.joints_deg, axis=0) / T)
    np.testing.assert_allclose(plan.segments[-1].target_deg, ROBOT.ik(np.array(B)))


def test_line_joints_are_the_plans_way_points():
    for law in ("linear", "smooth"):
        plan = plan_line(ROBOT, A, B, 12, T, time_law=law)
        poses, joints = line_joints(ROBOT, A, B, 12, T, time_law=law)
        assert np.array_equal(poses, plan.poses) and np.array_equal(joints, plan.joints_deg)
        assert joints.flags.writeable                     # the caller's to adjust
    with pytest.raises(TrajectoryError, match="segment_s"):
        line_joints(ROBOT, A, B, 12, 0.0)


def test_a_way_point_unwrapped_past_its_limit_is_named():
    """θ4 comes back from the inverse kinematics wrapped to ±180°; unwrapped along the move
    it may leave a narrower range, and the first point that does is named."""
    g = ROBOT.g
    narrow = Scara(g.model_copy(update={"limits": (*g.limits[:3], (-180.0, 180.0))}))
    for plan in (plan_line, line_joints):
        with pytest.raises(TrajectoryError, match=r"interpolation point 11 of 12: j4 = 187.5323 is outside"):
            plan(narrow, (300.0, -60.0, -30.0, 100.0), (300.0, 60.0, -30.0, 250.0), 12, T)


def test_plan_corrects_each_joint_with_its_own_station_delay():
    order = ("j2", "j4", "j1", "j3")
    lam = joint_delays(0.002, order)
    plan = plan_line(ROBOT, A, B, 8, T, lam, station_order=order)
    assert plan.station_order == order
    np.testing.assert_allclose(plan.delays_s, [0.006, 0.002, 0.008, 0.004])
    delta = np.diff(plan.joints_deg, axis=0)
    np.testing.assert_allclose(plan.velocities_deg_s * (T - lam), delta, atol=1e-9)


def test_plan_is_read_only():
    plan = plan_line(ROBOT, A, B, 4, T)
    with pytest.raises(ValueError):
        plan.joints_deg[0, 0] = 1.0
    with pytest.raises(AttributeError):
        plan.segment_s = 1.0


def test_seed002_home_pose_is_a_valid_start():
    # seed 002's example starts at (400, 0, −50, 0): arm stretched, all joints zero
    plan = plan_line(ROBOT, (400, 0, -50, 0), (300, 0, -20, 45), 20, T)
    np.testing.assert_allclose(plan.joints_deg[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(ROBOT.fk(plan.joints_deg[-1]), [300, 0, -20, 45], atol=1e-9)


@pytest.mark.parametrize("kwargs, words", [
    (dict(n_points=0), "n_points"), (dict(n_points=2.5), "n_points"),
    (dict(segment_s=0.0), "segment_s"), (dict(segment_s=float("nan")), "segment_s"),
    (dict(start_pose=(300, float("nan"), -30, 0)), "start_pose"),
    (dict(end_pose=(300, 0, -30)), "end_pose"),
    (dict(delays_s=[0.001, 0.002, 0.003, 0.011]), "j4"),
    (dict(station_order=("j1", "j2")), "station_order"),
])
def test_plan_rejects_bad_input(kwargs, words):
    args = dict(robot=ROBOT, start_pose=A, end_pose=B, n_points=4, segment_s=T)
    args.update(kwargs)
    with pytest.raises(TrajectoryError, match=words):
        plan_line(**args)


def test_plan_names_the_unreachable_interpolation_point():
    # both ends reachable, but the line passes within 103.5 mm of the base where j2 would
    # have to fold beyond its 150° limit (first at interpolation point 1)
    with pytest.raises(TrajectoryError, match=r"interpolation point 1 of 4 .* j2") as exc:
        plan_line(ROBOT, (80, -120, -30, 0), (80, 120, -30, 0), 4, T)
    assert isinstance(exc.value, CellError)
    with pytest.raises(TrajectoryError, match="out of reach"):
        plan_line(ROBOT, A, (500, 0, -30, 0), 4, T)


# --------------------------------------------------------------------------- simulation
def test_corrected_joints_reach_every_point_together():
    lam = joint_delays(0.002)
    plan = plan_line(ROBOT, A, B, 10, T, lam)
    q = joint_positions_at(plan, lam, np.arange(11) * T)
    np.testing.assert_allclose(q, plan.joints_deg, atol=1e-9)
    sim = simulate_line(ROBOT, plan, lam)
    np.testing.assert_allclose(sim.xyz_mm[sim.point_index], plan.poses[:, :3], atol=1e-9)
    assert max_line_deviation(sim.xyz_mm[sim.point_index], A[:3], B[:3]) < 1e-9
    assert sim.times_s[-1] == pytest.approx(10 * T)  # nobody is late at the end


def test_uncorrected_joints_lag_behind_by_their_delay():
    lam = joint_delays(0.002)
    plan = plan_line(ROBOT, A, B, 10, T)
    sim = simulate_line(ROBOT, plan, lam)
    at_points = max_line_deviation(sim.xyz_mm[sim.point_index], A[:3], B[:3])
    assert at_points > 0.01  # mm: the bend seed 002 describes
    # each joint is exactly its own delay late
    t = np.array([0.035, 0.062])
    late = joint_positions_at(plan, lam, t)
    for j in range(4):
        on_time = joint_positions_at(plan, np.zeros(4), t - lam[j])
        np.testing.assert_allclose(late[:, j], on_time[:, j], atol=1e-9)
    assert sim.times_s[-1] == pytest.approx(10 * T + lam.max())


def test_no_delay_uncorrected_plan_reaches_the_points():
    plan = plan_line(ROBOT, A, B, 6, T)
    sim = simulate_line(ROBOT, plan, np.zeros(4), samples_per_segment=10)
    np.testing.assert_allclose(sim.xyz_mm[sim.point_index], plan.poses[:, :3], atol=1e-9)


def test_late_station_takes_the_next_command_from_where_it_is():
    # planned for 1 ms, actually 3 ms late: j1 never gets to finish a segment before the next
    plan = plan_line(ROBOT, A, B, 5, T, np.full(4, 0.001))
    actual = np.array([0.003, 0.001, 0.001, 0.001])
    q = joint_positions_at(plan, actual, [T + 0.003])
    w = plan.segments[0].velocity_deg_s[0]
    assert q[0, 0] == pytest.approx(plan.joints_deg[0, 0] + w * (T - 0.001), abs=1e-9)
    end = simulate_line(ROBOT, plan, actual)
    np.testing.assert_allclose(end.joints_deg[-1], plan.joints_deg[-1], atol=1e-9)


@pytest.mark.parametrize("actual, words", [([0.0, -0.001, 0, 0], "j2"), ([0, 0, float("nan"), 0], "actual"),
                                           ([0.0, 0.0], "shape")])
def test_simulation_rejects_bad_delays(actual, words):
    plan = plan_line(ROBOT, A, B, 3, T)
    with pytest.raises(TrajectoryError, match=words):
        simulate_line(ROBOT, plan, actual)
    with pytest.raises(TrajectoryError, match="samples_per_segment"):
        simulate_line(ROBOT, plan, np.zeros(4), samples_per_segment=0)
    with pytest.raises(TrajectoryError, match="times_s"):
        joint_positions_at(plan, np.zeros(4), np.zeros((2, 2)))


def test_tool_positions_match_forward_kinematics():
    rng = np.random.default_rng(0)
    q = np.column_stack([rng.uniform(-90, 90, 20), rng.uniform(10, 140, 20),
                         rng.uniform(0, 100, 20), rng.uniform(-180, 180, 20)])
    np.testing.assert_allclose(tool_positions(ROBOT, q), [ROBOT.fk(r)[:3] for r in q], atol=1e-9)


def test_line_deviation_is_perpendicular_distance():
    path = np.array([[0.0, 1.0, 0.0], [5.0, 0.0, -2.0], [20.0, 0.0, 0.0]])
    assert max_line_deviation(path, (0, 0, 0), (10, 0, 0)) == pytest.approx(2.0)
    assert max_line_deviation(path[:1], (0, 0, 0), (0, 0, 0)) == pytest.approx(1.0)
    with pytest.raises(TrajectoryError, match="path_xyz_mm"):
        max_line_deviation(np.zeros((3, 2)), (0, 0, 0), (1, 0, 0))
    with pytest.raises(TrajectoryError, match="start_xyz_mm"):
        max_line_deviation(path, (0, 0, float("inf")), (1, 0, 0))


# --------------------------------------------------------------------------- CLI
LINE = ["plan", "line", "--robot", "seed002", "--from", "400,0,-50,0", "--to", "300,0,-20,45",
        "--points", "20", "--segment-ms", "10", "--sigma-ms", "1"]


def test_cli_line_prints_segments_and_deviation(capsys):
    assert cli.main(LINE) == 0
    out = capsys.readouterr().out
    assert out.count("\n") >= 24
    assert "max deviation from the line, uncorrected" in out
    assert "max deviation from the line, corrected" in out


def test_cli_line_json(capsys):
    assert cli.main(LINE + ["--json", "--stations", "j2,j1,j3,j4"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["segments"]) == 20
    assert doc["delays_ms"] == pytest.approx([2.0, 1.0, 3.0, 4.0])
    seg = doc["segments"][4]
    lam = np.array(doc["delays_ms"]) / 1e3
    np.testing.assert_allclose(np.array(seg["velocity_corrected"]) * (T - lam),
                               np.array(seg["velocity_uncorrected"]) * T, atol=1e-9)
    assert doc["deviation"]["corrected"]["at_points_mm"] < 1e-9


@pytest.mark.parametrize("extra, words", [
    (["--sigma-ms", "3"], "not longer than the delay of j4"),
    (["--stations", "j1,j2,j2,j4"], "--stations"),
    (["--points", "0"], "n_points"),
    (["--to", "600,0,-20,0"], "out of reach"),
])
def test_cli_line_bad_input_exits_2(capsys, extra, words):
    assert cli.main(LINE + extra) == 2
    assert words in capsys.readouterr().err


def test_cli_line_malformed_pose_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["plan", "line", "--from", "400,0,x,0", "--to", "300,0,-20,45"])
    assert exc.value.code == 2
    assert "--from" in capsys.readouterr().err
