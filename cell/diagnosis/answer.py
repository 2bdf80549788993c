"""One call for any campaign: :func:`diagnose_campaign` diagnoses a planar campaign (v1) or
a chain campaign (Extension v1.1) with the one diagnosis (:mod:`cell.diagnosis.chain`) and
returns one :class:`Answer`, whose report follows the one format (``cell-diagnosis/1``, the
project's additions in ``cell/measurements.md``) and renders as text and as an HTML page.
A planar campaign is read as the chain campaign it is (:func:`as_chain`: a two-joint arm
whose sensor sees x and y), and its report carries the v1 report's figures as well
("Format version 1.3"); a caller never branches on the campaign's kind.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path


@dataclass
class Answer:
    """A diagnosis: ``report`` (JSON-ready dict) and what it was computed from
    (``computed``: :class:`~cell.diagnosis.chain.report.ChainDiagnosis`, which the HTML
    page's plots need)."""

    report: dict
    computed: object

    def text(self) -> str:
        """The report as readable lines (:func:`cell.diagnosis.text.render`)."""
        from cell.diagnosis.text import render
        return render(self.report)

    def write_html(self, out_dir) -> Path:
        """Write ``out_dir/index.html`` with its PNG plots; its path. Raises OSError."""
        from cell.diagnosis.chain.html import write_chain_html
        return write_chain_html(self.computed, out_dir)


def diagnose_campaign(campaign, lines: dict | None = None,
                      noise_mm: float | None = None) -> Answer:
    """The diagnosis of ``campaign`` (what :func:`cell.measurements.read_campaign` returns,
    or a chain campaign already); ``lines`` maps table → file line of each row of a planar
    campaign (its error messages), ``noise_mm`` the expected σ per axis of one point
    measurement if known. Raises CampaignFormatError for data that cannot be diagnosed."""
    from cell.measurements import Campaign
    if isinstance(campaign, Campaign):
        campaign = as_chain(campaign, lines)
    from cell.diagnosis.chain.report import diagnose_chain_full
    cd = diagnose_chain_full(campaign, noise_mm)
    return Answer(cd.report, cd)


def as_chain(campaign, lines: dict | None = None):
    """Planar campaign ``campaign`` read as the chain campaign it is
    (:func:`cell.measurements.chain.planar_as_chain`), after the planar checks that name a
    file line (:func:`cell.diagnosis.replay.prepare`: time running backwards in a move, a
    split that leaves too few rows, a cycle log with too few cycles), whose arrays the v1
    figures then use; ``lines`` maps table → file line of each row. Raises
    CampaignFormatError."""
    from cell.diagnosis.replay import prepare
    from cell.measurements.chain import planar_as_chain
    arrays = prepare(campaign, lines)
    cc = planar_as_chain(campaign, campaign.source or ".")
    cc.planar = replace(cc.planar, arrays=arrays)
    return cc
