"""One call for any campaign: :func:`diagnose_campaign` diagnoses a planar campaign (v1) or
a chain campaign (Extension v1.1) and returns one :class:`Answer`, whose report follows the
one format (``cell-diagnosis/1``, the project's additions in ``cell/measurements.md``) and
which renders as text and as an HTML page the same way for both. Which family computes it
is the campaign's kind; a caller never branches on it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass
class Answer:
    """A diagnosis: ``report`` (JSON-ready dict), ``family`` (``planar`` or ``chain``) and
    what it was computed from (``computed``: the family's own record, which the HTML page's
    plots need)."""

    report: dict
    family: str
    computed: Any

    def text(self) -> str:
        """The report as readable lines (:func:`cell.diagnosis.text.render`)."""
        from cell.diagnosis.text import render
        return render(self.report)

    def write_html(self, out_dir) -> Path:
        """Write ``out_dir/index.html`` with its PNG plots; its path. Raises OSError."""
        if self.family == "chain":
            from cell.diagnosis.chain.html import write_chain_html
            return write_chain_html(self.computed, out_dir)
        from cell.diagnosis.html import write_html
        return write_html(self.computed, out_dir)


def diagnose_campaign(campaign, lines: dict | None = None,
                      noise_mm: float | None = None) -> Answer:
    """The diagnosis of ``campaign`` (what :func:`cell.measurements.read_campaign` returns);
    ``lines`` maps table → file line of each row (planar error messages), ``noise_mm`` the
    expected σ per axis of one point measurement if known. Raises CampaignFormatError for
    data that cannot be diagnosed."""
    from cell.measurements import Campaign
    if isinstance(campaign, Campaign):
        from cell.diagnosis.report import diagnose
        dg = diagnose(campaign, lines, noise_mm)
        return Answer(dg.report, "planar", dg)
    from cell.diagnosis.chain.report import diagnose_chain_full
    cd = diagnose_chain_full(campaign, noise_mm)
    return Answer(cd.report, "chain", cd)
