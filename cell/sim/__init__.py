"""The simulated cell, all in one place: the plant and its true robot (:mod:`.plant`), the
simulated devices — CANopen drives (:mod:`.stations`) on a CAN wire (:mod:`.canbus`), a
rendering camera (:mod:`.camera`), a PLC that is a real Modbus client (:mod:`.plc`) — their
one clock (:mod:`.clock`) and the assembly of the whole (:mod:`.assembly`); measurement
campaigns drawn from the plant for tests and benchmarks (:mod:`.campaigns`).

Production code never imports this package: the device registry (:mod:`cell.devices`),
the CAN bus factory (``drivers.stations.bus``) and the camera registry name its modules
as strings and import them only when a config asks for the simulated devices. The effect
vocabulary the plant applies (:mod:`cell.effects`) stays outside: it is also the
diagnosis's model of what can go wrong on a real cell.
"""
