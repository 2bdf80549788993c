"""How a diagnosis report is judged against the truth a validation campaign was made of:
one verdict per trial, the same for the planar and the chain harness. Pure logic on the
report's JSON (``cell-diagnosis/1`` and the project's additions in ``cell/measurements.md``);
nothing from the diagnosis is imported.

A truth is a set of **components**, each an effect name with the joints it acts on (a
joint offset on j2 and j3 is one component ``("joint_offset", ("j2", "j3"))``); ``none``
is the empty set; a truth outside the vocabulary has no components to name
(``outside=True``). A named answer **matches** the truth when it has the same effect
names and each effect the same joints (joint order ignored). A cause is read from
``cause.components`` when the report gives them, else from ``cause.effect`` / ``joints``;
a rival from its ``components``, else from its ``effects`` and ``joints`` (with several
effects and one joint list, the effect names and the union of the joints are compared).

Verdicts (:data:`VERDICTS`), exactly one per trial:

* ``right``: ``unexplained`` false, confidence ``high`` (or none given), and the cause
  matches the truth (``none`` for a truth of none; ``none`` also for a truth outside the
  vocabulary, which names no cause);
* ``ambiguous``: confidence ``low`` or ``ambiguous`` and the truth is the named cause or
  one of ``cause.rivals``;
* ``ambiguous_missing``: confidence ``low`` or ``ambiguous``, the truth neither the cause
  nor a rival (always so for a truth outside the vocabulary that got a named cause);
* ``unexplained``: the report says ``unexplained: true`` (right for a truth outside the
  vocabulary, a miss for one inside it);
* ``wrong``: confidence ``high``, a cause that does not match (a wrong effect, wrong
  joints, a wrong ``none``; for a truth outside the vocabulary, any named cause).

``detail_ok`` lets a harness add what the names do not carry (the planar harness: a cyclic
error's number of cycles per revolution); a cause that fails it does not match.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Callable, Iterable, Mapping, Sequence

VERDICTS = ("right", "ambiguous", "ambiguous_missing", "unexplained", "wrong")
Component = tuple[str, tuple[str, ...]]


@dataclass(frozen=True)
class Expected:
    """The truth as the report should name it: ``components`` (empty for ``none``), or
    ``outside`` for an effect outside the vocabulary."""

    components: tuple[Component, ...] = ()
    outside: bool = False

    @property
    def label(self) -> str:
        if self.outside:
            return "outside"
        return " + ".join(f"{e}[{','.join(j)}]" if j else e for e, j in self.components) or "none"


def _key(comps: Iterable[Component]) -> frozenset:
    return frozenset((e, frozenset(j)) for e, j in comps)


def _loose(comps: Iterable[Component]) -> tuple[frozenset, frozenset]:
    comps = list(comps)
    return frozenset(e for e, _ in comps), frozenset(j for _, js in comps for j in js)


def cause_components(cause: Mapping) -> list[Component]:
    """The (effect, joints) the report's cause names; [] for ``none``."""
    comps = cause.get("components") or []
    if comps:
        return [(c["effect"], tuple(c.get("joints", ()))) for c in comps]
    if cause.get("effect", "none") == "none":
        return []
    return [(cause["effect"], tuple(cause.get("joints", ())))]


def matches(truth: Expected, named: Sequence[Component] | Mapping) -> bool:
    """Whether ``named`` (components, or a rival entry of the report) is the truth."""
    if truth.outside:
        return False
    if isinstance(named, Mapping):                 # a rival entry
        comps = named.get("components")
        if comps:
            named = [(c["effect"], tuple(c.get("joints", ()))) for c in comps]
        else:
            effects = list(named.get("effects", ()))
            joints = tuple(named.get("joints", ()))
            if len(effects) > 1:
                return _loose(truth.components) == (frozenset(effects), frozenset(joints))
            named = [(effects[0], joints)] if effects and effects[0] != "none" else []
    return _key(truth.components) == _key(named)


def classify(truth: Expected, report: Mapping,
             detail_ok: Callable[[Mapping], bool] | None = None) -> str:
    """The verdict (:data:`VERDICTS`) of ``report`` for ``truth`` (module docstring)."""
    if report.get("unexplained"):
        return "unexplained"
    cause = report["cause"]
    named = cause_components(cause)
    cause_ok = (not named if truth.outside else matches(truth, named)) \
        and (detail_ok is None or detail_ok(cause))
    if cause.get("confidence", "high") == "high":
        return "right" if cause_ok else "wrong"
    if truth.outside:
        return "ambiguous_missing" if named else "ambiguous"
    if cause_ok or any(matches(truth, r) for r in cause.get("rivals") or []):
        return "ambiguous"
    return "ambiguous_missing"


def counts(verdicts: Iterable[str]) -> dict[str, int]:
    """How many trials got each verdict (every verdict present, 0 if none); an empty
    verdict (a trial not judged) is not counted, an unknown one raises KeyError."""
    out = dict.fromkeys(VERDICTS, 0)
    for v in verdicts:
        if v:
            out[v] += 1
    return out


# ------------------------------------------------------------------ tables
#: header of the verdict table (Markdown); :func:`table_lines` gives its rows
TABLE_HEAD = ["| campaigns | trials | right | ambiguous, truth among rivals | ambiguous, truth missing "
              "| unexplained | wrong | 95 % CI coverage (intervals) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]


def table_rows(trials: Sequence, outside_of) -> list[tuple[str, dict[str, int], float, int]]:
    """[(set, verdict counts, coverage, intervals)] for the trials inside the vocabulary and
    those outside it (``outside_of(trial)`` says which; sets without trials left out).
    A trial has ``verdict``, ``covered`` and ``n_params`` (true values inside their 95 %
    interval, intervals checked: trials judged right only)."""
    out = []
    for name, want in (("in vocabulary", False), ("outside", True)):
        g = [t for t in trials if bool(outside_of(t)) == want]
        if g:
            n = sum(t.n_params for t in g)
            out.append((name, counts(t.verdict for t in g),
                        sum(t.covered for t in g) / n if n else math.nan, n))
    return out


def table_lines(family: str, trials: Sequence, outside_of) -> list[str]:
    """Rows of the verdict table (:data:`TABLE_HEAD`) for ``family``'s trials."""
    out = []
    for name, c, cov, n in table_rows(trials, outside_of):
        pct = "–" if math.isnan(cov) else f"{100 * cov:.1f} %"
        out.append(f"| {family}, {name} | {sum(c.values())} | {c['right']} | {c['ambiguous']} "
                   f"| {c['ambiguous_missing']} | {c['unexplained']} | {c['wrong']} | {pct} ({n}) |")
    return out


def wrong_lines(trials: Sequence) -> list[str]:
    """One Markdown list line per confident wrong answer: seed, truth, answer, layout (a
    trial has ``seed``, ``index``, ``truth_label``, ``answer_label``, ``confidence``,
    ``layout``)."""
    return [f"- seed {t.seed} (trial {t.index}): truth {t.truth_label}, answered "
            f"{t.answer_label} (confidence {t.confidence}); layout {t.layout}"
            for t in trials if t.verdict == "wrong"]
