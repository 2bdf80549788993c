"""The simulated cell: the plant and its true robot (:mod:`.plant`), a PLC that is a real
Modbus client (:mod:`.plc`), the one clock of every simulated device (:mod:`.clock`) and
the assembly of the whole (:mod:`.assembly`); measurement campaigns drawn from the plant for
tests and benchmarks (:mod:`.campaigns`).

The drivers' simulated twins live beside their drivers, as python-can's virtual bus does:
the CANopen drives (:mod:`drivers.stations.sim`) on their CAN wire
(:mod:`drivers.stations.sim_bus`), the rendering camera (:mod:`drivers.camera.sim`) and the
hand camera (:mod:`drivers.camera.sim_hand`).

Production code never imports simulation code (:func:`drivers.registry.is_simulation`):
the device registry (:mod:`cell.devices`), the CAN bus factory (``drivers.stations.bus``)
and the camera registry name those modules as strings and import them only when a config
asks for the simulated devices. The effect vocabulary the plant applies
(:mod:`cell.effects`) stays outside: it is also the diagnosis's model of what can go wrong
on a real cell.
"""
