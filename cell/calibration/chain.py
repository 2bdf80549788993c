"""Seed 001's differential error model fitted on a chain campaign, checked on held-out
poses, and written back as a model file in the same format (``cellctl calibrate
kinematics CAMPAIGN``). Pure numerics except :func:`write_calibrated`.

Parameters: every joint offset and every geometric parameter of the chain (DH a, α, d, θ;
URDF origin x, y, z, roll, pitch, yaw), offsets first. Those the campaign cannot see
beside the registration, or sees only as a sum with others, are left at nominal and
named (:func:`cell.diagnosis.chain.fit.identifiability`). Of the rest, the ones that improve the
leave-one-pose-out prediction are kept (:func:`cell.diagnosis.chain.rank.screen`): with tens of
poses, fitting all 40-odd identifiable parameters of a 7-joint arm would fit noise.

The check (:mod:`cell.calibration.check`): the held-out poses (the campaign's split, or
the diagnosis's generated one) must be predicted better in rms than by the nominal model
with its own registration, and neither their rms nor their max may get worse; and the
fit's residual σ per axis must not be far above the measurement noise, estimated apart
from the fit: from revisited poses when there are some and they agree with the sensor
noise (they then hold the arm's repeatability too), else from the markers' rigid
constellation within each pose (:mod:`cell.diagnosis.chain.noise`). A failed check writes nothing,
unless the caller accepts it (``accept_worse``): the written directory then holds the
warning in ``calibration.json`` and in ``model.yaml``'s ``source``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import json
import math

import numpy as np

from cell.calibration import check as C
from cell.diagnosis.chain import fit as F
from cell.diagnosis.chain import rank
from cell.diagnosis.chain.noise import estimate
from cell.diagnosis.chain.report import split_poses
from cell.jsonsafe import json_safe
from cell.kinematics.chain import AXES, matrix_rpy, parse_urdf, rot, rpy_matrix, trans
from cell.measurements.chain import ChainCampaign, ChainSpec, DHRow, write_chain_campaign

FORMAT = "cell-chain-calibration/1"
CALIBRATION_FILE = "calibration.json"   #: the report, written beside model.yaml


@dataclass
class ChainCalibration:
    campaign: ChainCampaign
    nominal: F.Fit
    fit: F.Fit
    dropped: dict[str, str]
    not_selected: list[str]
    hold_before: tuple[float, float]
    hold_after: tuple[float, float]
    fit_poses: int
    hold_poses: int
    split_source: str
    noise: C.Noise

    @property
    def verdict(self) -> C.Verdict:
        (b, bmax), (a, amax) = self.hold_before, self.hold_after
        other = () if a < b else (f"held-out rms {b:.4g} → {a:.4g} mm: not better than the nominal model",)
        return C.Verdict((C.Figure("rms", b, a, "mm"), C.Figure("max", bmax, amax, "mm")),
                         (self.noise,), other)

    @property
    def passed(self) -> bool:
        return self.verdict.passed

    def report(self) -> dict:
        f, (b, bmax), (a, amax) = self.fit, self.hold_before, self.hold_after
        return {
            "format": FORMAT, "source": self.campaign.source,
            "split": {"source": self.split_source, "fit_poses": self.fit_poses,
                      "holdout_poses": self.hold_poses},
            "registration": f.reg.as_dict(self.campaign.spec.measurement_frame == "sensor",
                                          self.campaign.spec.markers == "unknown", self.campaign.markers),
            "parameters": {p.name: {"value": round(float(v), 9), "se": round(float(se), 9),
                                    "low": round(float(lo), 9), "high": round(float(hi), 9),
                                    "unit": p.unit}
                           for p, v, se, (lo, hi) in zip(f.params, f.values, f.se, f.ci95)},
            "not_identifiable": self.dropped,
            "not_selected": self.not_selected,
            "identifiability": dict(zip(("rank", "columns", "condition"), f.conditioning()))
            | {"note": "of the column-scaled Jacobian at the solution, registration included"},
            "fit": {"rms_before_mm": round(self.nominal.rms, 6), "rms_after_mm": round(f.rms, 6),
                    "cv_rms_before_mm": round(self.nominal.cv_rms, 6), "cv_rms_after_mm": round(f.cv_rms, 6)},
            "holdout": {"rms_before_mm": round(b, 6), "rms_after_mm": round(a, 6),
                        "max_before_mm": round(bmax, 6), "max_after_mm": round(amax, 6),
                        "shrink": round(1 - a / b, 4) if b > 0 else 0.0},
            "check": self.verdict.as_dict(),
        }


def calibrate_chain(cc: ChainCampaign) -> ChainCalibration:
    """Fit offsets and geometric parameters on the fit poses of ``cc`` (see module doc)."""
    fit_mask, src = split_poses(cc)
    d = F.Data.of(cc)
    fit_d, hold_d = d.subset(fit_mask), d.subset(~fit_mask)
    F.check_registrable(fit_d, str(cc.directory / "points.csv"))
    f0 = F.fit(fit_d, [])
    pool = [p for p in F.vocabulary(cc.chain) if p.effect in ("joint_offset", "link_length")]
    ident = F.identifiability(fit_d, pool, f0.reg)
    chosen = rank.screen(fit_d, f0, ident.kept)
    f = F.fit(fit_d, chosen, f0.reg)
    before = F.predict_rms(hold_d, f0)
    after = F.predict_rms(hold_d, f)
    return ChainCalibration(cc, f0, f, ident.dropped, [p.name for p in ident.kept if p not in chosen],
                            before, after, fit_d.n_poses, hold_d.n_poses, src, _noise(cc, fit_d, f))


def _noise(cc: ChainCampaign, fit_d: F.Data, f: F.Fit) -> C.Noise:
    """The fit's residual σ per axis against the measurement noise the diagnosis judges
    with too (:func:`cell.diagnosis.chain.noise.estimate`)."""
    dof = f.J.shape[0] - f.J.shape[1]
    resid = math.sqrt(float(np.sum(f.resid ** 2)) / dof) if dof > 0 else math.nan
    n = estimate(cc, fit_d.xyz, fit_d.obs_pose, fit_d.obs_marker, f.reg.markers,
                 fit_d.known_markers is None)
    source = n.source if n.sigma is not None else "no revisited poses, fewer than 3 markers per pose"
    return C.noise_check(resid, dof, n.sigma, n.dof, source, "mm")


def _dh_rows(spec: ChainSpec, values: dict[str, float]) -> list[dict]:
    rows = []
    for k, j in enumerate(spec.joints):
        col = f"j{k + 1}"
        r = j.model_dump()
        own = "theta_deg" if j.type == "revolute" else "d_mm"
        r[own] += values.get(f"{col}_offset_{'deg' if j.type == 'revolute' else 'mm'}", 0.0)
        for f in ("a_mm", "alpha_deg", "d_mm", "theta_deg"):
            r[f] += values.get(f"{col}_{f}", 0.0)
        rows.append(r)
    return rows


def _urdf_text(cc: ChainCampaign, values: dict[str, float]) -> str:
    path = cc.directory / cc.spec.urdf
    robot = parse_urdf(path.read_text(encoding="utf-8"))
    for j in cc.chain.joints:
        col = f"{j.column}_"
        js = robot.joint_map[j.name]
        o = js.origin
        T = rpy_matrix(np.asarray(o.xyz, float) * 1000.0, o.rpy)
        D = (trans(AXES["x"], values.get(col + "x_mm", 0.0)) @ trans(AXES["y"], values.get(col + "y_mm", 0.0))
             @ trans(AXES["z"], values.get(col + "z_mm", 0.0)) @ rot(AXES["x"], values.get(col + "roll_deg", 0.0))
             @ rot(AXES["y"], values.get(col + "pitch_deg", 0.0)) @ rot(AXES["z"], values.get(col + "yaw_deg", 0.0)))
        axis = np.asarray(js.axis, float) / np.linalg.norm(js.axis)
        off = values.get(f"{col}offset_{j.unit}", 0.0)
        D = D @ (rot(axis, off) if j.type == "revolute" else trans(axis, off))
        xyz, rpy = matrix_rpy(T @ D)
        o.xyz, o.rpy = [v / 1000.0 for v in xyz], rpy
    return robot.to_xml_string()


def write_calibrated(cal: ChainCalibration, out_dir: Path | str, accept_worse: bool = False) -> dict:
    """Write the calibrated model with the campaign's points to ``out_dir`` (a campaign
    directory: ``cellctl diagnose OUT_DIR`` runs on it; ``cellctl diagnose CAMPAIGN
    --model OUT_DIR/model.yaml`` too) and the report as ``calibration.json``. Returns the
    written paths and the ``warning`` (None when the check passed).
    Raises ValueError when the check failed and ``accept_worse`` is not set (nothing is
    written); with it, the warning goes into ``calibration.json`` (``accept_worse``,
    ``warning``) and into ``model.yaml``'s ``source``."""
    verdict = cal.verdict
    if not verdict.passed and not accept_worse:
        raise ValueError(f"held-out check failed, nothing written: {verdict.reason()}")
    warn = None if verdict.passed else C.warning(verdict)
    cc, values = cal.campaign, cal.fit.named()
    files: dict[str, str] = {}
    if cc.spec.kinematics == "dh":
        spec = replace(cc.spec, joints=[DHRow(**r) for r in _dh_rows(cc.spec, values)])
    else:
        name = Path(cc.spec.urdf).stem + "_calibrated.urdf"
        files[name] = _urdf_text(cc, values)
        spec = replace(cc.spec, urdf=name)
    note = f"calibrated by cellctl calibrate kinematics from {cc.directory}"
    note += f"; WARNING: {warn}" if warn else ""
    spec = replace(spec, source=f"{spec.source} [{note}]" if spec.source else note)
    urdf = {"urdf": n for n in files}
    report = cal.report() | {"accept_worse": warn is not None, "warning": warn}
    files[CALIBRATION_FILE] = json.dumps(json_safe(report), indent=2, allow_nan=False) + "\n"
    d = write_chain_campaign(cc, out_dir, spec, files)
    return {"dir": str(d), "model": str(d / "model.yaml"), "report": str(d / CALIBRATION_FILE),
            **{k: str(d / n) for k, n in urdf.items()}, "warning": warn}
