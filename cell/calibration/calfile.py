"""The robot calibration file (format ``cell-robot-calibration/1``) and the calibrated robot.

A kinematic calibration (seed 001, ``cellctl calibrate kinematics``) is written as one JSON
file: the identified DH errors with their 95 % intervals, the identifiability report, the
held-out check, the poses and measurements it came from, whom it belongs to (the cell's
name and its nominal robot's fingerprint) and a SHA-256 of all that. Files are versioned:
a new calibration gets the next ``version`` and the one it replaces is kept beside it as
``<name>.v<N>.json``; the active file is replaced atomically.

The cell applies the robot's own parameters (:data:`APPLIED`): the joint zeros of θ1, θ2
and the two link lengths; and from seed 004's sweeps (the optional ``joints`` section,
:mod:`cell.calibration.joint_terms`) the measured backlash, and the gear-ratio and cyclic
terms listed as ``applied`` there. The board's placement (``base.x``, ``base.y``) is the board's
error, not the robot's, and is only reported; the board's rotation cannot be told from
θ1's zero (they appear only as a sum) and is in ``j1.theta``.

:func:`load` refuses, with :class:`~cell.errors.CalibrationError` naming the file and the
cause, a file that is missing, not JSON, of another format, altered or cut (checksum), or
made for another cell or another nominal robot, or whose joint terms do not fit the robot.
Nothing is applied then.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np

from cell import paths
from cell.errors import CalibrationError, KinematicsError
from cell.kinematics import Elbow, Scara
from cell.robots import Geometry

FORMAT = "cell-robot-calibration/1"
_IK_STEPS = 6          #: fixed-point steps of the inverse through the joint terms (|d'| ≤ 0.05)
#: calibration parameter → (what the calibrated robot does with it, unit)
APPLIED = {"j1.theta": "θ1 zero", "j2.theta": "θ2 zero", "j1.a": "link 1 length",
           "j2.a": "link 2 length"}


def robot_fingerprint(robot: Scara) -> str:
    """SHA-256 (16 hex digits) of the nominal geometry: a calibration belongs to one."""
    text = json.dumps(robot.g.model_dump(mode="json"), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _digest(doc: dict) -> str:
    body = {k: v for k, v in doc.items() if k != "sha256"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def calibration_id(doc: dict) -> str:
    """Short id a cycle row records: ``v<version>-<first 8 of sha256>``."""
    return f"v{doc['version']}-{doc['sha256'][:8]}"


class CalibratedScara(Scara):
    """The nominal robot with the calibrated joint zeros and link lengths, and the joint
    terms of seed 004 the calibration applies.

    Commands stay in the nominal robot's terms (a command θ_cmd turns the joint to
    θ_cmd + Δθ + d(θ_cmd), d the applied gear-ratio and cyclic terms, ``joint_effects``);
    forward kinematics, its Jacobian and the inverse use the calibrated geometry, so a
    planned first move lands closer. Limits and command units are the nominal ones.
    ``calibration`` is the id of the file it came from; ``approach_dirs`` the side its poses
    took up backlash from (the zeros hold half of each band from that side);
    ``backlash_deg`` the band seed 004 measured on j1, j2 (0: not measured);
    ``arrival_scatter_mm`` the held-out rms of the calibration's check (0: not measured).
    """

    def __init__(self, nominal: Scara, offsets_deg, link_deltas_mm, calibration: str,
                 approach_dirs=Scara.approach_dirs, joint_effects=(), backlash_deg=(0.0, 0.0),
                 arrival_scatter_mm: float = 0.0):
        super().__init__(nominal.g)
        self.offsets = np.asarray(offsets_deg, dtype=float)
        self.calibration = calibration
        self.approach_dirs = (int(approach_dirs[0]), int(approach_dirs[1]))
        self.joint_effects = tuple(joint_effects)
        self.backlash_deg = (float(backlash_deg[0]), float(backlash_deg[1]))
        self.arrival_scatter_mm = float(arrival_scatter_mm)
        g = nominal.g
        self._true = Scara(g.model_copy(update={"l1_mm": g.l1_mm + float(link_deltas_mm[0]),
                                                "l2_mm": g.l2_mm + float(link_deltas_mm[1])}))

    def _turned(self, q_deg) -> tuple[np.ndarray, np.ndarray]:
        """(angles the joints turn to, their derivative by the command), each (N, 2), for
        commands (N, 2): θ_cmd + zero + the applied joint terms."""
        q = np.asarray(q_deg, dtype=float)
        if not self.joint_effects:
            return q + self.offsets, np.ones_like(q)
        from cell.calibration.joint_terms import joint_delta
        delta, slope = joint_delta(self.joint_effects, q)
        return q + self.offsets + delta, 1.0 + slope

    def fk_planar(self, t1_deg: float, t2_deg: float) -> np.ndarray:
        if self.joint_effects:
            t = self._turned([[t1_deg, t2_deg]])[0][0]
            return self._true.fk_planar(t[0], t[1])
        return self._true.fk_planar(t1_deg + self.offsets[0], t2_deg + self.offsets[1])

    @property
    def calibrated_geometry(self) -> Geometry:
        """The nominal geometry with the calibrated link lengths (zeros apart)."""
        return self._true.g

    def fk_planar_batch(self, q_deg) -> np.ndarray:
        if self.joint_effects:
            return self._true.fk_planar_batch(self._turned(q_deg)[0])
        return self._true.fk_planar_batch(np.asarray(q_deg, dtype=float) + self.offsets)

    def jacobian(self, t1_deg: float, t2_deg: float) -> np.ndarray:
        if self.joint_effects:
            t, slope = self._turned([[t1_deg, t2_deg]])
            return self._true.jacobian(t[0, 0], t[0, 1]) * slope[0]
        return self._true.jacobian(t1_deg + self.offsets[0], t2_deg + self.offsets[1])

    def ik_planar(self, x_mm: float, y_mm: float, elbow: Elbow = "right",
                  check_limits: bool = True) -> np.ndarray:
        q = self._true.ik_planar(x_mm, y_mm, elbow=elbow, check_limits=False) - self.offsets
        if self.joint_effects:            # θ + d(θ) = q, d small and slow: fixed-point steps
            from cell.calibration.joint_terms import joint_delta
            target = q.copy()
            for _ in range(_IK_STEPS):
                q = target - joint_delta(self.joint_effects, q[None])[0][0]
        q[0] = (q[0] + 180.0) % 360.0 - 180.0
        if check_limits:
            self.check_limits(q, joints=(0, 1))
        return q


def calibrated_robot(nominal: Scara, doc: dict) -> CalibratedScara:
    """The robot a loaded calibration describes (see :data:`APPLIED`). A file without
    ``approach_dirs`` was measured from below (+1, +1): the procedure has approached every
    pose that way since the format's first version. A file without ``joints`` and
    ``gear_ratio`` (every file before them) applies no joint term; one without a held-out
    check gives no arrival scatter."""
    p = {k: float(v["value"]) for k, v in doc["parameters"].items()}
    fx, backlash = [], (0.0, 0.0)
    if doc.get("joints") or doc.get("gear_ratio"):
        from cell.calibration import joint_terms
        fx = joint_terms.effects(doc.get("joints")) + joint_terms.gear_effects(doc.get("gear_ratio"))
        backlash = joint_terms.backlash_deg(doc.get("joints"))
    return CalibratedScara(nominal, (p.get("j1.theta", 0.0), p.get("j2.theta", 0.0)),
                           (p.get("j1.a", 0.0), p.get("j2.a", 0.0)), calibration_id(doc),
                           approach_dirs(doc), fx, backlash, arrival_scatter(doc))


def arrival_scatter(doc: dict) -> float:
    """The held-out rms (2-D, mm) of the calibration's check: how far arrivals lay from the
    calibrated model on poses the fit did not use (0 when the file has no check)."""
    v = ((doc.get("report") or {}).get("holdout") or {}).get("rms_xy_after_mm")
    try:
        v = float(v)
    except (TypeError, ValueError):
        return 0.0
    return v if math.isfinite(v) and v > 0 else 0.0


def approach_dirs(doc: dict) -> tuple[int, int]:
    """The side (θ1, θ2: +1 or −1) the calibration's poses were approached from.
    :raises ValueError: anything but two of +1 / −1."""
    dirs = doc.get("approach_dirs", list(Scara.approach_dirs))
    if not isinstance(dirs, list) or len(dirs) != 2 or any(d not in (1, -1) or isinstance(d, bool)
                                                           for d in dirs):
        raise ValueError(f"approach_dirs = {dirs!r}: must be two of +1 / -1 (θ1, θ2)")
    return int(dirs[0]), int(dirs[1])


def new_document(robot: Scara, cell: str, parameters: dict, report: dict, data: dict,
                 created_at: str, warning: str | None = None, joints: dict | None = None,
                 gear_ratio: dict | None = None) -> dict:
    """A calibration document (version and checksum are set by :func:`write`).
    ``parameters``: name → {value, se, low, high, unit}; ``report``: identifiability,
    held-out check and fit figures; ``data``: the poses and measurements; ``warning``: why
    a calibration whose check failed was written anyway (``--accept-worse``), stored with
    ``accept_worse: true`` (None: the check passed, ``accept_worse: false``); ``joints``: seed
    004's terms per joint and ``gear_ratio`` seed 001's own gear-ratio estimates
    (:mod:`cell.calibration.joint_terms`), each written only when given."""
    extra = {k: v for k, v in (("joints", joints), ("gear_ratio", gear_ratio)) if v}
    return {"format": FORMAT, "version": 0, "created_at": created_at, "cell": cell,
            "robot": {"name": robot.g.name, "fingerprint": robot_fingerprint(robot)},
            "approach_dirs": list(Scara.approach_dirs),
            "applied": sorted(APPLIED), "parameters": parameters, "report": report, "data": data,
            "accept_worse": warning is not None, "warning": warning, **extra}


def write(path, doc: dict) -> dict:
    """Write ``doc`` as the active calibration at ``path`` with the next version number;
    the file it replaces is kept as ``<stem>.v<N>.json``. Atomic (temporary file + rename)
    and the folder is created. Returns the document as written (version, sha256).
    Raises CalibrationError naming the file when it cannot be written (the active file is
    then the one that was there)."""
    path = Path(path)
    try:
        return _write(path, doc)
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot write the robot calibration: {exc}") from None


def _write(path: Path, doc: dict) -> dict:
    path.parent.mkdir(parents=True, exist_ok=True)
    version, keep_as = 1, None
    if path.exists():              # the one it replaces is kept beside it (a copy: the active
        try:                       # file stays in place until the new one is complete)
            old = int(json.loads(path.read_text(encoding="utf-8")).get("version", 0))
            version, keep_as = old + 1, path.with_name(f"{path.stem}.v{old}.json")
        except (ValueError, TypeError, AttributeError, UnicodeDecodeError):
            keep_as = path.with_name(f"{path.stem}.unreadable.json")
    doc = {**doc, "version": version}
    doc["sha256"] = _digest(doc)
    fd, tmp = paths.temp_beside(path)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
            f.flush()
            os.fsync(f.fileno())
        if keep_as is not None:
            shutil.copy2(path, keep_as)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return doc


def load(path, robot: Scara, cell: str) -> dict:
    """Read and check a calibration for the nominal ``robot`` of cell ``cell``.

    :raises CalibrationError: missing or unreadable file, not JSON, another format, a
        checksum that does not match (altered or cut), another cell, another nominal robot,
        or a parameter that is not a finite number.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibrationError(f"{path}: robot calibration not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read the robot calibration: {exc}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path}, line {exc.lineno}: corrupt robot calibration, not valid "
                               f"JSON: {exc.msg}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise CalibrationError(f"{path}: not a robot calibration (format {got!r}, expected {FORMAT!r})")
    if doc.get("sha256") != _digest(doc):
        raise CalibrationError(f"{path}: corrupt robot calibration: its checksum does not match its "
                               "content (edited or cut); run the calibration again or restore "
                               "the previous version")
    if doc.get("cell") != cell:
        raise CalibrationError(f"{path}: calibration belongs to cell {doc.get('cell')!r}, not to "
                               f"this cell {cell!r}")
    theirs, ours = doc.get("robot", {}).get("fingerprint"), robot_fingerprint(robot)
    if theirs != ours:
        raise CalibrationError(f"{path}: calibration belongs to another robot "
                               f"({doc.get('robot', {}).get('name')!r}, fingerprint {theirs}); this "
                               f"cell's robot is {robot.g.name!r} ({ours})")
    try:
        approach_dirs(doc)
    except ValueError as exc:
        raise CalibrationError(f"{path}: corrupt robot calibration: {exc}") from None
    if "joints" in doc or "gear_ratio" in doc:
        from cell.calibration import joint_terms
        try:
            if "joints" in doc:
                joint_terms.check(doc["joints"])
            if "gear_ratio" in doc:
                joint_terms.check_gear_ratio(doc["gear_ratio"])
        except ValueError as exc:
            raise CalibrationError(f"{path}: the calibration's joint terms do not fit the robot "
                                   f"{robot.g.name!r}: {exc}") from None
    try:
        for name, v in doc["parameters"].items():
            if not np.isfinite(float(v["value"])):
                raise ValueError(name)
        calibrated_robot(robot, doc)
    except (KeyError, TypeError, ValueError, KinematicsError) as exc:
        raise CalibrationError(f"{path}: corrupt robot calibration: bad parameter {exc}") from None
    return doc
