"""Joint stations over CAN (issue 3): CANopen CiA 301/402 drives on python-can.

* :mod:`.driver` — :class:`JointStations`, the controller side (one object for all four).
* :mod:`.config` — :class:`StationsConfig`, the ``stations`` config section.
* :mod:`.sim_station` — the simulated twin (canopen ``LocalNode`` + shipped ``scara_axis.eds``).
* :mod:`.bus` — bus factory by interface name; rate-limited virtual wire.
* :mod:`.cia402` — the drive state machine; :mod:`.faults` — fault codes, latch, monitors.
"""
from drivers.stations.config import StationConfig, StationsConfig
from drivers.stations.driver import JointStations, StationStartupError
from drivers.stations.faults import FaultCode, FaultRecord, StationFaultError
from drivers.stations.streaming import StationCommandError, StreamReport

__all__ = ["JointStations", "StationsConfig", "StationConfig", "FaultCode", "FaultRecord",
           "StationFaultError", "StationStartupError", "StationCommandError", "StreamReport"]
