"""Names of seed 003's time laws and knot timings, without the numerics (cheap to import:
``cellctl``'s parser offers them as choices)."""

LAWS = ("quintic-poly", "quintic-bspline", "septic-bspline")
TIMINGS = ("uniform", "chord")
