"""The HTML page of a diagnosis, planar or chain (``cellctl diagnose --html``), from the
report dict and the plots already written beside it. Pure: returns text.

Layout, in reading order:

1. **The answer** (first screen at 1280 × 800 and 1024 wide): the cause (or none, or
   unexplained) with its largest parameters' 95 % intervals, how sure (confidence or the
   test's p), the HOLDOUT rms before → after and its shrink (rows the fit never saw),
   kept apart from the FIT rms (rows it was fitted on), and the recommended action
   (:func:`cell.diagnosis.action.recommend`). Element ids ``cause``, ``shrink``, ``action``.
2. Where the gap lies (one sentence), then the evidence plots with captions.
3. The ranking as a table (fit and holdout columns named as such), the cause's
   parameters, noise, what cannot be identified, and the full text report folded away.

Every text from the report is escaped. The CSS keeps everything inside the window's
width: images scale down, long words break, wide tables scroll inside their own box.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from cell.diagnosis.action import recommend
from cell.diagnosis.words import DEPENDS_TEXT, FORMAT, FORMAT_VERSION, describe_cause  # noqa: F401

#: parameters shown in the answer card; the rest are in the parameters table below
CARD_PARAMS = 3
#: the v1 names a planar campaign's report gives beside the fitted parameters
#: (cell/measurements.md, "Format version 1.3"): JSON only, never listed twice on a page
V1_ALIAS = re.compile(r"_link_delta_mm$|_cyclic_(amp|phase)_deg$|_cyclic_order$|_cyclic_period_deg$")
#: ranking rows shown (the rest are in report.json)
TABLE_ROWS = 15

CSS = """
*{box-sizing:border-box}
html{-webkit-text-size-adjust:100%}
body{font:15px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;color:#1d232a;
 max-width:1180px;margin:0 auto;padding:12px 20px 40px;overflow-wrap:anywhere}
h1{font-size:1.35rem;margin:.2rem 0 .1rem}
h2{font-size:1.1rem;margin:1.6rem 0 .5rem;border-bottom:1px solid #d8dde3;padding-bottom:.2rem}
.src{color:#5b6570;font-size:.85rem;margin:0 0 .6rem;display:-webkit-box;-webkit-line-clamp:2;
 -webkit-box-orient:vertical;overflow:hidden}
.answer{display:grid;grid-template-columns:repeat(auto-fit,minmax(280px,1fr));gap:12px}
.card{border:1px solid #cfd6de;border-radius:8px;padding:10px 14px;background:#f8fafc;min-width:0}
.card h3{margin:0 0 .35rem;font-size:.78rem;letter-spacing:.06em;text-transform:uppercase;color:#5b6570}
.big{font-size:1.2rem;font-weight:600;margin:0 0 .3rem}
.card p{margin:.25rem 0}
.card ul{margin:.25rem 0;padding-left:1.1rem}
.small{font-size:.85rem;color:#4a545e}
.cause-unexplained{border-color:#d97706;background:#fff8eb}
.cause-none{border-color:#16a34a;background:#f0fdf4}
.action{border-color:#2563eb;background:#eff6ff}
.badge{display:inline-block;border-radius:4px;padding:0 6px;font-size:.8rem;font-weight:600}
.b-high{background:#dcfce7;color:#14532d}.b-low{background:#fef3c7;color:#78350f}
.b-unexplained{background:#fde68a;color:#78350f}
code{font:.85rem ui-monospace,SFMono-Regular,Menlo,monospace;background:#e8edf3;padding:1px 4px;
 border-radius:3px;overflow-wrap:anywhere}
.where{margin:.9rem 0 0}
figure{margin:1rem 0}
figure img{display:block;max-width:100%;height:auto;border:1px solid #e3e7ec}
figcaption{font-size:.88rem;color:#4a545e;margin-top:.3rem}
.scroll{overflow-x:auto;max-width:100%}
table{border-collapse:collapse;width:100%;font-size:.88rem}
th,td{border-bottom:1px solid #e3e7ec;padding:4px 8px;text-align:left;vertical-align:top}
th{background:#f1f4f7}
td.n,th.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
tr.chosen td{background:#eff6ff;font-weight:600}
details pre{white-space:pre-wrap;overflow-wrap:anywhere;font-size:.8rem;background:#f6f8fa;
 padding:10px;border-radius:6px}
"""


@dataclass(frozen=True)
class Figure:
    """A plot beside the page: ``file`` name, ``title``, ``caption`` (plain text)."""

    file: str
    title: str
    caption: str


@dataclass(frozen=True)
class FitRms:
    """FIT rms (mm) on the rows the model was fitted on: before (nominal / registration
    only) and after the cause, over ``rows``."""

    before: float | None
    after: float | None
    rows: str


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend (imported on first use: only a page
    needs it)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(plt, fig, path: Path) -> Path:
    """Save ``fig`` as ``path`` with a margin around whatever was drawn (nothing clipped at
    the edges), close it; ``path``."""
    if not fig.get_layout_engine():
        fig.tight_layout()
    fig.savefig(path, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def esc(v) -> str:
    """``v`` as HTML text. :mod:`html` is imported here: the report itself needs no HTML,
    and the module (with its entity table) costs about 1 ms to import."""
    from html import escape
    return escape(str(v), quote=True)


def num(v, nd: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, (int,)) and not isinstance(v, bool):
        return str(v)
    return f"{v:.{nd}f}" if abs(v) >= 10 ** -nd or v == 0 else f"{v:.3g}"


def _cause_card(rep: dict) -> str:
    c = rep["cause"]
    eff = c["effect"]
    on = f" on {', '.join(c['joints'])}" if c["joints"] else ""
    sub = f" ({c['subsystem']})" if c.get("subsystem") not in (None, "none") else ""
    t = c.get("test", {})
    p = t.get("p_value")
    ptxt = ""
    if isinstance(p, (int, float)):
        ptxt = (f"test against {'registration alone' if 'chain' in rep else 'the nominal model'}: "
                f"p {'< 1e-12' if p < 1e-12 else f'= {p:.2g}'} (α {t.get('alpha')})")
    if rep["unexplained"]:
        cls, head = "cause-unexplained", "Unexplained"
        sub_line = (f"best candidate: {esc(eff)}{esc(on)}" if eff != "none"
                    else "no candidate of the vocabulary is supported")
        badge = '<span class="badge b-unexplained">most of the gap left</span>'
    elif eff == "none":
        cls, head, sub_line = "cause-none", "None: within noise", "no effect of the vocabulary is supported"
        badge = ""
    else:
        cls, head, sub_line, badge = "", esc(describe_cause(c)), esc(sub.strip(" ()")), ""
    conf = c.get("confidence")
    if conf and not rep["unexplained"] and eff != "none":
        badge = f'<span class="badge b-{esc(conf)}">confidence {esc(conf)}</span>'
    rivals = c.get("rivals") or []
    if rivals:
        sub_line += (" — or, as the campaign sees it, "
                     + " or ".join(esc(r.get("label", "?")) for r in rivals))
    rows, names = [], fitted(rep)
    for n in names[:CARD_PARAMS]:
        v, ci = c["params"][n], c.get("ci95", {}).get(n)
        iv = f" <span class='small'>[{num(ci[0])} … {num(ci[1])}]</span>" if ci else ""
        rows.append(f"<li><code>{esc(n)}</code> = {num(v)}{iv}</li>")
    more = len(names) - CARD_PARAMS
    extra = f"<p class='small'>+{more} more parameters in the table below</p>" if more > 0 else ""
    plist = (f"<p class='small'>estimate [95 % interval]</p><ul>{''.join(rows)}</ul>{extra}"
             if rows else "")
    n = len(c.get("separating_poses") or [])
    poses = (f"<p class='small'><a href='#separating'>{n} poses</a> would tell them apart</p>"
             if n else "")
    return (f'<section class="card {cls}" id="cause"><h3>What is wrong</h3>'
            f'<p class="big">{head}</p><p>{sub_line} {badge}</p>'
            f'{plist}{poses}<p class="small">{esc(ptxt)}</p></section>')


def pose_words(pz: dict) -> str:
    """Where a separating pose is, in words: the chain's readings (``jK value``), or the
    planar joints with their approach directions (``j1 30.0° (+1), …``)."""
    if "readings" in pz:
        dirs = pz.get("dirs", {})
        return ", ".join(f"{k} {v:g}" + (f" ({dirs[k]:+d})" if k in dirs else "")
                         for k, v in pz["readings"].items())
    return (f"j1 {pz['j1_deg']:.1f}° ({pz['j1_dir']:+d}), "
            f"j2 {pz['j2_deg']:.1f}° ({pz['j2_dir']:+d})")


def _separating(c: dict) -> str:
    """The separating poses (planar joints and directions, or chain readings) as a list."""
    items = []
    for pz in c.get("separating_poses") or []:
        diff = ", ".join(f"{esc(k)} {num(v)} mm" for k, v in pz["difference_mm"].items())
        items.append(f"<li>{esc(pose_words(pz))}: differs from {diff}</li>")
    if not items:
        return ""
    return ("<h2 id='separating'>Measure next: where the rival causes differ most</h2>"
            f"<ul>{''.join(items)}</ul>")


def _shrink_card(rep: dict, fit: FitRms) -> str:
    h = rep["holdout"]
    rows = f"{h['poses']} poses, {h['n']} points" if "poses" in h else f"{h['n']} rows"
    sh = h.get("shrink")
    shtxt = f"{100 * sh:.0f} %" if isinstance(sh, (int, float)) else "–"
    fit_html = (f"<p class='small' id='fit-rms'><b>FIT rms</b> (rows the model was fitted on, "
                f"{esc(fit.rows)}): {num(fit.before)} → {num(fit.after)} mm</p>")
    return (f'<section class="card" id="shrink"><h3>How sure: held-out check</h3>'
            f'<p class="big"><b>HOLDOUT rms</b> {num(h["rms_before_mm"])} → '
            f'{num(h["rms_after_mm"])} mm</p>'
            f'<p>shrink <b>{shtxt}</b> on {esc(rows)} the fit never saw</p>{fit_html}'
            f'{_noise_line(rep)}</section>')


def _noise_line(rep: dict) -> str:
    nz = rep.get("noise") or {}
    s = nz.get("sigma_mm")
    if s is None:
        return "<p class='small'>noise: unknown</p>"
    return f"<p class='small'>noise σ {num(s)} mm per axis ({esc(nz.get('source'))})</p>"


def _action_card(rep: dict) -> str:
    a = recommend(rep)
    cmds = "".join(f"<li><code>{esc(c)}</code></li>" for c in a.commands)
    cav = f"<p class='small'>⚠ {esc(a.caveat)}</p>" if a.caveat else ""
    reasons = rep.get("remainder", {}).get("reasons") or []
    why = (f"<p class='small'>{esc(reasons[0])}</p>" if rep["unexplained"] and reasons else "")
    return (f'<section class="card action" id="action" data-kind="{esc(a.kind)}">'
            f'<h3>What to do</h3><p class="big">{esc(a.text)}</p>'
            f'{f"<p>{esc(a.detail)}</p>" if a.detail else ""}'
            f'{"<ul>" + cmds + "</ul>" if cmds else ""}{cav}{why}</section>')


def ranking_table(rep: dict, chosen_label: str | None = None) -> str:
    """The ranking as a table, registration alone first; the row of the candidate labelled
    ``chosen_label`` (the named cause) is marked."""
    chosen = next((i for i, r in enumerate(rep["ranking"]) if r["label"] == chosen_label), None)
    h, reg = rep["holdout"], rep["registration"]
    head = ("<tr><th class='n'>rank</th><th>candidate</th><th>joints</th><th class='n'>k</th>"
            "<th class='n'>leave-one-pose-out rms mm</th><th class='n'>FIT rms mm</th>"
            "<th class='n'>HOLDOUT rms mm</th><th class='n'>condition</th></tr>")
    rows = [f"<tr><td class='n'>–</td><td>registration only</td><td></td><td class='n'>0</td>"
            f"<td class='n'>{num(rep['noise'].get('registration_cv_rms_mm'))}</td>"
            f"<td class='n'>{num(reg['rms_mm'])}</td><td class='n'>{num(h['rms_before_mm'])}</td>"
            f"<td class='n'>{num(reg.get('condition'), 1)}</td></tr>"]
    for i, r in enumerate(rep["ranking"]):
        rows.append(f"<tr{' class=chosen' if i == chosen else ''}><td class='n'>{i + 1}</td>"
                    f"<td>{esc(r['label'])}</td><td>{esc(', '.join(r['joints']))}</td>"
                    f"<td class='n'>{r['k']}</td><td class='n'>{num(r['cv_rms_mm'])}</td>"
                    f"<td class='n'>{num(r['fit_rms_mm'])}</td>"
                    f"<td class='n'>{num(r['holdout_rms_mm'])}</td>"
                    f"<td class='n'>{num(r['condition'], 1)}</td></tr>")
    more = len(rep["ranking"]) - TABLE_ROWS
    tail = (f"<p class='small'>{more} more candidates in report.json.</p>" if more > 0 else "")
    return (f"<div class='scroll'><table id='ranking'><thead>{head}</thead>"
            f"<tbody>{''.join(rows)}</tbody></table></div>{tail}")


def fitted(rep: dict) -> list[str]:
    """The names of the cause's fitted parameters: ``cause.params`` without the v1 names a
    planar campaign's report repeats them under (:data:`V1_ALIAS`)."""
    names = list(rep["cause"].get("params", {}))
    if (rep.get("chain") or {}).get("planar"):
        names = [n for n in names if not V1_ALIAS.search(n)]
    return names


def params_table(rep: dict) -> str:
    c = rep["cause"]
    if not c.get("params"):
        return ""
    rows = "".join(f"<tr><td><code>{esc(n)}</code></td><td class='n'>{num(c['params'][n], 6)}</td>"
                   f"<td class='n'>{num((c['ci95'].get(n) or [None])[0], 6)}</td>"
                   f"<td class='n'>{num((c['ci95'].get(n) or [None, None])[1], 6)}</td></tr>"
                   for n in fitted(rep))
    return ("<h2>Parameters of the cause</h2><div class='scroll'><table id='params'><thead><tr>"
            "<th>parameter (unit in its name)</th><th class='n'>estimate</th>"
            "<th class='n'>95 % low</th><th class='n'>95 % high</th></tr></thead>"
            f"<tbody>{rows}</tbody></table></div>")


def _notes(rep: dict) -> str:
    items = [f"<li><b>unexplained:</b> {esc(r)}</li>" for r in rep.get("remainder", {}).get("reasons", [])]
    items += [f"<li>{esc(n)}</li>" for n in rep.get("remainder", {}).get("notes", [])]
    items += [f"<li>warning: {esc(w)}</li>" for w in rep["cause"].get("warnings", [])]
    ni = rep.get("not_identifiable") or {}
    nid = "".join(f"<li><code>{esc(k)}</code>: {esc(v)}</li>" for k, v in ni.items())
    out = f"<h2>Notes</h2><ul>{''.join(items)}</ul>" if items else ""
    if nid:
        out += (f"<details><summary>Not identifiable from this campaign ({len(ni)})</summary>"
                f"<ul class='small'>{nid}</ul></details>")
    return out


def render(rep: dict, figures: list[Figure], fit: FitRms, text: str,
           chosen_label: str | None = None) -> str:
    """The whole page (see the module doc). ``text``: the full text report (folded);
    ``chosen_label``: the ranking label of the named cause (its row is marked)."""
    fig_html = "".join(
        f'<figure><img src="{esc(f.file)}" alt="{esc(f.title)}"><figcaption>'
        f"<b>{esc(f.title)}.</b> "
        f"{esc(f.caption)}</figcaption></figure>" for f in figures)
    kind = "planar" if (rep.get("chain") or {}).get("planar") else "chain"
    what = "planar campaign, read as a two-joint chain" if kind == "planar" else "chain campaign"
    return (
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width,initial-scale=1'>"
        f"<title>cellctl diagnose: {esc(rep['cause']['effect'])}</title><style>{CSS}</style></head>"
        f"<body data-kind='{kind}'><h1>Sim-to-real diagnosis</h1>"
        f"<p class='src' title='{esc(rep.get('source') or '')}'>{esc(what)} · format "
        f"{esc(rep.get('format'))} · {esc(rep.get('source') or '')}</p>"
        f"<div class='answer'>{_cause_card(rep)}{_shrink_card(rep, fit)}{_action_card(rep)}</div>"
        f"<p class='where' id='where'>{esc(rep['gap']['where']['summary'])}</p>"
        f"{_separating(rep['cause'])}"
        f"<h2>Evidence</h2>{fig_html}"
        f"<h2>Ranking of the candidates</h2>{ranking_table(rep, chosen_label)}"
        f"<p class='small'>FIT columns: rows the model was fitted on; HOLDOUT: rows it never saw. "
        f"The highlighted row is the named cause.</p>"
        f"{params_table(rep)}{_notes(rep)}"
        f"<h2>Full report</h2><details><summary>the text <code>cellctl diagnose</code> prints"
        f"</summary><pre>{esc(text)}</pre></details>"
        "<p><a href='report.json'>report.json</a> (format cell-diagnosis/1)</p></body></html>")
