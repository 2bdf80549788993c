"""What to do about a diagnosis: one recommended action derived from the report dict
(``cell-diagnosis/1``, planar or chain), for the top of the HTML page. Pure; reads only
the report's public keys (``unexplained``, ``cause.effect`` / ``joints`` / ``subsystem`` /
``confidence``, ``remainder.depends_on``, ``chain``, ``source``).

Order of the decision: unexplained first (a named cause that leaves most of the gap is
not the answer), then none, then the cause's effect:

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

#: seed 004 measures these per joint (cellctl calibrate joint)
JOINT_LEVEL = ("backlash", "gear_ratio", "cyclic_error")
GEOMETRIC = ("joint_offset", "link_length")
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
    chain = "chain" in rep
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
    if effect in JOINT_LEVEL and not chain:
        js = [j for j in joints if j in CALIBRATABLE_JOINTS] or joints
        return Action("calibrate_joint", f"Calibrate the joint: {effect.replace('_', ' ')}{on}.",
                      tuple(f"cellctl calibrate joint {j}" for j in js), caveat)
    if effect in GEOMETRIC or (chain and effect == "gear_ratio"):
        cmd = f"cellctl calibrate kinematics {src}" if chain else "cellctl calibrate kinematics"
        return Action("calibrate_kinematics", f"Calibrate the kinematics: "
                      f"{effect.replace('_', ' ')}{on}.", (cmd,), caveat)
    if effect == "thermal_drift":
        return Action("thermal", "Calibrate the kinematics at working temperature, and keep the "
                      "cell's temperature steady: the links grow with it.",
                      ("cellctl calibrate kinematics",), caveat)
    if cause.get("subsystem") == "vision" or effect.startswith("camera_"):
        return Action("camera", f"Check the camera calibration ({effect.replace('_', ' ')}).",
                      ("cellctl calibrate-camera --board board.yaml --images DIR --out cal.json",),
                      caveat)
    if effect == "comm_delay":
        return Action("comms", "Check the joint stations' delays on the bus and the recipe's "
                      "motion.sync (corrected or sync), then run a line to compare.",
                      ("cellctl recipe show NAME",), caveat)
    if effect == "gravity_compliance":
        return Action("compliance", f"Check the drive and payload{on}: the joint gives way "
                      "under the gravity load.", (), caveat)
    return Action("investigate", f"Investigate {effect}{on}: no standard remedy is known.", (),
                  caveat)
