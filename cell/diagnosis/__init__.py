"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect of the
vocabulary (:mod:`cell.effects`) causes it, and how far it shrinks on withheld rows.

* :mod:`.replay`     campaign -> arrays, nominal replay, residuals
* :mod:`.where`      what the gap varies with (effect sizes)
* :mod:`.candidates` which effects the data can identify at all
* :mod:`.jacobian`   the replay with its exact Jacobian (what fits and screening evaluate)
* :mod:`.screen`     linearised screening of every candidate (harmonic orders included)
* :mod:`.fit`        one candidate fitted on the fit rows (least_squares, BIC, 95 % CI)
* :mod:`.rank`       search over singles and pairs, none / pair / unexplained decisions
* :mod:`.crossval`   the cause that predicts left-out places; rivals; separating poses
* :mod:`.robust`     outliers set aside, and how many places the fit rows cover
* :mod:`.noise`      the point noise: given, from revisited poses or from the remainder
* :mod:`.delay`      per-station comm lags and the λ_i = σ·i check
* :mod:`.report`     :func:`diagnose`, the JSON report
* :mod:`.answer`     :func:`~.answer.diagnose_campaign`: any campaign, planar or chain, one answer
* :mod:`.validate`   validation trials on the independent truth (:mod:`cell.truth`), scores
* :mod:`.html`       the HTML page with plots (the one module here that writes files)

Shared by the planar and the chain (:mod:`.chain`) diagnosis:

* :mod:`.leaveout`   the leave-one-fold-out prediction error of any linearised fit
* :mod:`.tie`        when the left-out folds cannot tell a candidate from the best; naming
* :mod:`.places`     poses at one station, folds, separating poses spaced apart
* :mod:`.page`       the report format's version and the words for a cause
* :mod:`.harness`    the validation harness: judged trials, scores, tables
* :mod:`.text`       the report as text (:func:`render_text`)
"""
__all__ = ["FORMAT", "Diagnosis", "diagnose", "render_text"]


def __getattr__(name: str):
    """The planar diagnosis on first use only: the chain side imports small modules of this
    package (:mod:`.crossval`, :mod:`.page`) without loading the whole planar search."""
    if name == "render_text":
        from cell.diagnosis.text import render
        return render
    if name in __all__:
        from cell.diagnosis import report
        return getattr(report, name)
    raise AttributeError(f"module 'cell.diagnosis' has no attribute {name!r}")
