"""The cell controller: numerics, state machine, recipes and cycle log for a vision-guided SCARA cell.

One BLAS thread per process, unless the environment says otherwise. Our linear algebra is
small and dense (Jacobians of a few hundred rows, normal matrices of tens of columns):
OpenBLAS's worker threads do not speed it up, they spin. Measured on the 100-pose 7-joint
chain diagnosis: 1.17 s CPU with the default threads against 0.78 s with one, the same
cause named. On a cell PC the spinning threads would also compete with the control loop.
OpenBLAS reads the variable when numpy loads, so it is set here, before any of our modules
imports numpy (``cellctl`` imports numpy only once a command runs).
"""
import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
