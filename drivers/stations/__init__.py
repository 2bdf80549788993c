"""Joint stations over CAN: CANopen CiA 301/402 drives on python-can.

* :mod:`.driver` — :class:`JointStations`, the controller side (one object for all four),
  with the drives' EDS (``scara_axis.eds``); :mod:`.streaming` — its line streaming and
  seed 002's delays.
* :mod:`.config` — :class:`StationsConfig`, the ``stations`` config section.
* :mod:`.bus` — bus factory by interface name, CAN bit timing.
* :mod:`.cia402` — the drive state machine; :mod:`.faults` — fault codes, latch, monitors.

The simulated drives and the virtual CAN wire are part of the simulated cell
(:mod:`drivers.stations.sim`, :mod:`drivers.stations.sim_bus`).
"""
from drivers.stations.config import StationConfig, StationsConfig
from drivers.stations.driver import JointStations, StationStartupError
from drivers.stations.faults import FaultCode, FaultRecord, StationFaultError
from drivers.stations.streaming import StationCommandError, StreamReport

__all__ = ["JointStations", "StationsConfig", "StationConfig", "FaultCode", "FaultRecord",
           "StationFaultError", "StationStartupError", "StationCommandError", "StreamReport"]
