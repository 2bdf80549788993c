"""Cell fault codes: the one number the PLC reads in ``fault_code`` (0 = no fault).

Numbers are stable: append, never renumber. Ranges say which subsystem failed:

====  =====================================================================
1xx   PLC link and handshake
2xx   joint stations: 200 + the station driver's own code
      (``drivers.stations.faults.FaultCode``: 201 heartbeat lost, 204 limit, ...)
3xx   camera and vision
4xx   motion planning and accuracy
5xx   controller internals
6xx   robot calibration started by the PLC (nothing is written when one fails)
====  =====================================================================
"""
from __future__ import annotations

import enum

STATION_BASE = 200


class Fault(enum.IntEnum):
    NONE = 0
    PLC_HEARTBEAT_LOST = 101      #: plc_heartbeat did not change for plc.heartbeat_timeout_s
    STATION = 200                 #: a joint-station fault; fault_code = 200 + station code
    CAMERA_FAILED = 301           #: the camera returned no frame (timeout, device gone)
    NO_TARGET = 302               #: the expected fiducial was not found
    MULTIPLE_TARGETS = 303        #: more than one candidate where one was expected
    TARGET_CUT = 304              #: the fiducial touches the image edge
    SATURATED = 305               #: too many saturated pixels around the fiducial
    LOW_CONTRAST = 306            #: fiducial contrast too low to trust
    VISION_FAILED = 307           #: any other vision failure
    PART_OUT_OF_WINDOW = 308      #: the part lies outside the recipe's search radius
    UNREACHABLE = 401             #: a target the robot cannot reach (IK, limits, singularity)
    VERIFY_OUT_OF_TOLERANCE = 402 #: the verified error exceeds the recipe's tolerance
    MOTION_TIMEOUT = 403          #: the joints did not reach their target in time
    INTERNAL = 501                #: an unexpected error in the controller (see the log)
    LOG_WRITE_FAILED = 502        #: the cycle could not be written to the cycle log
    INTERRUPTED = 503             #: a cycle was interrupted by a controller restart (crash, power
                                  #: loss); part_id_echo holds its part id; cleared by reset
    CALIBRATION_REFUSED = 601     #: calibration_select names no procedure this cell can run
                                  #: (j3 is prismatic; no hand camera configured)
    CALIBRATION_MEASUREMENT = 602 #: a calibration image failed: target lost, cut or doubled
    CALIBRATION_FIT = 603         #: the calibration could not be trusted: too few points, a
                                  #: singular design, or the held-out check failed


class CellFault(Exception):
    """Raised inside a cycle to end it with ``code``; ``detail`` is logged and recorded."""

    def __init__(self, code: int, detail: str):
        self.code = int(code)
        self.detail = detail
        super().__init__(f"fault {self.code}: {detail}")


def station_fault(station_code: int) -> int:
    """PLC fault code for a joint-station driver fault code."""
    return STATION_BASE + int(station_code)
