"""The cell controller: numerics, state machine, recipes and cycle log for a vision-guided SCARA cell.

One BLAS thread per process, unless the environment says otherwise. Our linear algebra is
small and dense (Jacobians of a few hundred rows, normal matrices of tens of columns):
OpenBLAS's worker threads do not speed it up, they spin. Measured on the 100-pose 7-joint
chain diagnosis: 1.17 s CPU with the default threads against 0.78 s with one, the same
cause named. On a cell PC the spinning threads would also compete with the control loop.
OpenBLAS reads the variable when numpy loads, so it is set here, before any of our modules
imports numpy (``cellctl`` imports numpy only once a command runs).

One OpenCV thread too, for the same reason: the cell's frames are small (a 640 × 512 frame, a
window of a few thousand pixels around a fiducial), and OpenCV's pool costs more CPU than it
saves. Measured on the cycle's windowed tool find (``bench/bench_vision.py``'s cell frames):
4.73 ms CPU with OpenCV's two threads against 3.68 ms with one, the same centre.
``OPENCV_FOR_THREADS_NUM`` is read when cv2 loads.
"""
import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
