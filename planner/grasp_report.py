"""The report of a realized grasp (`regrasp check`): its text and the contact markers of its picture.

`planner.realization` realizes a grasp file (`realize` -> `RealizedGrasp`, whose ``summary`` is
the JSON form); this module words it for a person.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from planner.grip import FRICTION_MARGIN
from planner.objects import DEFAULT_DENSITY_KG_M3
from planner.realization import (AT_LIMIT_RAD, CONTACT_TOL_M, CONTACT_WARN_M, PAD_FACING_RAD, PENETRATION_TOL_M,
                                  ExecutionVerdict, RealizedGrasp, execution_verdict, wedged_fingers)


def object_text(obj) -> str:
    """One-line description of an object's shape and size (a mesh: its extents, not its scale)."""
    ext = obj.extents
    mm = " x ".join(f"{v * 1e3:.1f}" for v in ext)
    if obj.shape == "box":
        return f"box {mm} mm"
    if obj.shape == "cylinder":
        return f"cylinder radius {obj.size[0] * 1e3:.1f} mm, length {obj.size[1] * 1e3:.1f} mm"
    if obj.shape == "sphere":
        return f"sphere radius {obj.size[0] * 1e3:.1f} mm"
    return f"mesh {Path(obj.mesh_path).name} {mm} mm (scale {list(obj.size)})"


def check_text(grasp: RealizedGrasp, verdict: ExecutionVerdict | None = None, strict: bool = False,
               simulator: dict | None = None, gravity_option: str = "") -> str:
    """The text report of ``regrasp check``; ``verdict``: `planner.realization.execution_verdict`'s
    when already computed (its ``hold`` is the load table); ``strict`` (``--execution``,
    ``--gravity``): a refusal fails the check; ``simulator``: the grasp held in a physics engine
    (``check --execution``'s `planner.commands._simulator_hold` data), None when not replayed;
    ``gravity_option``: the ``--gravity`` given (`` --gravity palm_up``), in the plan it suggests."""
    verdict = execution_verdict(grasp) if verdict is None else verdict
    hold = verdict.hold
    report = grasp.summary(hold)
    fr = grasp.friction
    out = [f"grasp {grasp.spec.name} ({grasp.spec.path})",
           f"hand {grasp.hand.name}, {object_text(grasp.obj)}, mu {fr.mu:g}, gamma {fr.gamma:g} m, {fr.edges} cone edges",
           f"{'finger':<8} {'spec':<8} {'points':>6}  {'removable':<9}  touching links"]
    for name, f in report["fingers"].items():
        out.append(f"{name:<8} {f['kind']:<8} {f['contact_points']:>6}  {'yes' if f['removable'] else 'no':<9}  "
                   f"{', '.join(f['touching_links']) or '-'}")
    palm = report["palm"]
    gap = "" if palm["distance_m"] is None else f", {palm['distance_m'] * 1e3:.1f} mm from the object"
    if palm["holds"]:
        words = f"touches ({', '.join(palm['touching_links'])}), holds with {palm['contact_points']} point(s)"
    elif palm["touching"]:
        words = f"touches ({', '.join(palm['touching_links'])}) but is kept out of the grasp (palm: free)"
    else:
        words = "does not touch" + gap
    out.append(f"{'palm':<8} {palm['mode']:<8} {palm['contact_points']:>6}  {'never':<9}  {words}")
    out.append("realized contacts (object frame, mm; normal into the object):")
    out.append(f"  {'finger':<8} {'link':<20} {'point':>26}  {'normal':>22}  penetration")
    for c in grasp.contacts:
        p = " ".join(f"{v * 1e3:+8.2f}" for v in c.point)
        n = " ".join(f"{v:+6.3f}" for v in c.normal)
        out.append(f"  {c.finger or 'palm':<8} {c.link:<20} {p:>26}  {n:>22}  {c.penetration_m * 1e3:.2f} mm")
    for a, b, depth in grasp.collisions:
        out.append(f"collision: {a} - {b}, {depth * 1000:.2f} mm")
    for w in grasp.warnings:
        out.append(f"warning: {w}")
    for name, why in wedged_fingers(grasp).items():
        out.append(f"warning: fingers.{name}: a plan can neither lift it from this contact nor land it here ({why}): "
                   f"a regrasp that moves {name} cannot start or end in this grasp")
    for p in grasp.problems:
        out.append(f"NOT AS WRITTEN: {p}")
    out.append(f"force closure: {'yes' if grasp.is_force_closure else 'no'}, metric {grasp.metric:.4g}, "
               f"removable: {', '.join(sorted(grasp.removable)) or '-'}")
    mean = report["mean_contact_closure"]
    out.append(f"with one mean contact per finger (--contact-model mean): force closure "
               f"{'yes' if mean['force_closure'] else 'no'}, metric {mean['metric']:.4g}")
    link = report["link_contact_closure"]
    out.append(f"with one contact per touching link (--contact-model link, execution mode): force closure "
               f"{'yes' if link['force_closure'] else 'no'}, metric {link['metric']:.4g}")
    mass = f"{grasp.obj.mass_kg * 1e3:.4g} g" + ("" if grasp.obj.mass_given else " (no mass_kg in the file: "
                                                   f"its volume at {DEFAULT_DENSITY_KG_M3:g} kg/m^3)")
    out.append(f"load held within the joints' torque limits (a contact per link, {FRICTION_MARGIN:g} of the friction; "
               f"execution mode needs {verdict.hold_factor:g}x the weight, {mass}):")
    for h in hold:
        out.append(f"  {'ok  ' if h.capacity.factor >= verdict.hold_factor else 'LOW '} {h.words()}")
    if not hold:
        out.append(f"  not computed: {grasp.hold_unavailable() or 'no direction'}")
    names = ", ".join(n for n, _ in verdict.directions)
    if not verdict.ok:
        accepted = f"refuses it: {verdict.reason}" + ("" if strict else " (check --execution fails it)")
    elif simulator is not None:
        accepted = "accepts it as an end grasp by its static test"
    else:
        skipped = ("engine from the start, as check --execution does)" if not strict else
                   "engine from the start: --no-verify skipped that)" if grasp.ok else
                   "engine from the start: not replayed, the grasp is not as written)")  # (a problem fails the check already)
        # (as an initial grasp: plan replays its plan from it; a plan arriving at a grasp may
        # still end in it where the grasp held alone drops)
        accepted = ("accepts it as an end grasp by its static test (as an initial grasp, plan --execution also holds it "
                    "in a physics " + skipped)
    out.append(f"execution mode (plan --execution, {names}): {accepted}")
    if simulator is not None:
        where = f"held in a physics engine ({simulator['engine']}, as plan --execution replays an initial grasp)"
        if simulator["held"]:
            out.append(f"{where}: holds it in {len(simulator['directions'])} direction(s) "
                       f"({', '.join(simulator['directions'])}), {simulator['wall_s']:.1f} s")
        else:
            failure = simulator["failure"]
            out.append(f"{where}: does not hold it: "
                       + (f"{failure['direction']}: " if failure["direction"] else "") + failure["verdict"])
    why = [] if grasp.is_force_closure else ["not force closure"]
    why += [f"{len(grasp.problems)} problem(s)"] if grasp.problems else []
    why += [f"execution mode refuses it: {verdict.brief()}"] if strict and not verdict.ok else []
    if strict and simulator is not None and not simulator["held"]:
        why += ["execution mode refuses it: it does not hold in the simulator"
                + (f" ({simulator['failure']['direction']})" if simulator["failure"]["direction"] else "")
                + " from the start, as plan --execution replays an initial grasp (a plan arriving at it may "
                  f"still hold it as its final grasp: plan A.yaml THIS.yaml --execution{gravity_option})"]
    out.append(f"{'FAIL' if why else 'PASS'}{': ' + ', '.join(why) if why else ''} (tolerances: penetration "
               f"{PENETRATION_TOL_M * 1e3:.1f} mm, contact warning {CONTACT_WARN_M * 1e3:.0f} mm, "
               f"contact: points realized within {CONTACT_TOL_M * 1e3:.0f} mm by the asked link with the pad within "
               f"{math.degrees(PAD_FACING_RAD):.0f} deg, joint at a limit within {AT_LIMIT_RAD:g} rad)")
    return "\n".join(out)


def contact_markers(grasp: RealizedGrasp, highlight: str | None = None, normal_len_m: float = 0.025) -> list:
    """Contacts to draw: [(point_palm (3,), normal_tip_palm (3,), rgba)] for `render_png(markers=...)`.

    Each realized contact is a dot with its inward normal drawn as a line ending at the
    point (the direction the finger pushes). Red: a finger with a problem; orange: a
    finger with a warning; the ``highlight`` finger (e.g. the moving one) yellow; the palm's
    contacts grey; else green.
    """
    T = np.asarray(grasp.obj.T_palm_obj)
    R, t = T[:3, :3], T[:3, 3]
    bad = {f for f in grasp.hand.fingers if any(f"fingers.{f}" in p for p in grasp.problems)}
    warn = {f for f in grasp.hand.fingers if any(f"fingers.{f}" in w for w in grasp.warnings)}
    out = []
    for c in grasp.contacts:
        f = c.finger
        rgba = ((1.0, 0.9, 0.0, 1.0) if f is not None and f == highlight else (0.9, 0.1, 0.1, 1.0) if f in bad
                else (1.0, 0.5, 0.0, 1.0) if f in warn else (0.35, 0.35, 0.35, 1.0) if f is None else (0.1, 0.8, 0.2, 1.0))
        p = R @ c.point + t
        out.append((p, p - normal_len_m * (R @ c.normal), rgba))
    return out
