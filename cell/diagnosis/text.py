"""The diagnosis report as readable lines: what ``cellctl diagnose`` prints without
``--json``, for a planar and a chain campaign alike. It reads only the report (the one
format, ``cell-diagnosis/1``), section by section, and prints what the report holds: a
section the report lacks (the chain's registration, the planar per-station lags) is left
out, so the text never says more or other than the JSON.

Sections, in order: the source; the chain and its registration; the gap and where it
lies; the ranking table; the cause with its parameters, confidence and warnings; how it
was chosen; its rivals and the poses that would separate them; the holdout; outliers;
noise; UNEXPLAINED and notes; the per-station lags; what the campaign cannot identify.
"""
from __future__ import annotations

from cell.diagnosis.page import describe_cause, fitted, pose_words



def _n(v, spec: str) -> str:
    """``v`` formatted with ``spec``; '–' for a figure the report leaves undefined (None: too
    few poses to leave any out, say)."""
    return "–" if v is None else format(v, spec)

def render(rep: dict) -> str:
    """The report ``rep`` as lines joined by newlines."""
    out = [f"Sim-to-real diagnosis of {rep.get('source', '')}"]
    for section in (_chain, _gap, _ranking, _cause, _selection, _rivals, _holdout, _outliers,
                    _noise, _remainder, _delay, _not_identifiable):
        out += section(rep)
    return "\n".join(out)


def _chain(rep: dict) -> list[str]:
    ch, reg = rep.get("chain"), rep.get("registration")
    if ch is None:
        return []
    seen = f", seeing {', '.join(ch['sensor_axes'])} only" if "sensor_axes" in ch else ""
    out = [f"chain: {ch['kinematics']}, {len(ch['joints'])} joints, markers {ch['markers']}, "
           f"measured in the {ch['measurement_frame']} frame{seen}"]
    if "sensor_frame" in reg:
        sf = reg["sensor_frame"]
        out.append(f"registration: sensor frame t = {sf['t_mm']} mm, rpy = {sf['rpy_deg']} deg")
    for m, p in reg.get("markers_mm", {}).items():
        out.append(f"  marker {m} in the tip frame: {p} mm")
    out += [f"  {n}: {why}" for n, why in reg["absorbs"].items()]
    out += [f"  warning: {w}" for w in reg["warnings"]]
    return out


def _gap(rep: dict) -> list[str]:
    g, w = rep["gap"], rep["gap"]["where"]
    if "points" in g:
        out = [f"gap: rms {_n(g['rms_mm'], '.4f')} mm, max {_n(g['max_mm'], '.4f')} mm over {g['n']} rows "
               f"(points {g['points']['n']}, path samples {g['paths']['n']})"]
    else:
        out = [f"gap after registration: rms {_n(g['rms_mm'], '.4f')} mm, max {_n(g['max_mm'], '.4f')} mm "
               f"over {g['n']} points ({g['poses']} fit poses)"]
    out.append(f"where: {w['summary']}")
    if "effect_sizes" in w:
        out.append("effect sizes (share of the gap's mean square each variable explains):")
        for k, v in sorted(w["effect_sizes"].items(), key=lambda kv: -kv[1]["r2"]):
            out.append(f"  {k:<12} {_n(100 * v['r2'], '6.1f')} %  {_n(v['rms_mm'], '.4f')} mm"
                       + (f"  ({v['joint']})" if v.get("joint") else ""))
    pj = w.get("per_joint_rms_deg", {})
    if pj.get("j1") is not None:
        out.append(f"per joint (joint space): j1 {_n(pj['j1'], '.5f')}°, j2 {_n(pj['j2'], '.5f')}° rms")
    return out


def _ranking(rep: dict) -> list[str]:
    rows = rep["ranking"]
    if "registration" not in rep:
        out = ["", "| rank | candidate | k | BIC | holdout rms mm | identifiable |",
               "|---:|---|---:|---:|---:|---|"]
        for i, r in enumerate(rows[:12], 1):
            out.append(f"| {i} | {r['label']} | {r['k']} | {_n(r['score'], '.1f')} | "
                       f"{_n(r['holdout_rms_mm'], '.4f')} | "
                       f"{'yes' if r['identifiable'] else 'no: ' + r.get('reason', '')} |")
        return out + [""]
    reg, h = rep["registration"], rep["holdout"]
    out = ["", "| rank | candidate | k | leave-one-pose-out rms mm | fit rms mm | holdout rms mm "
           "| condition |", "|---:|---|---:|---:|---:|---:|---:|",
           f"| – | registration only | 0 | {_n(rep['noise']['registration_cv_rms_mm'], '.4f')} | "
           f"{_n(reg['rms_mm'], '.4f')} | {_n(h['rms_before_mm'], '.4f')} | {_n(reg['condition'], '.3g')} |"]
    for i, r in enumerate(rows, 1):
        note = "" if r["identifiable"] else f", rank {r['rank']} of {r['columns']}"
        on = f" ({', '.join(r['joints'])})" if r["joints"] else ""
        out.append(f"| {i} | {r['label']}{on} | {r['k']} | "
                   f"{_n(r['cv_rms_mm'], '.4f')} | {_n(r['fit_rms_mm'], '.4f')} | {_n(r['holdout_rms_mm'], '.4f')} | "
                   f"{_n(r['condition'], '.3g')}{note} |")
    return out + [""]


def _cause(rep: dict) -> list[str]:
    c, t = rep["cause"], rep["cause"]["test"]
    if c["effect"] == "none":
        out = [f"cause: none (best candidate not significant: p = {_n(t['p_value'], '.3g')})"]
    else:
        bic = f", ΔBIC vs nominal {_n(t['delta_bic'], '.1f')}" if "delta_bic" in t else ""
        out = [f"cause: {describe_cause(c)} ({c['subsystem']}), p = {_n(t['p_value'], '.3g')}{bic}"]
        for n in fitted(rep):
            v, (lo, hi) = c["params"][n], c["ci95"][n]
            out.append(f"  {n} = {_n(v, '.6g')}  (95 % interval {_n(lo, '.6g')} … {_n(hi, '.6g')})")
        for j, o in c.get("cyclic_orders", {}).items():
            out.append(f"  {j}: {o['order']} cycle(s) per revolution (orders in the 95 % "
                       f"likelihood set: {', '.join(map(str, o['set95']))})")
        if t.get("runner_up"):
            m = t.get("runner_up_margin_bic")
            out.append(f"  runner-up: {t['runner_up']}"
                       + (f" (BIC {m:+.1f} worse)" if m is not None else "")
                       + (f" (p = {_n(t['runner_up_p_value'], '.3g')} that it predicts worse)"
                          if t.get("runner_up_p_value") is not None else ""))
    out.append(f"confidence: {c.get('confidence', 'high')}")
    return out + [f"  warning: {w}" for w in c.get("warnings", [])]


def _selection(rep: dict) -> list[str]:
    sel = rep["cause"].get("selection", {})
    if not sel.get("folds") or "places" not in sel:
        return []
    mm = "cv_rms_mm" in (sel["table"] or [{}])[0]
    out = [f"chosen by predicting left-out places ({sel['folds']} folds, {sel['places']} "
           "places): prediction rms " + ("in mm" if mm else "in noise units, 1 ≈ noise")]
    for x in sel["table"][:6]:
        mark = ("tied" if x["tied"] else "worse" if "p_worse_than_best" not in x
                else f"worse, p = {_n(x['p_worse_than_best'], '.2g')}")
        out.append(f"  {x['label']:<40} k {x['k']}  "
                   f"{_n(x['cv_rms_mm'], '.4f') if mm else _n(x['cv_rms'], '.3f')}  ({mark})")
    return out


def _rivals(rep: dict) -> list[str]:
    c, out = rep["cause"], []
    for r in c.get("rivals", []):
        on = f" on {', '.join(r['joints'])}" if "registration" in rep and r.get("joints") else ""
        pred = (f"leave-out rms {_n(r['cv_rms_mm'], '.4f')} mm" if "cv_rms_mm" in r
                else f"prediction rms {_n(r['cv_rms'], '.3f')}" if "cv_rms" in r else "")
        if r.get("testable") is False:
            out.append(f"  rival: {r['label']} (" + "; ".join(x for x in (pred, r["why"]) if x)
                       + ")")
            continue
        out.append(f"  rival: {r['label']}{on} (k {r['k']}, {pred}, holdout rms "
                   f"{_n(r['holdout_rms_mm'], '.4f')} mm)")
    for pz in c.get("separating_poses", []):
        diff = ", ".join(f"{k} {_n(v, '.4f')} mm" for k, v in pz["difference_mm"].items())
        out.append(f"  measure next: {pose_words(pz)}: differs from {diff}")
    return out


def _holdout(rep: dict) -> list[str]:
    h = rep["holdout"]
    poses = f"{h['poses']} poses, {h['n']} points" if "poses" in h else f"{h['n']} rows"
    return [f"holdout ({poses}): rms {_n(h['rms_before_mm'], '.4f')} -> {_n(h['rms_after_mm'], '.4f')} mm, "
            f"shrink {_n(h['shrink'], '.3f')}"]


def _outliers(rep: dict) -> list[str]:
    o, inl = rep.get("outliers") or {}, rep["holdout"].get("inliers") or {}
    if not o.get("n"):
        return []
    if isinstance(o["points"], list):
        out = [f"outliers set aside: {o['n']} point(s) beyond {_n(o['cut_mm'], '.4f')} mm ("
               + ", ".join(f"sample {p['sample']} marker {p['marker']} {p['split']} "
                           f"{_n(p['distance_mm'], '.3f')} mm" for p in o["points"][:8])
               + (", …" if o["n"] > 8 else "") + ")"]
        if inl:
            out.append(f"holdout without them ({inl['n']} points): rms {_n(inl['rms_before_mm'], '.4f')} "
                       f"-> {_n(inl['rms_after_mm'], '.4f')} mm, shrink {_n(inl['shrink'], '.3f')}")
        return out
    pts = o["points"]
    return [f"outliers set aside: {pts['n']} points (samples "
            f"{', '.join(map(str, pts['samples'][:20]))}{' …' if pts['n'] > 20 else ''}), "
            f"{o['paths']['n']} path samples; without them the holdout goes "
            f"{_n(inl['rms_before_mm'], '.4f')} -> {_n(inl['rms_after_mm'], '.4f')} mm (shrink {_n(inl['shrink'], '.3f')})"]


def _noise(rep: dict) -> list[str]:
    nz = rep.get("noise", {})
    if nz.get("sigma_mm") is None:
        return ["noise: unknown (no repeated poses, no --noise-mm)"] if "registration" in rep else []
    how = f": {nz['method']}" if nz.get("method") else ""
    return [f"noise: σ {_n(nz['sigma_mm'], '.4f')} mm per axis ({nz['source']}{how})"]


def _remainder(rep: dict) -> list[str]:
    out = ["UNEXPLAINED: " + "; ".join(rep["remainder"]["reasons"])] if rep["unexplained"] else []
    return out + [f"note: {n}" for n in rep["remainder"].get("notes", [])]


def _delay(rep: dict) -> list[str]:
    dl = rep.get("delay")
    if not dl:
        return []
    lag = dl["lags_ms"]
    return [f"comm lags: j1 {_n(lag['j1'], '.3f')} ms, j2 {_n(lag['j2'], '.3f')} ms (stations "
            f"{', '.join(dl['stations'])}); "
            + ("no lag detected" if not dl["detected"] else
               f"σ = {_n(dl['sigma_ms'], '.3f')} ms, proportional to station position: "
               f"{'yes' if dl['proportional'] else 'NO'}")]


def _not_identifiable(rep: dict) -> list[str]:
    ni = rep["not_identifiable"]
    return ["not identifiable from this campaign: " + "; ".join(f"{k} ({v})" for k, v in ni.items())
            ] if ni else []
