"""Numerics shared by the diagnosis and the calibration, without scipy's import cost:
distribution functions (:mod:`.stats`) and bounded nonlinear least squares (:mod:`.lsq`).
"""
