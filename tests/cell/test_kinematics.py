"""Kinematics: FK/IK round trips over the workspace, Jacobian, units, and every bad input."""
import math

import numpy as np
import pytest

from cell.errors import KinematicsError
from cell.kinematics import Scara
from cell.robots import PRESETS, Geometry


@pytest.fixture(params=sorted(PRESETS))
def robot(request):
    return Scara.preset(request.param)


def test_seed000_start_pose_matches_paper():
    # seed 000 Table 1, group c: the start pose (π/3, π/6) is the point (250.0000, 933.0127)
    x, y = Scara.preset("seed000").fk_planar(60, 30)
    assert (round(x, 4), round(y, 4)) == (250.0, 933.0127)


def test_seed002_home_pose():
    # seed 002: all joints zero -> tool at (400, 0, -50) with phi 0
    np.testing.assert_allclose(Scara.preset("seed002").fk([0, 0, 0, 0]), [400, 0, -50, 0], atol=1e-12)


@pytest.mark.parametrize("elbow", ["right", "left"])
def test_ik_fk_round_trip_over_workspace(robot, elbow):
    rng = np.random.default_rng(7)
    lo2, hi2 = (5, 145) if elbow == "right" else (-145, -5)
    for _ in range(400):
        q = np.array([rng.uniform(-160, 160), rng.uniform(lo2, hi2),
                      rng.uniform(*robot.g.limits[2]), rng.uniform(-170, 170)])
        pose = robot.fk(q)
        back = robot.ik(pose, elbow=elbow)
        np.testing.assert_allclose(back, q, atol=1e-8)
        np.testing.assert_allclose(robot.fk(back), pose, atol=1e-8)


def test_both_elbows_reach_the_same_point():
    r = Scara.preset("seed000")
    right, left = r.ik_planar(300, 700, "right"), r.ik_planar(300, 700, "left")
    assert right[1] > 0 > left[1]
    np.testing.assert_allclose(r.fk_planar(*right), r.fk_planar(*left), atol=1e-9)


def test_jacobian_matches_finite_differences(robot):
    q, h = np.array([35.0, 70.0]), 1e-6
    numeric = np.column_stack([(robot.fk_planar(*(q + dq)) - robot.fk_planar(*(q - dq))) / (2 * h)
                               for dq in (np.array([h, 0]), np.array([0, h]))])
    np.testing.assert_allclose(robot.jacobian(*q), numeric, rtol=1e-6, atol=1e-8)


def test_command_units_round_trip():
    r = Scara.preset("seed000")
    assert list(r.to_units([60.0, 30.0])) == [6000, 3000]
    assert list(r.to_units([-0.015, 0.004])) == [-2, 0]
    np.testing.assert_allclose(r.from_units([6016, 3000]), [60.16, 30.0])


@pytest.mark.parametrize("x, y, words", [
    (2000.0, 0.0, "out of reach"),
    (0.0, 0.0, "singularity"),             # l1 = l2: the origin is the folded singularity
    (999.99999, 0.0, "singularity"),
    (float("nan"), 1.0, "x_mm"),
    (1.0, float("inf"), "y_mm"),
])
def test_bad_targets_are_named(x, y, words):
    with pytest.raises(KinematicsError, match=words):
        Scara.preset("seed000").ik_planar(x, y)


def test_limits_violated_names_joint_and_value():
    r = Scara(Geometry(l1_mm=500, l2_mm=500, limits=((-10, 10), (-150, 150), (-200, 0), (-360, 360))))
    with pytest.raises(KinematicsError, match=r"j1 = .* outside its limits \[-10.0, 10.0\]"):
        r.ik_planar(0, 900)
    with pytest.raises(KinematicsError, match="j3"):
        r.check_limits([0, 30, 50, 0])


def test_bad_shapes_and_elbow():
    r = Scara.preset("seed002")
    with pytest.raises(KinematicsError, match="shape"):
        r.fk([1, 2, 3])
    with pytest.raises(KinematicsError, match="elbow"):
        r.ik_planar(300, 0, elbow="up")
    with pytest.raises(KinematicsError, match="j2"):
        r.to_units([1.0, math.nan])


def test_geometry_is_validated():
    with pytest.raises(ValueError, match="l1_mm"):
        Geometry(l1_mm=-1, l2_mm=500)
    with pytest.raises(ValueError, match="extra"):
        Geometry(l1_mm=1, l2_mm=1, l3_mm=2)
    with pytest.raises(ValueError, match="low"):
        Geometry(l1_mm=1, l2_mm=1, limits=((10, -10), (0, 1), (0, 1), (0, 1)))
    with pytest.raises(KeyError, match="known"):
        Scara.preset("puma")


def test_the_scara_is_a_chain_like_any_other(robot):
    """One robot model: the closed form the control loop uses (fk, jacobian) is the SCARA's
    chain (cell.kinematics.scara_chain) evaluated like a UR5's, pose for pose, and its
    Jacobian is that chain's op twists."""
    from cell.kinematics import forward, twist
    rng = np.random.default_rng(11)
    lims = np.array(robot.g.limits, float)
    q = rng.uniform(lims[:, 0] * 0.9, lims[:, 1] * 0.9, size=(40, 4))
    T, starts = forward(robot.chain, q, keep=True)
    closed = np.array([robot.fk(row) for row in q])
    np.testing.assert_allclose(T[:, :3, 3], closed[:, :3], atol=1e-9)
    heading = np.degrees(np.arctan2(T[:, 1, 0], T[:, 0, 0]))
    np.testing.assert_allclose((heading - closed[:, 3] + 180.0) % 360.0 - 180.0, 0.0, atol=1e-9)
    every = np.arange(len(q))
    for k in (0, 1):
        col = twist(robot.chain, starts, robot.chain.joint_op[k], T[:, :3, 3], every)[:, :2]
        want = np.array([robot.jacobian(a, b)[:, k] for a, b in q[:, :2]])
        np.testing.assert_allclose(col, want, atol=1e-9)
    assert [j.type for j in robot.chain.joints] == ["revolute", "revolute", "prismatic", "revolute"]
    assert [(j.lower, j.upper) for j in robot.chain.joints] == [tuple(v) for v in robot.g.limits]


@pytest.mark.parametrize("elbow", ["right", "left"])
def test_ik_rows_is_ik_of_each_row_to_the_bit(robot, elbow):
    from cell.calibration.calfile import CalibratedScara
    rng = np.random.default_rng(11)
    lo2, hi2 = (5, 145) if elbow == "right" else (-145, -5)
    q = np.column_stack([rng.uniform(-160, 160, 300), rng.uniform(lo2, hi2, 300),
                         rng.uniform(*robot.g.limits[2], 300), rng.uniform(-170, 170, 300)])
    calibrated = CalibratedScara(robot, (0.01, -0.02), (0.3, -0.2), "v1-test")
    for r in (robot, calibrated):
        poses = np.array([r.fk(row) for row in q])
        rows = r.ik_rows(poses, elbow)
        assert rows.tobytes() == np.array([r.ik(p, elbow=elbow) for p in poses]).tobytes()


def test_ik_rows_is_none_where_ik_raises_for_a_row(robot):
    d3 = sum(robot.g.limits[2]) / 2
    poses = np.array([robot.fk([10, 40, d3, 5]), robot.fk([20, 50, d3, 5])])
    assert robot.ik_rows(poses).shape == (2, 4)
    for bad in ([math.nan, 0, 0, 0],                                     # not finite
                [robot.g.l1_mm + robot.g.l2_mm + 1, 0, -50, 0],          # out of reach
                [*robot.fk([10, 40, d3, 0])[:2], 1e6, 0]):                # j3 beyond its limits
        assert robot.ik_rows(np.vstack([poses, bad])) is None
        with pytest.raises(KinematicsError):
            robot.ik(bad)
    assert robot.ik_rows(poses, elbow="up") is None
    assert robot.ik_rows(poses[0]) is None                                # not (N, 4)
