"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect of the
vocabulary (:mod:`cell.effects`) causes it, and how far it shrinks on withheld poses. One
diagnosis for every campaign: :func:`~.answer.diagnose_campaign` reads a planar (v1)
campaign as the chain campaign it is and diagnoses it, as any chain campaign
(Extension v1.1), with :mod:`.chain` (search, ranking, noise, decision, report).

* :mod:`.answer`     :func:`~.answer.diagnose_campaign`: any campaign, one answer
* :mod:`.chain`      the diagnosis itself (fits, ranking, decision, report, page)
* :mod:`.leaveout`   the leave-one-fold-out prediction error of any linearised fit
* :mod:`.tie`        when the left-out folds cannot tell a candidate from the best; naming
* :mod:`.places`     poses at one station, folds, separating poses spaced apart
* :mod:`.noise`      noise estimates: revisited poses, local planes, the 95 % upper bound
* :mod:`.words`      the report format's name and version, the words for a cause
* :mod:`.page`       the HTML layout
* :mod:`.action`     the recommended action of a report
* :mod:`.text`       the report as text (:func:`render_text`)
* :mod:`.harness`    the validation harness: judged trials, scores, tables
* :mod:`.validate`   validation trials of planar campaigns on the independent truth
                     (:mod:`cell.truth`); :mod:`.chain.validate` those of chain campaigns

The v1 report's figures of a planar campaign (``cell/measurements.md``, "Format version
1.3"), computed from the one diagnosis's fits by :mod:`.chain.planar`:

* :mod:`.replay`     a planar campaign's rows as arrays (checks that name a file line)
* :mod:`.jacobian`   the planar replay with its exact Jacobian (the station lags' fit)
* :mod:`.where`      what a residual varies with (effect sizes)
* :mod:`.delay`      per-station comm lags and the λ_i = σ·i check
* :mod:`.figures`    per-table summaries, spread, point noise estimates
"""
__all__ = ["FORMAT", "diagnose_campaign", "render_text"]


def __getattr__(name: str):
    """The diagnosis on first use only: small modules of this package load without it."""
    if name == "render_text":
        from cell.diagnosis.text import render
        return render
    if name == "FORMAT":
        from cell.diagnosis.words import FORMAT
        return FORMAT
    if name == "diagnose_campaign":
        from cell.diagnosis.answer import diagnose_campaign
        return diagnose_campaign
    raise AttributeError(f"module 'cell.diagnosis' has no attribute {name!r}")
