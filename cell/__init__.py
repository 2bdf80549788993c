"""The cell controller: numerics, state machine, recipes and cycle log for a vision-guided SCARA cell."""

__version__ = "0.1.0"
