"""What to do about a diagnosis: one recommended action derived from the report dict
(``cell-diagnosis/1``, planar or chain), for the top of the HTML page. Pure; reads only
the report's public keys (``unexplained``, ``cause.effect`` / ``joints`` / ``subsystem`` /
``confidence``, ``remainder.depends_on``, ``chain``, ``source``).

Order of the decision: unexplained first (a named cause that leaves most of the gap is
not the answer), then none, then ambiguous, then the cause's effect: the action is the
effect's own (``Effect.remedy``, or its chain one, in :mod:`cell.effects`). Today:

- joint-level transmission (backlash, gear ratio, cyclic error) on the SCARA:
  ``cellctl calibrate joint jN`` (seed 004, the hand camera over a target);
- geometry (joint offset, link length), and on a chain also gear ratio (its model fits
  joint scale with the geometry): ``cellctl calibrate kinematics`` (chain: on the campaign);
- thermal drift: calibrate the kinematics at working temperature;
- camera scale or rotation: check the camera calibration (``cellctl calibrate-camera``);
- comm delay: check the stations' delays and the recipe's ``motion.sync``;
- gravity compliance (chain): the joint gives way under load: check its drive and payload.

A ``low`` confidence keeps the action and adds a caveat: confirm on a second campaign.
An ``ambiguous`` answer (the campaign cannot tell the cause from its ``cause.rivals``)
changes nothing on the robot: measure the ``cause.separating_poses`` first.
"""
from __future__ import annotations

from dataclasses import dataclass

from cell import effects as fx

#: the joints ``cellctl calibrate joint`` accepts (the SCARA's rotary joints)
CALIBRATABLE_JOINTS = ("j1", "j2", "j4")


@dataclass(frozen=True)
class Action:
    """``kind`` (calibrate_joint, calibrate_kinematics, thermal, camera, comms,
    compliance, none, investigate, measure_more), ``text`` (one short sentence for a person), ``commands``
    (shell commands to run, may be empty), ``caveat`` (or ''), ``detail`` (or '': what
    follows the headline)."""

    kind: str
    text: str
    commands: tuple[str, ...] = ()
    caveat: str = ""
    detail: str = ""


def recommend(rep: dict) -> Action:
    """The action for report ``rep`` (see the module doc for the rules)."""
    cause = rep.get("cause", {})
    effect = cause.get("effect", "none")
    joints = list(cause.get("joints", []))
    chain = "chain" in rep and not rep["chain"].get("planar")   # a SCARA keeps its remedies
    src = rep.get("source") or "CAMPAIGN"
    caveat = ("confidence is low: confirm on a second campaign before acting"
              if cause.get("confidence") == "low" else "")
    if rep.get("unexplained"):
        where = (rep.get("remainder") or {}).get("depends_on")
        lies = f" (the remainder depends on {where.replace('_', ' ')})" if where else ""
        best = f"The best candidate, {effect}, takes off only part of it. " if effect != "none" else ""
        return Action("investigate", "Investigate: the gap is not explained by the vocabulary.",
                      (), caveat, f"{best}See where it lies{lies} in the plots below.")
    if effect == "none":
        return Action("none", "No action: the gap is within noise.", (), "")
    if cause.get("confidence") == "ambiguous":
        rivals = [cause.get("label", effect)] + [r.get("label", "?") for r in cause.get("rivals", [])]
        n = len(cause.get("separating_poses", []))
        return Action("measure_more", "Measure more before acting: the campaign cannot tell "
                      + " from ".join(rivals[:2]) + (" and others" if len(rivals) > 2 else "") + ".",
                      (), "", f"Add the {n} separating poses listed below to the campaign and "
                      "diagnose again." if n else "Add poses at places the campaign did not visit.")
    on = f" on {', '.join(joints)}" if joints else ""
    eff = fx.REGISTRY.get(effect)
    remedy = eff.remedy_for(chain) if eff is not None else None
    if remedy is None:
        return Action("investigate", f"Investigate {effect}{on}: no standard remedy is known.",
                      (), caveat)
    cmds: list[str] = []
    for c in remedy.commands:
        if "{joint}" in c:
            js = [j for j in joints if j in CALIBRATABLE_JOINTS] or joints
            cmds += [c.format(joint=j) for j in js]
        else:
            cmds.append(c.format(src=src))
    return Action(remedy.kind, remedy.text.format(what=effect.replace("_", " "), on=on),
                  tuple(cmds), caveat)
