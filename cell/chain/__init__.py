"""Any serial arm, measured in 3-D (``cell/measurements.md``, Extension v1.1): chain
registration, the sim-to-real diagnosis and the kinematic calibration of chains.
The chain itself (dh / urdf → ops, forward kinematics, twists) is :mod:`cell.kinematics`.

* :mod:`.campaign`  chain campaigns: read, validate (file/line/joint errors), write
* :mod:`.fit`       registration (sensor frame, markers) and parameter fits, robust errors
* :mod:`.rank`      screening, candidate fits and the none / cause / unexplained decision
* :mod:`.report`    the ``cell-diagnosis/1`` report for chains
* :mod:`.calibrate` seed 001's differential model fitted, checked on holdout, written back
"""
