"""The one validation harness of the diagnosis, planar and chain: a judged trial, the loop
over trials, the scores and their Markdown tables. What differs between the two families
is only how a trial's truth is drawn and its campaign made (:mod:`cell.diagnosis.validate`,
:mod:`cell.diagnosis.chain.validate`, both from the independent :mod:`cell.truth`); everything from
the report on is judged here, by the same rules (:mod:`cell.truth.verdict`).

A :class:`Trial` holds the hidden truth (its main effect, or ``none``, or a kind outside
the vocabulary), what the report answered, its verdict, and the interval coverage of the
true parameters (counted on the trials judged ``right`` only: a wrong or ambiguous answer
has no true parameters to cover). :func:`summarise` gives the scores as a dict (JSON-ready,
the same keys for planar and chain campaigns; ``subsystem_accuracy`` and
``depends_on_agreement`` only where the trials say which subsystem and dependence the truth has), and
:func:`markdown` the four tables the README shows: verdicts, summary, per truth, confusion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from cell.truth import verdict as vd

DOUBT = ("low", "ambiguous")        # confidences that do not name a cause as certain


@dataclass
class Trial:
    """One judged trial. ``true_effect`` is the hidden truth's main effect (``none``, or a
    kind outside the vocabulary when ``outside``), ``true_joints`` its joints, ``second``
    the kind of a second effect; ``named`` / ``named_joints`` the report's cause,
    ``verdict`` one of :data:`cell.truth.verdict.VERDICTS`; ``covered`` of ``n_params`` true
    parameters inside their 95 % intervals (trials judged right); ``seconds`` the
    diagnosis' CPU time; ``truth_subsystem`` / ``truth_depends_on`` what the vocabulary says
    of the true effect and ``subsystem`` / ``depends_on`` what the report says (empty where
    the family does not score them)."""

    index: int
    true_effect: str
    true_joints: tuple[str, ...]
    outside: bool
    named: str
    named_joints: tuple[str, ...]
    unexplained: bool
    confidence: str | None
    shrink: float
    covered: int
    n_params: int
    seconds: float
    verdict: str
    truth_label: str
    answer_label: str
    layout: dict = field(default_factory=dict)
    seed: int = 0
    second: str | None = None
    truth_params: dict = field(default_factory=dict)
    order_ok: bool = True           # a cyclic error named with the true cycles per revolution
    rivals: tuple[str, ...] = ()
    subsystem: str = ""
    truth_subsystem: str = ""
    depends_on: str = ""
    truth_depends_on: str = ""

    @property
    def answer(self) -> str:
        """The named cause, or ``unexplained``."""
        return "unexplained" if self.unexplained else self.named

    @property
    def named_or_unexplained(self) -> str:
        return self.answer

    @property
    def effect_ok(self) -> bool:
        """The answer is the true effect (``none`` for a truth of none)."""
        return self.answer == self.true_effect

    @property
    def joint_ok(self) -> bool:
        """Right effect on the right joints (a cyclic error: with the right order too)."""
        return self.effect_ok and tuple(self.named_joints) == tuple(self.true_joints) \
            and self.order_ok

    @property
    def confident_cause(self) -> bool:
        """The report names a vocabulary cause, does not call it unexplained and does not
        doubt it (confidence high, or none given)."""
        return not self.unexplained and self.named != "none" and self.confidence not in DOUBT


def judge(index: int, seed: int, report: Mapping, expected: vd.Expected, *,
          true_effect: str, true_joints: Sequence[str], truth_label: str, seconds: float,
          covered: Callable[[dict], tuple[int, int]], layout: dict | None = None,
          second: str | None = None, truth_params: dict | None = None,
          detail_ok: Callable[[Mapping], bool] | None = None,
          truth_subsystem: str = "", truth_depends_on: str = "",
          subsystem_of: Callable[[str], str] | None = None) -> Trial:
    """The :class:`Trial` of ``report`` (a diagnosis report as JSON) against the truth:
    its verdict (:func:`cell.truth.verdict.classify`, with ``detail_ok`` for what names do
    not carry) and, when right, ``covered(cause.ci95)`` → (inside, compared)."""
    c = report["cause"]
    verdict = vd.classify(expected, report, detail_ok)
    hit = n = 0
    if verdict == "right":
        hit, n = covered(c.get("ci95") or {})
    named = vd.cause_components(c)
    answer = " + ".join(f"{e}[{','.join(j)}]" if j else e for e, j in named) or "none"
    unexplained = bool(report["unexplained"])
    where = (report.get("gap") or {}).get("where") or {}
    return Trial(index, true_effect, tuple(true_joints), expected.outside, c["effect"],
                 tuple(c["joints"]), unexplained, c.get("confidence"),
                 float(report["holdout"]["shrink"] or 0.0), hit, n, seconds, verdict,
                 truth_label, answer, dict(layout or {}), seed, second, dict(truth_params or {}),
                 detail_ok(c) if detail_ok and expected.components else True,
                 tuple(r.get("label", "?") for r in c.get("rivals") or []),
                 subsystem_of("unexplained" if unexplained else c["effect"]) if subsystem_of else "",
                 truth_subsystem, str(where.get("depends_on", "")), truth_depends_on)


def run(trial: Callable[[int], Trial], trials: int, start: int = 0, progress=None) -> list[Trial]:
    """Trials ``start`` … ``start + trials − 1`` (``trial(i)`` draws, diagnoses and judges
    one); ``progress(i, trial)`` is called after each."""
    out = []
    for i in range(start, start + trials):
        out.append(trial(i))
        if progress:
            progress(i, out[-1])
    return out


def check_outside(outside_share: float, outside_kinds: Sequence[str], known: Sequence[str],
                  layout: str, layouts: Sequence[str]) -> None:
    """Raise ValueError for a share outside [0, 1], an unknown kind or an unknown layout."""
    if not 0.0 <= outside_share <= 1.0:
        raise ValueError(f"outside_share {outside_share} must lie in [0, 1]")
    bad = [k for k in outside_kinds if k not in known]
    if bad or not outside_kinds:
        raise ValueError(f"unknown kinds {bad}; known: {list(known)}")
    if layout not in layouts:
        raise ValueError(f"unknown layout {layout!r}; known: {list(layouts)}")


def _share(xs) -> float:
    xs = list(xs)
    return sum(map(bool, xs)) / len(xs) if xs else math.nan


def summarise(ts: list[Trial]) -> dict:
    """The scores as a dict (JSON-ready). ``verdicts`` / ``outside_verdicts`` count the
    verdicts of the vocabulary trials (``none`` included) and of those outside it;
    ``coverage`` is over the trials judged right; the other vocabulary scores are over the
    vocabulary trials; ``outside_*`` count the trials outside it: all of them, named as a
    confident cause, unexplained, none."""
    voc = [t for t in ts if not t.outside]
    out = [t for t in ts if t.outside]
    eff = [t for t in voc if t.true_effect != "none"]
    none = [t for t in voc if t.true_effect == "none"]
    secs = [t.seconds for t in ts] or [math.nan]
    cov_hit, cov_n = sum(t.covered for t in voc), sum(t.n_params for t in voc)
    s = {
        "trials": len(ts),
        "verdicts": vd.counts(t.verdict for t in voc),
        "outside_verdicts": vd.counts(t.verdict for t in out),
        "wrong": [{"seed": t.seed, "truth": t.truth_label, "answer": t.answer_label,
                   "confidence": t.confidence, "layout": t.layout}
                  for t in ts if t.verdict == "wrong"],
        "effect_accuracy": _share(t.effect_ok for t in voc),
        "joint_accuracy_effects": _share(t.joint_ok for t in eff),
        "effect_accuracy_effects": _share(t.effect_ok for t in eff),
        "none_named_as_effect": sum(t.answer != "none" for t in none),
        "none_trials": len(none),
        "effects_called_none": sum(t.answer == "none" for t in eff),
        "unexplained": sum(t.unexplained for t in voc),
        "median_shrink": float(np.median([t.shrink for t in eff])) if eff else math.nan,
        "coverage": cov_hit / cov_n if cov_n else math.nan,
        "coverage_n": cov_n,
        "seconds_median": float(np.median(secs)), "seconds_max": float(np.max(secs)),
        "outside_trials": len(out),
        "outside_named_as_cause": sum(t.confident_cause for t in out),
        "outside_unexplained": sum(t.unexplained for t in out),
        "outside_none": sum(t.answer == "none" for t in out),
    }
    if voc and all(t.truth_subsystem for t in voc):
        s["subsystem_accuracy"] = _share(t.subsystem == t.truth_subsystem for t in voc)
        s["depends_on_agreement"] = _share(t.depends_on == t.truth_depends_on
                                           for t in eff if t.effect_ok)
    return s


def _num(v: float) -> str:
    return "–" if v is None or math.isnan(v) else f"{v:.3f}"


def _pct(v: float) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.1f} %"


def _label(name: str, outside: Sequence[str], spaced: bool = False) -> str:
    return (name.replace("_", " ") if spaced else name) + (" (outside)" if name in outside else "")


def markdown(ts: list[Trial], title: str, family: str, vocabulary: Sequence[str],
             outside: Sequence[str]) -> str:
    """The four tables of ``ts`` under ``### title``: verdicts (``family`` names the row),
    summary (with subsystem and ``depends_on`` scores where :func:`summarise` gives them),
    per true effect, and the confusion matrix over ``vocabulary`` (``none`` included) and
    ``unexplained``. Rows for kinds of ``outside`` are marked "(outside)"; their "named
    right" counts trials that named no confident cause. The confident wrong answers are
    listed between the first two tables."""
    s = summarise(ts)
    wrong = vd.wrong_lines(ts)
    extra = "subsystem_accuracy" in s
    head = ["trials", "effect acc.", "effect+joint acc. (effects)"] \
        + (["subsystem acc."] if extra else []) \
        + ["none named as effect", "effects called none", "unexplained (vocab.)",
           "median holdout shrink"] + (["depends_on agrees"] if extra else []) \
        + ["95 % CI coverage", "CPU s/campaign median (max)", "outside vocab. named as cause"]
    row = [str(s["trials"]), _pct(s["effect_accuracy"]), _pct(s["joint_accuracy_effects"])] \
        + ([_pct(s["subsystem_accuracy"])] if extra else []) \
        + [f"{s['none_named_as_effect']}/{s['none_trials']}", str(s["effects_called_none"]),
           str(s["unexplained"]), _num(s["median_shrink"])] \
        + ([_pct(s["depends_on_agreement"])] if extra else []) \
        + [f"{_pct(s['coverage'])} ({s['coverage_n']})",
           f"{s['seconds_median']:.2f} ({s['seconds_max']:.2f})",
           f"{s['outside_named_as_cause']}/{s['outside_trials']}" if s["outside_trials"] else "–"]
    out = [f"### {title}", "", *vd.TABLE_HEAD, *vd.table_lines(family, ts, lambda t: t.outside),
           "", *(["Confident wrong answers:", "", *wrong, ""] if wrong else []),
           "| " + " | ".join(head) + " |", "|" + "---:|" * len(head), "| " + " | ".join(row) + " |",
           "", "| true effect | trials | named right | right joints | median shrink | CI coverage "
           "| median CPU s |", "|---|---:|---:|---:|---:|---:|---:|"]
    kinds = [k for k in list(vocabulary) + list(outside) if any(t.true_effect == k for t in ts)]
    for k in kinds:
        g = [t for t in ts if t.true_effect == k]
        if k in outside:
            right, jr = sum(not t.confident_cause for t in g), "–"
        else:
            right, jr = sum(t.effect_ok for t in g), sum(t.joint_ok for t in g)
        ch, cn = sum(t.covered for t in g), sum(t.n_params for t in g)
        sh = f"{np.median([t.shrink for t in g]):.3f}" if k != "none" else "–"
        out.append(f"| {_label(k, outside)} | {len(g)} | {right} | {jr} | {sh} | "
                   f"{(f'{ch}/{cn}') if cn else '–'} | {np.median([t.seconds for t in g]):.2f} |")
    cols = list(vocabulary) + ["unexplained"]
    out += ["", "Confusion matrix (rows: true effect, columns: answer):", "",
            "| true \\ answer | " + " | ".join(c.replace("_", " ") for c in cols) + " |",
            "|---|" + "---:|" * len(cols)]
    for k in kinds:
        g = [t for t in ts if t.true_effect == k]
        cells = [sum(t.answer == c for t in g) for c in cols]
        out.append(f"| {_label(k, outside, True)} | "
                   + " | ".join(str(v) if v else "·" for v in cells) + " |")
    return "\n".join(out)
