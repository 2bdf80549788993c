"""The one robot model of the cell, its calibration and its diagnosis.

Every robot is a serial chain of elementary transforms, whatever file it comes from
(``kinematics: scara``, ``dh`` or ``urdf``; see :mod:`cell.robots` and
``cell/measurements.md``):

* :mod:`.chain`     a model (DH rows or a URDF path) → one product of ops, as data (mm, deg)
* :mod:`.evaluate`  forward kinematics over many poses at once, and exact Jacobians (op
  twists) for any error parameter
* :mod:`.scara`     the cell's SCARA: its DH rows, and that chain's closed form for the
  control loop (inverse kinematics, limits, command units)

The names most callers need are importable from here.
"""
from cell.kinematics.chain import AXES, D2R, Chain, Joint, Op, dh_chain, urdf_chain
from cell.kinematics.evaluate import forward, gravity_levers, joint_axes, points, twist
from cell.kinematics.scara import (JOINT_NAMES, Elbow, PlanarArm, Scara, dh_rows, planar_xy,
                                   scara_chain)

__all__ = ["AXES", "D2R", "Chain", "Elbow", "JOINT_NAMES", "Joint", "Op", "PlanarArm", "Scara",
           "dh_chain", "dh_rows", "forward", "gravity_levers", "joint_axes", "planar_xy",
           "points", "scara_chain", "twist", "urdf_chain"]
