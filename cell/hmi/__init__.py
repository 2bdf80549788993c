"""The maintenance HMI (``cellctl hmi``): a small local web app beside the controller.

It shows the cell's status and last cycles (the cycle log read-only; optionally the PLC
status registers, read-only over Modbus TCP), the accuracy trend, the recipes (view, diff
against the active version, edit with validation as you type) and the diagnosis reports.
It never writes the cycle log (the controller holds its writer's lock): a saved recipe
reaches the cell the way every edit does, through the controller's recipe store, which
audits it with the user and role of the edit note the HMI leaves (:mod:`cell.recipes.notes`).

Modules: :mod:`~cell.hmi.app` (settings, the shared wiring, the middleware stack),
:mod:`~cell.hmi.pages` (status, trend, recipes, reports), :mod:`~cell.hmi.auth` (login,
logout, sessions, CSRF, bounded form and JSON bodies), :mod:`~cell.hmi.guard` (trusted
hosts and proxies, body limits, response headers), :mod:`~cell.hmi.netguard` (request-read
time-out, connection cap, rate-limited accept errors), :mod:`~cell.hmi.work` (bounded pools
for blocking work), :mod:`~cell.hmi.recipes` (the recipe desk), :mod:`~cell.hmi.status`
(log, PLC, trend), :mod:`~cell.hmi.users` (the users file), :mod:`~cell.hmi.throttle` (login
throttle), :mod:`~cell.hmi.server` (settings from the cell config, uvicorn with limits).
Threats and defences: ``docs/hmi-security.md``.
"""
