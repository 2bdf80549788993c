"""Degenerate campaigns (issue 22, "Bad input"): a clear answer, never a traceback, never a
confident cause, from ``cellctl diagnose`` and ``cellctl calibrate kinematics``.

What is refused and what is answered (the reason is in :mod:`cell.measurements`):

* refused by the readers, naming file, line, column or joint: a value that is not finite
  (CSV cell, model.yaml, URDF), one pose, all poses at one place, a URDF chain that does not
  reach the named tip;
* answered: a joint that never moves (its angle-dependent effects are not identifiable and
  must be listed so), a sensor frame that drifts with sample order.

The real CLI runs as a process on a few campaigns written here; the readers' refusals are
checked in-process over every variant. Planar data come from the two-link SCARA written out
below (link lengths of the format document's example, 325 and 275 mm); chain data from the
independent forward model :mod:`cell.truth.chain` (the UR5 of :mod:`cell.truth.chain_campaign`).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cell.measurements import CampaignFormatError, read_campaign
from cell.truth import chain as truth
from cell.truth.chain_campaign import MARKERS, UR5

REPO = Path(__file__).resolve().parents[2]
L1, L2 = 325.0, 275.0                      # cell/measurements.md, model.yaml example


# ------------------------------------------------------------------ campaigns
def planar(d: Path, q: np.ndarray, offset_deg=(0.05, 0.0), dirs: np.ndarray | None = None,
           noise_mm: float = 0.01, seed: int = 0, paths: str | None = None) -> Path:
    """A SCARA campaign: poses ``q`` (N, 2) deg, the true joint offsets ``offset_deg``,
    optional approach directions ``dirs`` (N, 2)."""
    rng = np.random.default_rng(seed)
    d.mkdir(parents=True, exist_ok=True)
    (d / "model.yaml").write_text(f"format: cell-measurements/1\nkinematics: scara\nl1_mm: {L1}\nl2_mm: {L2}\n")
    head = "sample,time_s,j1_deg,j2_deg,x_mm,y_mm" + (",j1_dir,j2_dir" if dirs is not None else "")
    rows = [head]
    for i, (a, b) in enumerate(np.asarray(q, float)):
        t1 = math.radians(a + offset_deg[0])
        t12 = t1 + math.radians(b + offset_deg[1])
        x = L1 * math.cos(t1) + L2 * math.cos(t12) + rng.normal(0, noise_mm)
        y = L1 * math.sin(t1) + L2 * math.sin(t12) + rng.normal(0, noise_mm)
        cells = [str(i), repr(2.0 * i), repr(float(a)), repr(float(b)), repr(float(x)), repr(float(y))]
        cells += [] if dirs is None else [str(int(v)) for v in dirs[i]]
        rows.append(",".join(cells))
    (d / "points.csv").write_text("\n".join(rows) + "\n")
    if paths is not None:
        (d / "paths.csv").write_text(paths)
    return d


def planar_poses(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-90, 90, n), rng.uniform(20, 140, n)])


def chain(d: Path, q: np.ndarray, effects: dict, sensor: bool = True, drift=(0.0, 0.0),
          seed: int = 0, noise_mm: float = 0.05) -> Path:
    """A UR5 chain campaign of poses ``q`` (P, 6) deg with ``effects`` (see
    :mod:`cell.truth.chain`), measured by a tracker at an unknown pose (``sensor``) or in the
    base frame. ``drift`` = (mm along the sensor's x, deg about its z) reached by the last
    pose, growing linearly with sample order: a tracker that slowly moves."""
    rng = np.random.default_rng(seed)
    R = truth.random_rotation(rng) if sensor else np.eye(3)
    t = rng.uniform(-800, 800, 3) if sensor else np.zeros(3)
    rows = []
    for p, qp in enumerate(np.asarray(q, float)):
        s = p / max(len(q) - 1, 1)
        a = math.radians(drift[1] * s)
        Rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        tp = t + np.array([drift[0] * s, 0.0, 0.0])
        rows += [[p] + r[1:] for r in truth.campaign_rows(UR5, False, qp[None], MARKERS, effects,
                                                          Rz @ R, tp, noise_mm, rng)]
    d.mkdir(parents=True, exist_ok=True)
    model = {"format": "cell-measurements/1", "kinematics": "dh", "dh_convention": "standard",
             "joints": UR5, "measurement_frame": "sensor" if sensor else "base", "markers": "unknown"}
    (d / "model.yaml").write_text(yaml.safe_dump(model, sort_keys=False))
    out = ["sample," + ",".join(f"j{k}" for k in range(1, 7)) + ",marker,x_mm,y_mm,z_mm"]
    for r in rows:
        out.append(",".join([str(r[0])] + [repr(float(v)) for v in r[1:7]] + [str(r[7])]
                            + [repr(float(v)) for v in r[8:]]))
    (d / "points.csv").write_text("\n".join(out) + "\n")
    return d


def chain_poses(n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-150, 150, (n, 6))
    q[:, 1] = rng.uniform(-160, -20, n)            # the arm above its base
    return q


ARM_URDF = """<robot name="arm">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="tool"/><link name="side"/><link name="lost"/>
  <joint name="q1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="q2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="q3" type="revolute"><parent link="l2"/><child link="tool"/><origin xyz="0.25 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="s" type="fixed"><parent link="base"/><child link="side"/><origin xyz="0 0.2 0"/></joint>
</robot>
"""


def urdf_campaign(d: Path, base="base", tip="tool", urdf=ARM_URDF) -> Path:
    """A 3-joint URDF arm (links base → l1 → l2 → tool, and a side link on the base)."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "arm.urdf").write_text(urdf)
    (d / "model.yaml").write_text(yaml.safe_dump(
        {"format": "cell-measurements/1", "kinematics": "urdf", "urdf": "arm.urdf", "base_link": base,
         "tip_link": tip, "joints": ["q1", "q2", "q3"], "markers": {0: [0.0, 0.0, 0.0]}}, sort_keys=False))
    q = np.random.default_rng(3).uniform(-90, 90, (12, 3))
    rows = ["sample,j1,j2,j3,x_mm,y_mm,z_mm"] + [f"{i},{a:.3f},{b:.3f},{c:.3f},1.0,2.0,3.0"
                                                   for i, (a, b, c) in enumerate(q)]
    (d / "points.csv").write_text("\n".join(rows) + "\n")
    return d


# ------------------------------------------------------------------ the CLI as a process
def cellctl(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), CELL_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "cell.cli", *args], cwd=REPO, env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)


def refused(out: subprocess.CompletedProcess, command: str) -> str:
    """The one error line of a refused command (exit 2, nothing on stdout, no traceback)."""
    assert out.returncode == 2, (out.returncode, out.stdout[-2000:], out.stderr[-2000:])
    assert "Traceback" not in out.stderr, out.stderr
    assert out.stdout == "", out.stdout[-2000:]
    lines = out.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"cellctl {command}: error: "), out.stderr
    return lines[0]


def answered(out: subprocess.CompletedProcess) -> dict:
    """The JSON report of a diagnosis that ran (exit 0, no traceback)."""
    assert out.returncode == 0, (out.returncode, out.stderr[-2000:])
    assert "Traceback" not in out.stderr, out.stderr
    return json.loads(out.stdout)


def not_confident(report: dict) -> bool:
    """No confident cause: none, unexplained, or a named cause whose confidence is not high."""
    cause = report["cause"]
    return cause["effect"] == "none" or report.get("unexplained") is True or cause.get("confidence") != "high"


# ------------------------------------------------------------------ refused, seen from the CLI
def test_planar_single_pose_one_place_and_nan_are_refused_by_diagnose(tmp_path):
    q = planar_poses(40)
    single = planar(tmp_path / "single", q[:1])
    one_place = planar(tmp_path / "one", np.repeat(q[:1], 40, axis=0))
    nan = planar(tmp_path / "nan", q)
    rows = (nan / "points.csv").read_text().splitlines()
    cells = rows[6].split(",")
    cells[4] = "nan"                                          # x_mm of line 7
    rows[6] = ",".join(cells)
    (nan / "points.csv").write_text("\n".join(rows) + "\n")

    msg = refused(cellctl("diagnose", str(single)), "diagnose")
    assert "single/points.csv, line 2, column 'j1_deg': one pose (sample 0" in msg
    msg = refused(cellctl("diagnose", str(one_place), "--json"), "diagnose")
    assert "one/points.csv, line 2, column 'j1_deg': all 40 poses at one place" in msg
    msg = refused(cellctl("diagnose", str(nan)), "diagnose")
    assert "nan/points.csv, line 7, column 'x_mm': not a finite number: 'nan'" in msg


@pytest.mark.parametrize("command", [("diagnose",), ("calibrate", "kinematics", "--dry-run")])
def test_chain_one_place_nan_model_and_unreachable_tip_are_refused(tmp_path, command):
    one_place = chain(tmp_path / "one", np.repeat(chain_poses(1), 30, axis=0), {"offset": {"j2": 0.05}})
    nan = chain(tmp_path / "nan", chain_poses(30), {})
    text = (nan / "model.yaml").read_text()
    (nan / "model.yaml").write_text(text.replace("a_mm: -425.0", "a_mm: .nan", 1))
    nan_line = 1 + text[:text.index("a_mm: -425.0")].count("\n")
    tip = urdf_campaign(tmp_path / "tip", base="l1", tip="side")
    name = command[0] if command[0] == "diagnose" else "calibrate"

    def run(d):
        return refused(cellctl(*command[:2 if name == "calibrate" else 1], str(d), *command[2:]), name)

    assert "one/points.csv, line 2, column 'j1': all 30 poses at one place" in run(one_place)
    msg = run(nan)
    assert f"nan/model.yaml, line {nan_line}, column 'joints.1.a_mm': joint 2 (column j2): must be a finite " \
           "number" in msg
    msg = run(tip)
    assert ("tip/model.yaml, line 5, column 'tip_link': no path from base_link 'l1' to tip_link 'side' in "
            "arm.urdf: 'side' hangs from base → side; below 'l1' are 'l2', 'tool'") in msg


# ------------------------------------------------------------------ answered, seen from the CLI
def test_planar_joint_that_never_moves_is_not_named(tmp_path):
    """j1 stays at 10° (and so keeps its last direction) while its offset is the truth: its
    angle-dependent effects are listed as not identifiable, and no confident cause on j1."""
    q = planar_poses(60)
    q[:, 0] = 10.0
    dirs = np.column_stack([np.ones(60), np.random.default_rng(2).choice([-1.0, 1.0], 60)])
    d = planar(tmp_path / "frozen", q, offset_deg=(0.05, 0.0), dirs=dirs)
    report = answered(cellctl("diagnose", str(d), "--json"))
    frozen = {"j1_gear_ratio_rel", "j1_cyclic1_sin_deg", "j1_backlash_deg"}
    assert frozen <= set(report["not_identifiable"]), report["not_identifiable"]
    assert all("j1" in report["not_identifiable"][k] for k in frozen)     # the reason names the joint
    if "j1" in report["cause"]["joints"]:
        assert not_confident(report), report["cause"]


def test_planar_joint_that_never_moves_is_never_named_confidently(tmp_path):
    """A true j1 offset with j1 frozen at 10°: a constant angle error on j1 is all the
    campaign can see, and a gear ratio or cyclic error on a joint that never moves looks
    just like it (their definitions' ``mimics``). So joint_offset[j1] may be named, but not
    with confidence high, and the untestable rivals are listed with the reason."""
    q = planar_poses(60)
    q[:, 0] = 10.0
    dirs = np.column_stack([np.ones(60), np.random.default_rng(2).choice([-1.0, 1.0], 60)])
    report = answered(cellctl("diagnose", str(planar(tmp_path / "frozen", q, dirs=dirs)), "--json"))
    cause = report["cause"]
    if "j1" in cause["joints"]:
        assert not_confident(report), cause
        rivals = {r["label"]: r for r in cause.get("rivals", [])}
        for lab in ("gear_ratio[j1]", "cyclic_error[j1]"):
            assert lab in rivals and rivals[lab]["testable"] is False, cause
            assert "j1 spans 0.0° < 20.0°" in rivals[lab]["why"], rivals[lab]


def test_chain_joint_that_never_moves_is_not_named_confidently(tmp_path):
    q = chain_poses(40)
    q[:, 2] = -30.0                                            # j3 never moves
    report = answered(cellctl("diagnose", str(chain(tmp_path / "frozen", q, {"offset": {"j3": 0.05}})), "--json"))
    if "j3" in report["cause"]["joints"]:
        assert not_confident(report), report["cause"]


def test_chain_joint_that_never_moves_is_listed_not_identifiable(tmp_path):
    q = chain_poses(40)
    q[:, 2] = -30.0
    report = answered(cellctl("diagnose", str(chain(tmp_path / "frozen", q, {"offset": {"j3": 0.05}})), "--json"))
    assert "j3_gear_ratio_rel" in report["not_identifiable"], report["not_identifiable"]
    assert "j3" not in report["cause"]["joints"], report["cause"]


def drifting(tmp_path: Path, name: str, effects: dict) -> dict:
    """The diagnosis of a campaign whose tracker turns 0.05° about its z over the campaign
    while the poses sweep j1 in order (a common way to walk an arm)."""
    q = chain_poses(60)
    q = q[np.argsort(q[:, 0])]
    return answered(cellctl("diagnose", str(chain(tmp_path / name, q, effects, drift=(0.0, 0.05))), "--json"))


def test_chain_sensor_frame_that_drifts_gets_no_confident_cause(tmp_path):
    """No arm effect at all: the drift must not come out as a confident arm cause (before
    commit 7808c18 it came out as gear_ratio[j1], confidence high)."""
    report = drifting(tmp_path, "drift", {})
    assert not_confident(report), report["cause"]


def test_chain_sensor_frame_drift_beside_a_true_cause_is_said(tmp_path):
    """A true j2 offset and the same drift: before cell/diagnosis/chain/drift.py,
    joint_offset[j2] + gear_ratio[j1] (the drift) came out with confidence high, and nothing
    mentioned the drift. The poses walk j1 in order, so a drifting frame and a j1 effect
    look alike: the answer must not be confident, and must say the frame may have moved
    (as a rival, or as a reason the gap is unexplained)."""
    report = drifting(tmp_path, "drift", {"offset": {"j2": 0.05}})
    assert set(report["cause"]["params"]) == {"j2_offset_deg"} or not_confident(report), report["cause"]
    said = report["remainder"]["reasons"] + report["cause"]["warnings"]
    assert any("sample order" in r for r in said), said


def test_chain_sensor_frame_drift_over_random_order_is_said(tmp_path):
    """The same drift with the poses in random order: no joint effect can mimic it, so
    the frame's motion is named as the reason the gap is not explained."""
    q = chain_poses(60)
    rep = answered(cellctl("diagnose", str(chain(tmp_path / "r", q, {"offset": {"j2": 0.05}},
                                                  drift=(2.0, 0.05))), "--json"))
    assert rep["unexplained"] is True and not_confident(rep), rep["cause"]
    assert any("sample order" in r for r in rep["remainder"]["reasons"]), rep["remainder"]


# ------------------------------------------------------------------ the readers, in-process
def _refusal(d: Path) -> str:
    with pytest.raises(CampaignFormatError) as exc:
        read_campaign(d)
    return str(exc.value)


@pytest.mark.parametrize("column, value", [("x_mm", "nan"), ("y_mm", "inf"), ("j1_deg", "-inf"),
                                           ("time_s", "NaN"), ("j2_dir", "nan")])
def test_planar_cells_that_are_not_finite(tmp_path, column, value):
    q = planar_poses(10)
    d = planar(tmp_path / "c", q, dirs=np.ones((10, 2)))
    rows = (d / "points.csv").read_text().splitlines()
    head = rows[0].split(",")
    cells = rows[4].split(",")
    cells[head.index(column)] = value
    rows[4] = ",".join(cells)
    (d / "points.csv").write_text("\n".join(rows) + "\n")
    assert f"points.csv, line 5, column {column!r}: not a finite number: {value!r}" in _refusal(d)


@pytest.mark.parametrize("key, value, line", [("l1_mm", ".inf", 3), ("command_unit_deg", ".nan", 5),
                                              ("joint_limits_deg", "[[-132, .inf], [-145, 145]]", 5),
                                              ("camera", "{center_mm: [.nan, 150.0]}", 5)])
def test_planar_model_numbers_that_are_not_finite(tmp_path, key, value, line):
    d = planar(tmp_path / "c", planar_poses(10))
    text = (d / "model.yaml").read_text()
    text = text.replace("l1_mm: 325.0", f"l1_mm: {value}") if key == "l1_mm" else text + f"{key}: {value}\n"
    (d / "model.yaml").write_text(text)
    msg = _refusal(d)
    assert f"model.yaml, line {line}, column '{key}" in msg and "finite number" in msg, msg


@pytest.mark.parametrize("edit, column", [
    (lambda m: m["joints"][1].update(a_mm=float("nan")), "joints.1.a_mm"),
    (lambda m: m["joints"][2].update(theta_deg=float("inf")), "joints.2.theta_deg"),
    (lambda m: m["joints"][2].update(limits=[float("-inf"), 10.0]), "joints.2.limits.0"),
    (lambda m: m.update(tool_mm=[0.0, float("nan"), 0.0]), "tool_mm.1"),
    (lambda m: m.update(markers={1: [float("inf"), 0, 0], 2: [0, 0, 0], 3: [1, 1, 1]}), "markers.1.0"),
    (lambda m: m.update(coupling=[{"joint": "j3", "from": "j2", "factor": float("nan")}]), "coupling.0.factor"),
    (lambda m: m.update(gravity=[0.0, float("nan"), -1.0]), "gravity.1"),
])
def test_chain_model_numbers_that_are_not_finite(tmp_path, edit, column):
    d = chain(tmp_path / "c", chain_poses(10), {})
    model = yaml.safe_load((d / "model.yaml").read_text())
    edit(model)
    (d / "model.yaml").write_text(yaml.safe_dump(model, sort_keys=False))
    msg = _refusal(d)
    assert f"column {column!r}" in msg and "must be a finite number" in msg and ", line " in msg, msg
    if column.startswith("joints."):
        k = int(column.split(".")[1]) + 1
        assert f"joint {k} (column j{k})" in msg


@pytest.mark.parametrize("old, new, line, words", [
    ('<origin xyz="0.3 0 0"/>', '<origin xyz="nan 0 0"/>', 5, "joint 'q2': origin xyz nan 0 0 is not finite"),
    ('<origin xyz="0.25 0 0"/>', '<origin xyz="0.25 0 0" rpy="0 inf 0"/>', 7, "joint 'q3': origin rpy 0 inf 0"),
    ('<axis xyz="0 0 1"/>', '<axis xyz="nan 0 1"/>', 3, "joint 'q1': axis nan 0 1 is not finite"),
    ('lower="-3" upper="3"', 'lower="nan" upper="3"', 3, "joint 'q1': limit lower/upper nan 3 is not finite"),
])
def test_urdf_numbers_that_are_not_finite(tmp_path, old, new, line, words):
    d = urdf_campaign(tmp_path / "u", urdf=ARM_URDF.replace(old, new, 1))
    assert f"arm.urdf, line {line}: {words}" in _refusal(d)


@pytest.mark.parametrize("base, tip, words", [
    ("l1", "side", "'side' hangs from base → side; below 'l1' are 'l2', 'tool'"),
    ("base", "lost", "'lost' is attached to no joint; below 'base' are 'l1', 'side', 'l2', 'tool'"),
    ("tool", "l1", "'l1' hangs from base → l1; below 'tool' are no links"),
])
def test_urdf_chain_that_does_not_reach_the_tip(tmp_path, base, tip, words):
    d = urdf_campaign(tmp_path / "u", base=base, tip=tip)
    msg = _refusal(d)
    assert (f"model.yaml, line 5, column 'tip_link': no path from base_link {base!r} to tip_link {tip!r} "
            f"in arm.urdf: {words}") in msg, msg
    d = urdf_campaign(tmp_path / "v", tip="nowhere")
    assert "model.yaml, line 5, column 'tip_link': tip_link 'nowhere' is not a link of arm.urdf" in _refusal(d)


PATHS_STILL = "move,time_s,j1_cmd_deg,j2_cmd_deg,x_mm,y_mm\n0,0.0,5,50,1,2\n0,0.1,5,50,1,2\n"
PATHS_MOVING = "move,time_s,j1_cmd_deg,j2_cmd_deg,x_mm,y_mm\n0,0.0,5,50,1,2\n0,0.1,6,51,1,2\n"


@pytest.mark.parametrize("n, paths, file, words", [
    (1, None, "points.csv", "line 2, column 'j1_deg': one pose (sample 0, j1_deg 5, j2_deg 50)"),
    (7, None, "points.csv", "line 2, column 'j1_deg': all 7 poses at one place (j1_deg 5, j2_deg 50 in every row)"),
    (3, PATHS_STILL, "points.csv", "line 2, column 'j1_deg': all 3 poses at one place"),
])
def test_planar_one_place_is_refused(tmp_path, n, paths, file, words):
    d = planar(tmp_path / "c", np.tile([5.0, 50.0], (n, 1)), paths=paths)
    msg = _refusal(d)
    assert f"{file}, {words}" in msg and "measure poses spread over the joints' ranges" in msg, msg


def test_planar_second_place_or_moving_paths_are_read(tmp_path):
    """Two places, or one pose beside moves that do move, are valid (if weak) campaigns."""
    q = np.tile([5.0, 50.0], (7, 1))
    q[3] = [5.0, 50.001]
    assert read_campaign(planar(tmp_path / "a", q)).points["j2_deg"][3] == 50.001
    assert read_campaign(planar(tmp_path / "b", q[:1], paths=PATHS_MOVING)).paths is not None
    still = planar(tmp_path / "c", q[:1])
    (still / "points.csv").unlink()
    (still / "paths.csv").write_text(PATHS_STILL)
    assert "paths.csv, line 2, column 'j1_cmd_deg': all 2 poses at one place" in _refusal(still)


@pytest.mark.parametrize("sensor", [True, False])
def test_chain_single_pose_and_one_place_are_refused(tmp_path, sensor):
    q = chain_poses(1)
    msg = _refusal(chain(tmp_path / "one", q, {}, sensor=sensor))            # 3 markers, one pose
    assert "points.csv, line 2, column 'j1': one pose (sample 0, j1 " in msg, msg
    msg = _refusal(chain(tmp_path / "many", np.repeat(q, 20, axis=0), {}, sensor=sensor))
    assert "points.csv, line 2, column 'j1': all 20 poses at one place" in msg, msg


def test_joints_that_never_move_are_read(tmp_path):
    """A joint that never moves is a valid campaign (what it hides is the diagnosis's to say)."""
    q = planar_poses(20)
    q[:, 1] = 60.0
    assert set(read_campaign(planar(tmp_path / "p", q)).points["j2_deg"].tolist()) == {60.0}
    q = chain_poses(12)
    q[:, 2] = -30.0
    c = read_campaign(chain(tmp_path / "c", q, {}))
    assert c.n_poses == 12 and set(c.readings[:, 2].tolist()) == {-30.0}
