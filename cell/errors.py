"""Exception hierarchy. Every error names the offending value and where it came from."""
from __future__ import annotations

from pathlib import Path


class CellError(Exception):
    """Base of every error the cell controller raises on purpose."""


class KinematicsError(CellError, ValueError):
    """A pose or joint value the robot cannot take (unreachable, singular, out of limits, not finite)."""


class TrajectoryError(CellError, ValueError):
    """A trajectory that cannot be planned as asked (bad timing, too few way-points, ...)."""


class ConfigError(CellError, ValueError):
    """A configuration or recipe value that failed validation; the message names file and field."""


class MeasurementError(CellError):
    """A measurement could not be taken or is not trustworthy (no target, saturated image, ...)."""


class LogError(CellError):
    """The cycle log cannot be used (damaged, read-only, disk full, in use by another
    controller); the message names the file, the cause and how to recover. ``problem``:
    the file and the cause alone, for a caller that gives its own advice (``log check``)."""

    def __init__(self, message: str, problem: str | None = None):
        super().__init__(message)
        self.problem = problem or message


class CalibrationError(CellError, ValueError):
    """A robot calibration that cannot be done or trusted (target lost, too few points, a
    singular design, a failed held-out check, a calibration file that is corrupt or belongs
    to another robot); the message names the cause and where. Nothing is written then.

    ``fault`` says which kind of failure it is (the PLC's fault code follows from it,
    :mod:`cell.faults` 601–603): ``refused`` (the cell cannot run it: no hand camera, a field
    too small), ``measurement`` (an image failed: target lost, cut or doubled, camera
    failed) or ``fit`` (everything else: too few points, a singular design, ...)."""

    FAULTS = ("refused", "measurement", "fit")

    def __init__(self, message: str, fault: str = "fit"):
        if fault not in self.FAULTS:
            raise ValueError(f"CalibrationError fault {fault!r}; use one of {self.FAULTS}")
        super().__init__(message)
        self.fault = fault


class CampaignFormatError(CellError, ValueError):
    """Bad campaign input; ``file``, ``line`` and ``column`` locate it (line/column may be
    None), ``message`` says what is wrong."""

    def __init__(self, file: Path | str, message: str, line: int | None = None,
                 column: str | None = None):
        self.file, self.line, self.column, self.message = str(file), line, column, message
        where = self.file + (f", line {line}" if line else "") + (f", column {column!r}" if column else "")
        super().__init__(f"{where}: {message}")
