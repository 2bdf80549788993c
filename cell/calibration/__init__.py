"""Robot calibration from the cell's own camera (pure numerics, no I/O here).

* :mod:`cell.calibration.joint` — seed 004: one joint at a time, a hand camera over a
  fixed target; circle fit of the target centres, per-step angle errors per pass, and the
  joint's backlash, gear-ratio error and cyclic error with 95 % intervals.
* :mod:`cell.calibration.kinematic` — seed 001: the SCARA's DH parameters from poses over
  a calibration board, by the differential (first-order) error model, iterated least
  squares, an identifiability report and a held-out check.
* :mod:`cell.calibration.chain` — seed 001's model on any serial arm's campaign (DH or
  URDF), checked on held-out poses and written back as a model file.
* :mod:`cell.calibration.check` — the checks every calibration must pass before it is
  written (held-out rms and max not worse, residual near the noise).

Every failure raises :class:`~cell.errors.CalibrationError` naming the cause.
"""
