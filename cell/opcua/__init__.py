"""A read-only OPC UA server for the MES (``opcua`` section of the cell config, or
``cellctl run|serve --opcua HOST:PORT``; off by default).

The server never touches the controller: it subscribes to the :class:`~cell.publish.Publisher`
(topics ``status`` and ``cycle``) and runs apart from the scan, in a thread of its own
("opcua-server") with its own asyncio loop, on wall time. What it serves (docs/opcua.md):

* an OPC 40010 (Robotics) subset: ``MotionDeviceSystem`` → ``MotionDevices`` →
  ``MotionDevice`` → ``Axes`` (j1..j4, each with ``ParameterSet/ActualPosition`` and its
  engineering units), and the controller's state, fault code and text, cycles done and
  active recipe;
* cycle results in the manner of OPC 40001-101 (Result Transfer): ``GetLatestResult`` on
  ``ResultManagement`` returns the last settled cycle's result, and a ``ResultReadyEventType``
  event is emitted for every settled cycle.

Modules: :mod:`~cell.opcua.config` (the config section), :mod:`~cell.opcua.model` (messages →
values, pure), :mod:`~cell.opcua.certs` (the server certificate and the trust list),
:mod:`~cell.opcua.space` (the address space), :mod:`~cell.opcua.server` (thread, loop,
security). Only :mod:`~cell.opcua.space` and :mod:`~cell.opcua.server` import ``asyncua``;
nothing here is imported unless the server is asked for.
"""
