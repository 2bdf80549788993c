"""The registry: every effect definition, in the order the diagnosis tries them (that order
is part of its answers: keep new effects at the end). Add an effect by writing its module
and listing it here (``docs/adding-an-effect.md``)."""
from __future__ import annotations

from cell.effects import (backlash, camera_rotation, camera_scale, comm_delay, cyclic_error,
                          gear_ratio, gravity_compliance, joint_offset, link_length,
                          motor_cyclic_error, thermal_drift)
from cell.effects.base import Effect

REGISTRY: dict[str, Effect] = {m.EFFECT.name: m.EFFECT for m in (
    joint_offset, link_length, gear_ratio, backlash, cyclic_error, thermal_drift,
    camera_scale, camera_rotation, comm_delay, gravity_compliance, motor_cyclic_error,
)}
#: the planar (SCARA) vocabulary: what the plant simulates (each also a chain effect, as the
#: diagnosis fits every campaign)
EFFECTS: dict[str, Effect] = {n: e for n, e in REGISTRY.items() if e.planar}
#: the chain vocabulary (:mod:`cell.diagnosis.chain.fit`), in registry order
CHAIN_EFFECTS: dict[str, Effect] = {n: e for n, e in REGISTRY.items() if e.chain is not None}
