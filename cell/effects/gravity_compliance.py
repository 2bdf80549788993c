"""gravity_compliance (chains only): the joint gives way under the gravity load,
Δq_K = c·τ_K with τ_K the gravity lever of a unit weight at the tool point (format,
"Chain effects"). Its forward model and derivative live with the chain's kinematics
(:mod:`cell.diagnosis.chain.fit`, which needs the arm's levers); the SCARA moves in a horizontal
plane, so it has no planar form."""
from __future__ import annotations

from cell.effects.base import Effect, OnChain, ParamSpec, Remedy

EFFECT = Effect(
    "gravity_compliance", "transmission", "joint", (), True,
    (ParamSpec("compliance_deg_per_m", "deg/m", "give per metre of gravity lever",
               (-10.0, 10.0), (0.1, 0.5)),),
    "position", "the joint gives way under the gravity load",
    remedy=Remedy("compliance", "Check the drive and payload{on}: the joint gives way "
                  "under the gravity load."),
    chain=OnChain("revolute", "compliance_deg_per_m", "deg/m",
                  term=lambda poses, k: poses.levers[:, k],     # Δq_k = c·τ_k
                  bounds=(0.0, None)))   # the joint gives way, never against the load. No
# upper bound: a plausible give per metre of a unit weight's lever depends on the arm (the best
# candidates on the real TIAGo set give its wrist 27 deg/m, beyond its ParamSpec's ±10)
