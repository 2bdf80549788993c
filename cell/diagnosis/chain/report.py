"""``cellctl diagnose`` for a chain campaign: the ``cell-diagnosis/1`` report with the
chain additions of ``cell/measurements.md`` (Extension v1.1): ``registration`` (sensor
frame, marker positions, what they absorb), the gap after registration alone, the cause
named by :mod:`cell.diagnosis.chain.rank`, and the holdout on poses the fit never saw.

Split: the campaign's ``split`` column when present; otherwise 30 % of the poses, drawn
with the fixed seed :data:`SPLIT_SEED` (the v1 diagnosis's), whole poses at a time.
Noise: ``--noise-mm``, else the scatter of revisited poses (same joint readings) when it
agrees with the sensor noise seen within each pose's rigid marker constellation, else that
sensor noise, else unknown (:func:`_noise`, :mod:`cell.diagnosis.chain.noise`). Revisits that
disagree beyond the sensor noise make the gap unexplained: every vocabulary effect is a
function of the readings, so they should agree.

A planar campaign read as a chain (``cc.planar``) also gets the v1 report's figures with
their v1 meaning (:mod:`cell.diagnosis.chain.planar`, ``cell/measurements.md`` "Format
version 1.3"): a consumer of the v1 report reads it as before.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.diagnosis.chain import fit as F
from cell.diagnosis.chain import rank
from cell.diagnosis.chain import robust
from cell.diagnosis import tie
from cell.diagnosis.chain.noise import estimate
from cell.diagnosis.noise import upper95
from cell.diagnosis.words import DEPENDS_TEXT, FORMAT, FORMAT_VERSION, describe_cause
from cell.measurements import CampaignFormatError
from cell.measurements.campaign import HOLDOUT_SHARE, SPLIT_SEED
from cell.measurements.chain import ChainCampaign


def split_poses(cc: ChainCampaign) -> tuple[np.ndarray, str]:
    """(P,) True for fit poses, and where the split came from."""
    if cc.split is not None:
        fit = cc.split == "fit"
        if not fit.any() or fit.all():
            raise CampaignFormatError(cc.directory / "points.csv", "split has no "
                                      + ("fit" if not fit.any() else "holdout") + " poses", column="split")
        return fit, cc.split_source or "campaign"
    P = cc.n_poses
    n_hold = int(round(HOLDOUT_SHARE * P))
    if P - n_hold < 3 or n_hold < 1:
        raise CampaignFormatError(cc.directory / "points.csv", f"{P} poses: too few to hold any out "
                                  "(need at least 5)", column="sample")
    rng = np.random.default_rng(SPLIT_SEED)
    fit = np.ones(P, bool)
    fit[rng.choice(P, n_hold, replace=False)] = False
    return fit, f"generated ({100 * HOLDOUT_SHARE:.0f} % of poses, seed {SPLIT_SEED})"


def _noise(cc: ChainCampaign, fit_d: F.Data, f0: F.Fit, given: float | None,
           keep: np.ndarray | None = None, best: F.Fit | None = None
           ) -> tuple[float | None, float, str, str | None]:
    """(σ per axis, its degrees of freedom (inf: given), where it came from, the reason to
    call the gap unexplained when revisited poses disagree beyond the sensor noise, or
    None): a given σ first, else :func:`cell.diagnosis.chain.noise.estimate`, its last
    resort the remainder of ``best`` (the candidate that predicts left-out poses best;
    default ``f0``). ``keep`` (M,) marks the campaign's points that are not outliers;
    ``fit_d`` holds only such points."""
    q = fit_d.chain.model_values(fit_d.readings)[fit_d.obs_pose]
    n = estimate(cc, fit_d.xyz, fit_d.obs_pose, fit_d.obs_marker, f0.reg.markers,
                 fit_d.known_markers is None, keep, remainder=(q, (best or f0).resid))
    if given is not None:
        return given, math.inf, "given", n.disagree
    return n.sigma, n.dof, n.source, n.disagree


def _r(v, nd: int = 6):
    return None if v is None or not math.isfinite(v) else round(float(v), nd)


def _params(c: rank.Candidate) -> tuple[dict, dict]:
    f = c.fit
    return ({p.name: _r(v, 9) for p, v in zip(f.params, f.values)},
            {p.name: [_r(lo, 9), _r(hi, 9)] for p, (lo, hi) in zip(f.params, f.ci95)})


def _components(c: rank.Candidate) -> list[dict]:
    """Per effect of a candidate: its joints, its parameters and their rms displacement of
    the points, mm."""
    f = c.fit
    nr = f.J.shape[1] - len(f.params)
    out = []
    for e in c.effects:
        idx = [nr + i for i, p in enumerate(f.params) if p.effect == e]
        disp = (f.J[:, idx] @ f.values[[i - nr for i in idx]]).reshape(-1, c.fit.resid.shape[1])
        joints = {f"j{p.joint + 1}" for p in f.params if p.effect == e and p.on_joint}
        out.append({"effect": e, "joints": sorted(joints, key=lambda s: int(s[1:])),
                    "params": {p.name: _r(v, 9) for p, v in zip(f.params, f.values) if p.effect == e},
                    "rms_mm": _r(F.rms3(disp))})
    return sorted(out, key=lambda x: -(x["rms_mm"] or 0))


def _entry(c: rank.Candidate) -> dict:
    params, ci = _params(c)
    rk, cols, cond = c.fit.conditioning()
    comps = _components(c)
    for x in comps:
        x["params"] = {n: v for p, (n, v) in zip(c.fit.params, params.items()) if p.effect == x["effect"]}
    return {"effect": comps[0]["effect"] if comps else "none", "components": comps, "fit": "full",
            "label": c.label, "effects": list(c.effects), "joints": c.joints, "k": len(c.fit.params),
            "params": params, "ci95": ci, "score": _r(c.fit.cv_rms), "cv_rms_mm": _r(c.fit.cv_rms),
            "fit_rms_mm": _r(c.fit.rms), "holdout_rms_mm": _r(c.hold_rms), "identifiable": rk == cols,
            "rank": rk, "columns": cols, "condition": _r(cond, 1)}


@dataclass
class ChainDiagnosis:
    """The report and what it was computed from (the HTML page's plots need the fits);
    ``reading`` the planar campaign's rows beside them (:class:`.planar.Reading`) when the
    campaign is a planar one read as a chain, else None."""

    report: dict
    search: rank.Search
    decision: rank.Decision
    reading: object = None


def diagnose_chain(cc: ChainCampaign, noise_mm: float | None = None) -> dict:
    """The report (a JSON-ready dict) for chain campaign ``cc``; ``noise_mm`` is σ per axis
    of one point measurement if known. Raises CampaignFormatError for data that cannot be
    diagnosed (too few poses, a sensor frame the fit poses cannot fix)."""
    return diagnose_chain_full(cc, noise_mm).report


def diagnose_chain_full(cc: ChainCampaign, noise_mm: float | None = None) -> ChainDiagnosis:
    """:func:`diagnose_chain` with the search and decision behind the report."""
    given = noise_mm
    fit_mask, split_src = split_poses(cc)
    d_all = F.Data.of(cc)
    fit_all, hold_d = d_all.subset(fit_mask), d_all.subset(~fit_mask)
    F.check_registrable(fit_all, str(cc.directory / "points.csv"))
    s, outl, _ = robust.robust_search(fit_all, hold_d)
    fit_d = s.fit_d
    f0 = s.nominal.fit
    keep = np.ones(len(cc.xyz), bool)
    keep[fit_mask[cc.obs_pose]] = ~outl.fit
    keep[~fit_mask[cc.obs_pose]] = ~outl.hold
    noise_mm, noise_dof, noise_src, drift = _noise(cc, fit_d, f0, noise_mm, keep,
                                                   robust.reference(s))
    # judged against what the noise may be, not its estimate: a σ from one revisited pose
    # (two degrees of freedom) must not make a gap look systematic
    noise_hi = None if noise_mm is None else upper95(noise_mm, noise_dof)
    dec = rank.decide(s, noise_hi, noise_mm)
    if noise_src.startswith("residual") and not dec.unexplained:
        dec.notes.append("the noise was estimated from the remainder itself (no revisited poses, "
                         "no --noise-mm): a gap that is not smooth over the poses cannot be told "
                         "from noise; give --noise-mm or measure some poses twice")
    dec.warnings += outl.warnings
    if outl.n:
        cut = f"{outl.cut_mm:.3f} mm" if len(outl.scales) < 2 else " (static poses), ".join(
            f"{c:.3f} mm" for _, _, c in outl.scales.values()) + " (measured moves)"
        dec.notes.append(f"{outl.n} measured point(s) lie beyond {cut} of the best "
                         "candidate's residual and were set aside as outliers (outliers)")
    dec.notes += outl.notes
    if drift:
        dec.reasons.append(drift)
        dec.unexplained = True
    # every parameter is in one effect's pool, so the pools' drops cover the vocabulary;
    # "absorbed by the registration" does not depend on which pool a parameter was in
    not_ident = {n: why for e in s.idents.values() for n, why in e.dropped.items()}
    absorbed = {n: why for n, why in not_ident.items() if "registration" in why}
    warnings = sorted({w for c in s.ranking[:1] if c.ident for w in c.ident.warnings.values()})
    named = dec.chosen or s.nominal
    before, after = s.nominal.hold_rms, named.hold_rms
    shrink = 1 - after / before if before > 0 else 0.0
    in_before, in_after = s.nominal.hold_in_rms, named.hold_in_rms
    in_shrink = 1 - in_after / in_before if in_before > 0 else 0.0
    if dec.chosen is not None:
        comps = _components(dec.chosen)
        main = comps[0]["effect"]
        params, ci = _params(dec.chosen)
        joints = comps[0]["joints"]
        cause = {"effect": main, "joints": joints, "params": params, "ci95": ci,
                 "subsystem": F.SUBSYSTEM[main], "components": comps}
        subsystem, depends = F.SUBSYSTEM[main], F.DEPENDS_ON[main]
    else:
        cause = {"effect": "none", "joints": [], "params": {}, "ci95": {}, "subsystem": "none",
                 "components": []}
        subsystem, depends, joints = "none", "position", []
    cause["confidence"] = dec.confidence
    cause["warnings"] = dec.warnings
    cause["label"] = dec.chosen.label if dec.chosen is not None else "none"
    testable = fit_d.folds()[1] >= rank.MIN_FOLDS and tie.testable(fit_d.folds()[1])
    cause["selection"] = {
        "method": "leave-one-out prediction over "
                  + ("places (poses that share one are left out together)"
                     if fit_d.folds()[1] < fit_d.n_poses else "poses")
                  + ", then fewest parameters",
        "folds": fit_d.folds()[1], "alpha": rank.ALPHA, "rival_ratio": rank.RIVAL_RATIO,
        "named": cause["label"],
        "best": s.ranking[0].label if s.ranking else None,
        "places": fit_d.folds()[1], "testable": testable,
        "nominal_cv_rms_mm": _r(f0.cv_rms),
        "notes": [] if testable else [f"{fit_d.folds()[1]} folds: too few for the test over folds "
                                      f"to reach alpha {rank.ALPHA}"],
        "table": [{"label": c.label, "k": len(c.fit.params), "cv_rms_mm": _r(c.fit.cv_rms),
                   "tied": any(c is t for t in dec.tied)} for c in s.ranking]}
    cause["rivals"] = [{"label": c.label, "effects": list(c.effects), "joints": c.joints,
                        "k": len(c.fit.params), "cv_rms_mm": _r(c.fit.cv_rms),
                        "holdout_rms_mm": _r(c.hold_rms), "params": _params(c)[0]}
                       for c in dec.rivals] + dec.drift_rivals + dec.untestable
    cause["separating_poses"] = rank.separating_poses(s, dec.chosen, dec.rivals, noise_mm)
    cause["test"] = {"p_value": _r(dec.p_value, 8), "alpha": rank.ALPHA,
                     "method": "one-sided Wilcoxon signed-rank over fit poses of the "
                               "leave-one-pose-out error, vs registration alone",
                     "runner_up": dec.runner_up.label if dec.runner_up else None,
                     "runner_up_p_value": _r(dec.runner_up_p, 8),
                     "runner_up_fit": "full" if dec.runner_up else None}
    pr = None
    if cc.planar is not None:   # the v1 figures' code (the planar replay) only for a planar reading
        from cell.diagnosis.chain import planar
        pr = planar.reading(cc, d_all, fit_mask, keep, s, dec)
    if pr is not None:          # what the gap varies with, as v1 has it (cell/measurements.md)
        gap_v1, wh = planar.gap(pr)
        depends = wh.depends_on
    chain = cc.chain
    summary = (f"After registration the gap is {f0.rms:.3f} mm rms over {len(fit_d.xyz)} points "
               f"({fit_d.n_poses} poses)" if pr is None else
               f"The gap is {gap_v1['rms_mm']:.4f} mm rms over {gap_v1['n']} rows ("
               f"{gap_v1['points']['n']} points, {gap_v1['paths']['n']} path samples)")
    if cause["effect"] == "none":
        summary += "; no effect of the chain vocabulary is supported"
    else:
        summary += f"; it {DEPENDS_TEXT[depends]} and the best-supported cause is {describe_cause(cause)}"
    summary += (", but most of it is left unexplained." if dec.unexplained else ".")
    n_reg = F.n_registration(fit_d)
    rep = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "source": cc.source,
        "chain": {"kinematics": chain.kind, "convention": chain.convention or None,
                  "joints": {j.column: {"name": j.name, "type": j.type, "unit": j.unit}
                             for j in chain.joints},
                  "markers": cc.markers, "measurement_frame": cc.spec.measurement_frame}
        | ({} if len(cc.axes) == 3 else {"sensor_axes": list(cc.spec.sensor_axes)}),
        "registration": f0.reg.as_dict(fit_d.sensor, fit_d.known_markers is None, cc.markers)
        | {"parameters": n_reg, "condition": _r(f0.conditioning()[2], 1), "rms_mm": _r(f0.rms),
           "absorbs": absorbed,
           "warnings": warnings,
           "note": "registration is nuisance, fitted first and with every candidate; "
                   "gap.rms_mm is the residual after registration alone"},
        "gap": {"rms_mm": _r(f0.rms), "max_mm": _r(float(np.sqrt((f0.resid ** 2).sum(1)).max())),
                "n": len(fit_d.xyz), "poses": fit_d.n_poses,
                "where": {"subsystem": subsystem, "joints": joints, "depends_on": depends,
                          "summary": summary}},
        "ranking": [_entry(c) for c in s.ranking],
        "cause": cause,
        "holdout": {"n": len(hold_d.xyz), "poses": hold_d.n_poses, "rms_before_mm": _r(before),
                    "rms_after_mm": _r(after), "shrink": _r(shrink, 4),
                    "max_before_mm": _r(s.nominal.hold_max), "max_after_mm": _r(named.hold_max),
                    "inliers": {"n": int((~outl.hold).sum()), "rms_before_mm": _r(in_before),
                                "rms_after_mm": _r(in_after), "shrink": _r(in_shrink, 4),
                                "max_before_mm": _r(s.nominal.hold_in_max),
                                "max_after_mm": _r(named.hold_in_max)}},
        "unexplained": dec.unexplained,
        "remainder": {"reasons": dec.reasons, "notes": dec.notes},
        "not_identifiable": not_ident,
        "outliers": robust.describe(outl, fit_all, hold_d, cc.pose_ids, np.flatnonzero(fit_mask),
                                    np.flatnonzero(~fit_mask), cc.markers),
        "noise": {"sigma_mm": _r(noise_mm, 7), "source": noise_src,
                  "dof": None if noise_mm is None or math.isinf(noise_dof) else int(noise_dof),
                  "upper95_mm": _r(noise_hi, 7),
                  "fit_rms_mm": _r((dec.chosen or s.nominal).fit.rms),
                  "cv_rms_mm": _r((dec.chosen or s.nominal).fit.cv_rms),
                  "registration_cv_rms_mm": _r(f0.cv_rms)},
        "split": {"source": split_src, "fit_poses": fit_all.n_poses, "holdout_poses": hold_d.n_poses,
                  "fit_rows": len(fit_all.xyz), "holdout_rows": len(hold_d.xyz)},
    }
    if pr is not None:
        _planar_fields(rep, pr, gap_v1, wh, d_all, dec, outl, given)
    return ChainDiagnosis(rep, s, dec, pr)


def _planar_fields(rep: dict, pr, gap_v1: dict, wh, d_all: F.Data,
                   dec: rank.Decision, outl: robust.Outliers, given: float | None) -> None:
    """Give the report of a planar campaign read as a chain the v1 report's figures with
    their v1 meaning (:mod:`cell.diagnosis.chain.planar`; ``cell/measurements.md``, "Format
    version 1.3"): the gap over every row with ``points`` / ``paths`` and where it lies,
    the holdout per table, the per-station lags, the noise's v1 figures, the outliers per
    table (the chain's list of them moves to ``outliers.marked``), the spread, the split's
    source per table, what an unexplained remainder varies with, and a cyclic error's
    parameters by their v1 names."""
    rep["chain"]["planar"] = True
    # the reading's own structure (d, α, a compliance with no lever in the plane): the same
    # for every planar campaign, so nothing a campaign could change
    rep["not_identifiable"] = {n: why for n, why in rep["not_identifiable"].items()
                               if why != F.NO_EFFECT}
    from cell.diagnosis.chain import planar
    from cell.diagnosis.figures import where_figures
    rep["gap"] = gap_v1 | {"where": rep["gap"]["where"] | where_figures(wh)}
    rep["holdout"] |= planar.holdout_tables(pr)
    rep["delay"] = planar.station_lags(pr, d_all, dec)
    rep["noise"] |= planar.noise(pr, given)
    marked = rep["outliers"].pop("points")
    rep["outliers"] |= planar.outlier_tables(pr, outl) | {"marked": marked}
    rep["spread"] = planar.spread(pr)
    rep["split"]["source"] = planar.split_source(pr)
    rep["remainder"] |= planar.remainder(pr, dec)
    for x in [rep["cause"]] + rep["ranking"]:      # the v1 parameter names beside the chain's
        for comp in x.get("components", []):
            comp["params"] |= planar.v1_params(comp["params"], {
                k: x["ci95"][k] for k in comp["params"] if k in x["ci95"]})[0]
        add, ci = planar.v1_params(x["params"], x["ci95"])
        x["params"] |= add
        x["ci95"] |= ci
