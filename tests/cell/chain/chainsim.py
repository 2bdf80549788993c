"""The tests' chain campaigns: :mod:`cell.truth.chain_campaign` (drawn from the independent
forward model :mod:`cell.truth.chain`)."""
from cell.truth.chain_campaign import MARKERS, UR5, make  # noqa: F401
