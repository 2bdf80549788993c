"""The report format's name and version, and the words a cause and its gap are said in
(the report's summary, its text, its page and the recommended action say the same). Kept
apart from the page (:mod:`cell.diagnosis.page`, which re-exports them) so that a
diagnosis loads neither the page's HTML nor the action's remedies.
"""
from __future__ import annotations

FORMAT = "cell-diagnosis/1"
#: additive revisions of the report format (cell/measurements.md), planar and chain alike:
#: 1.0 the v1 report, 1.1 chains, 1.2 the out-of-sample choice (cause.label, selection,
#: rivals, separating_poses, and confidence "ambiguous"), 1.3 the v1 report's keys in the
#: chain diagnosis of a planar campaign, and in every chain ranking entry
FORMAT_VERSION = "1.3"

#: what the gap depends on (``gap.where.depends_on``), in the words of the summaries
DEPENDS_TEXT = {"constant": "is constant in joint space", "angle": "varies with the joint angle",
                "direction": "depends on the approach direction", "time": "drifts with time",
                "temperature": "follows the temperature", "position": "varies over the workspace",
                "speed": "follows the joint speeds along the moves"}


def describe_cause(c: dict) -> str:
    """The named cause in words, every fitted component: ``backlash on j2``,
    ``joint_offset on j1 + link_length on j1`` (text, page and action say the same)."""
    comps = c.get("components") or []
    if not comps:
        on = f" on {', '.join(c.get('joints', []))}" if c.get("joints") else ""
        return f"{c.get('effect', 'none')}{on}"
    return " + ".join(f"{x['effect']}" + (f" on {', '.join(x['joints'])}" if x.get("joints") else "")
                      for x in comps)
