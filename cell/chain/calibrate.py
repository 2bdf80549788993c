"""Seed 001's differential error model fitted on a chain campaign, checked on held-out
poses, and written back as a model file in the same format (``cellctl calibrate
kinematics CAMPAIGN``). Pure numerics except :func:`write_calibrated`.

Parameters: every joint offset and every geometric parameter of the chain (DH a, α, d, θ;
URDF origin x, y, z, roll, pitch, yaw), offsets first. Those the campaign cannot see
beside the registration, or sees only as a sum with others, are left at nominal and
named (:func:`cell.chain.fit.identifiability`). Of the rest, the ones that improve the
leave-one-pose-out prediction are kept (:func:`cell.chain.rank.screen`): with tens of
poses, fitting all 40-odd identifiable parameters of a 7-joint arm would fit noise.

The check: the held-out poses (the campaign's split, or the diagnosis's generated one)
must be predicted better than by the nominal model with its own registration. A failed
check writes nothing.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cell.chain import fit as F
from cell.chain import rank
from cell.chain.campaign import ChainCampaign, ChainSpec, write_chain_campaign
from cell.chain.model import AXES, matrix_rpy, parse_urdf, rot, rpy_matrix, trans
from cell.chain.report import split_poses

FORMAT = "cell-chain-calibration/1"


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

    @property
    def passed(self) -> bool:
        return self.hold_after[0] < self.hold_before[0]

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
            "check": {"passed": self.passed,
                      "reason": ("held-out poses are predicted better than by the nominal model"
                                 if self.passed else "the calibrated model does not predict the "
                                 "held-out poses better than the nominal one")},
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
                            before, after, fit_d.n_poses, hold_d.n_poses, src)


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


def write_calibrated(cal: ChainCalibration, out_dir: Path | str) -> dict:
    """Write the calibrated model with the campaign's points to ``out_dir`` (a campaign
    directory: ``cellctl diagnose OUT_DIR`` runs on it; ``cellctl diagnose CAMPAIGN
    --model OUT_DIR/model.yaml`` too). Returns the written paths."""
    cc, values = cal.campaign, cal.fit.named()
    files: dict[str, str] = {}
    if cc.spec.kinematics == "dh":
        spec = cc.spec.model_copy(update={"joints": [type(cc.spec.joints[0])(**r) for r in _dh_rows(cc.spec, values)]})
    else:
        name = Path(cc.spec.urdf).stem + "_calibrated.urdf"
        files[name] = _urdf_text(cc, values)
        spec = cc.spec.model_copy(update={"urdf": name})
    note = f"calibrated by cellctl calibrate kinematics from {cc.directory}"
    spec = spec.model_copy(update={"source": f"{spec.source} [{note}]" if spec.source else note})
    d = write_chain_campaign(cc, out_dir, spec, files)
    return {"dir": str(d), "model": str(d / "model.yaml"), **({"urdf": str(d / n) for n in files})}
