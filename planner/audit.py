"""A plan checked against physics and its inputs, without simulation (``regrasp verify``).

The integrity record of a plan (`planner.plan.read_plan`) proves that a file is the one
``regrasp plan`` wrote; anyone can recompute a digest, so it cannot prove the file is
*right*. `audit_plan` re-derives what the plan claims from the hand, the object and the
recorded inputs, with the planner's own models:

- **hand**: every step's finger is a finger of the hand and its joints are that finger's;
  every joint value within the URDF limits (a coupled hand's: `planner.hand.Hand.lower`);
  every state and path waypoint keeps the hand's couplings (``q_f = m q_d + o``) within
  `planner.hand.Hand.coupling_tolerances` (the follower angle that moves its links by the
  IK's accepted 0.5 mm);
- **contacts**: every state's patch points lie on the object's surface (within
  ``SURFACE_TOL_M``) with an inward normal of the surface there (within ``NORMAL_TOL_DEG``
  of its normal cone: on an edge, any normal between the faces'; a mean contact, of the
  mean of the hand's own patch normals at the state's joints, which on a box edge is no
  face's normal); the
  hand's forward kinematics at the state's joints puts each touching finger on the
  object where its patch is (mean points within ``FK_TOL_M``), no link deeper in the
  object than ``PENETRATION_TOL_M`` and no lifted finger touching it;
- **paths**: every waypoint of every finger path (at most ``PATH_STEP_RAD`` apart) keeps the
  moving finger out of the object (no deeper than at the path's own ends or
  ``PENETRATION_TOL_M``) and out of the other fingers and the palm;
- **grasp logic**: a finger the state calls removable leaves force closure without it; a
  lifted state is force closure (the closure model: patches, the plan's friction);
- **chain**: the steps go from the initial grasp to the final one: the first and the last
  state touch with the fingers of the recorded input grasps, at their realized contacts;
- **inputs**: the object (shape, size, pose, mass) and the friction equal the recorded
  input grasps' when those files are present and unchanged;
- **reposing** (schema 4): every state is checked with the object at its own pose
  (`planner.plan_data.Plan.object_at`: contacts, forward kinematics, penetration, closure,
  grip forces and hold factors with the load in that state's object frame; the final grasp
  against the last state's pose), and every ``repose`` step waypoint by waypoint
  (`_check_repose`: the object path continuous from its from-state's pose to its
  to-state's, each holding finger's contact fixed on the moving object, joint limits and
  couplings, no link in the object at the waypoint's pose, a finger touching at one end only keeping still);
  ``summary.reposing`` is recomputed from the object paths;
- **parameters**: the gravity directions the claims are recomputed for hold the ones the
  plan's ``gravity_set`` or ``gravity`` gives for its hand; a plan whose parameters say it was
  verified in the simulator (`planner.options.verifies`) carries the record; ``summary.order``
  is the plan's own steps (`planner.plan.read_plan` refuses names and flags the planner does
  not write).

Each failed check is one line naming the state or step, the finger and the check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planner.closure import GRIP_CONE_SIDES, apply_contact_model, grasp_closure, min_grip_force
from planner.collision import HAND_OVERLAP_TOL_M
from planner.contacts import TOUCH_TOL_M, contact_patches, link_contacts
from planner.errors import AuditError, PlannerError
from planner.finger_scene import FingerScene
from planner.grasp import load_grasp
from planner.plan import read_plan, recorded_input
from planner.grip import HOLD_FACTOR, finger_statics, grip_program, hold_capacity
from planner.model import PALM, Friction
from planner.options import PLAN_OPTION_LIMITS, VERIFY_ENGINES, in_range, option_range, verifies
from planner.plan_data import OBJECT, Plan, hand_files_record, object_still, order_entry, plan_hand, pose_matrix
from planner.realization import PENETRATION_TOL_M as _GRASP_PENETRATION_TOL_M
from planner.realization import realize
from planner.repose import FOLLOW_TOL_M as _REPOSE_FOLLOW_TOL_M
from planner.repose import STEP_M as _REPOSE_STEP_M
from planner.repose import STEP_RAD as _REPOSE_STEP_RAD
from planner.repose import pose_distance

#: A patch point farther than this from the object's surface is not on it, m.
SURFACE_TOL_M = 1e-3
#: Recorded numbers (metrics, grip forces, hold factors) and their recomputation agree within
#: this (relative; the plan's text keeps 10 significant digits) ...
CLAIM_RTOL = 1e-6
#: ... or this (absolute: metrics near 0, forces in N, factors).
CLAIM_ATOL = 1e-9
#: A patch normal farther than this from the surface's inward normal there, deg.
NORMAL_TOL_DEG = 20.0
#: Points of a patch whose surface and normal are checked (the first and an even spread).
POINTS_PER_PATCH = 5
#: Distance outside the surface at which a normal is probed (`_normal_error_deg`), m.
NORMAL_PROBE_M = 2e-3
#: A touching finger's patch (mean point) farther than this from where the hand's forward
#: kinematics puts the finger's contact, m.
FK_TOL_M = 2e-3
#: Deepest a link may be inside the object at a state or along a path (beyond the path's
#: own ends), m: the planner's realized contacts are within `planner.realization.PENETRATION_TOL_M`
#: (0.5 mm); twice that leaves room for the files' rounding.
PENETRATION_TOL_M = 2 * _GRASP_PENETRATION_TOL_M
#: Deepest two links of different fingers (or a finger and the palm) may overlap, m: what the
#: planner's finger paths may (`planner.collision.HAND_OVERLAP_TOL_M`).
SELF_TOL_M = HAND_OVERLAP_TOL_M
#: Largest joint step between two path waypoints checked (the planner's paths are denser).
PATH_STEP_RAD = 0.02
#: Joint values may exceed the URDF limits by this (file rounding), rad or m.
LIMIT_TOL = 1e-6
#: Object pose and size equal to the inputs' within this, m (and rad of the quaternion).
INPUT_TOL = 1e-6
#: Consecutive object poses of a reposing step at most this far apart, m and rad: the
#: planner's waypoints are at most `planner.repose.STEP_M` (1 mm) and `planner.repose.STEP_RAD`
#: (2 deg) apart; the files' rounding (10 significant digits) adds far less than 1e-6.
REPOSE_STEP_M = _REPOSE_STEP_M + 1e-6
REPOSE_STEP_RAD = _REPOSE_STEP_RAD + 1e-6
#: A held contact point (fixed in its link, `link_contacts` at one end of a reposing step)
#: farther than this from its object point moved with the object, m: the planner accepts a
#: finger that follows within twice `planner.repose.FOLLOW_TOL_M` (0.4 mm, its own refusal
#: threshold); the end's contact recomputed from the file's rounded joints may sit a little
#: elsewhere on a flat link, hence 0.1 mm more.
REPOSE_FOLLOW_TOL_M = 2 * _REPOSE_FOLLOW_TOL_M + 1e-4
#: summary.reposing's object path (mm, deg) is recomputed within this (it is rounded to 3 decimals).
REPOSE_SUM_TOL = 2e-3
#: Most problems listed (the first ones; the count says how many there were).
MAX_LISTED = 40


@dataclass
class AuditReport:
    """What `audit_plan` found: ``problems`` (one line each, empty when the plan passed),
    ``checked`` (check name -> how many items it covered), ``total`` problems found."""

    source: str
    problems: list[str] = field(default_factory=list)
    checked: dict[str, int] = field(default_factory=dict)
    total: int = 0
    recorded_verification: bool = False

    @property
    def ok(self) -> bool:
        return self.total == 0

    def add(self, line: str) -> None:
        self.total += 1
        if len(self.problems) < MAX_LISTED:
            self.problems.append(line)

    def count(self, check: str, n: int = 1) -> None:
        self.checked[check] = self.checked.get(check, 0) + n

    def summary(self) -> str:
        what = ", ".join(f"{n} {k}" for k, n in self.checked.items())
        if self.ok:
            note = ("; its recorded simulator verification is not re-run here: regrasp replay PLAN --gravity-set N "
                    "re-runs it" if self.recorded_verification else "")
            return f"{self.source}: plan verified ({what}){note}"
        more = f" (first {len(self.problems)} listed)" if self.total > len(self.problems) else ""
        return f"{self.source}: {self.total} problem(s){more}; checked {what}"

    def __repr__(self) -> str:
        return f"AuditReport({self.source!r}, ok={self.ok}, problems={self.total})"


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-300))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def _as_recorded(patch, model: str, recorded):
    """A patch of the hand (at a state's joints, or of an input grasp) as a plan records it
    under its contact model: the per-link means ("link"; one mean when the recorded patch
    names no links, as schema 2 plans), the mean ("mean"), or every point ("patch")."""
    if model not in ("mean", "link"):
        return patch
    if model == "link" and getattr(recorded, "links", None) is None:
        model = "mean"
    return apply_contact_model({"p": patch}, model)["p"]


def _references(fk_patch, model: str, recorded) -> list:
    """Per recorded point of a "mean"/"link" patch, the hand's own contact it stands for at the
    state's joints: (point, normal) of the hand's patch as the plan's contact model makes it
    (`_as_recorded`), matched by link; None where unknown."""
    n = len(recorded[0])
    if fk_patch is None:
        return [None] * n
    ref = _as_recorded(fk_patch, model, recorded)
    links = getattr(recorded, "links", None)
    if model == "mean" or ref.links is None or links is None:
        return [(ref.points[0], ref.normals[0]) if len(ref.points) == 1 == n else None] * n
    at = {str(link): k for k, link in enumerate(ref.links)}
    return [(ref.points[at[str(link)]], ref.normals[at[str(link)]]) if str(link) in at else None for link in links]


def _normal_error_deg(obj, p_surface: np.ndarray, n_in: np.ndarray) -> float:
    """How far (deg) an inward normal is from the object's normal cone at a surface point:
    ``-n_in`` is an outward normal there when the point is the closest surface point of
    ``p + h (-n_in)`` (the definition of the normal cone of a convex body; on an edge or a
    corner every normal between the faces' is one). The closest point's offset ``d`` from
    ``p`` over ``h`` is the sine of the error on a face."""
    n = n_in / max(float(np.linalg.norm(n_in)), 1e-300)
    h = NORMAL_PROBE_M
    ps, _, _ = obj.closest_surface(p_surface - h * n)
    d = float(np.linalg.norm(np.asarray(ps, float) - p_surface))
    return math.degrees(math.asin(min(1.0, d / h)))


def _input_grasps(plan) -> dict:
    """name -> GraspSpec of the recorded inputs that are present and unchanged."""
    out = {}
    for name in ("initial", "final"):
        found = recorded_input(plan.inputs.get(name), plan.source)
        if found is None or found[2] is not None:
            continue
        try:
            out[name] = load_grasp(found[0])
        except PlannerError:
            continue
    return out


def _check_inputs(plan, rep: AuditReport, grasps: dict) -> None:
    """The plan's object and friction against the recorded input grasps'."""
    last = plan.steps[-1].to_state if plan.steps else 0
    for name, spec in grasps.items():
        rep.count("input grasps")
        # a reposing plan (schema 4) ends at the final grasp's pose: its last state's
        o = spec.object
        po = plan.object_at(last) if name == "final" and last < len(plan.states) else plan.object
        if o.shape != po.shape:
            rep.add(f"object.shape: {po.shape!r}, the {name} grasp's object is a {o.shape!r}")
            continue
        for key, mine, theirs in (("size", po.size, o.size), ("position", po.position, o.position)):
            if len(mine) != len(theirs) or not np.allclose(mine, theirs, atol=INPUT_TOL, rtol=0):
                rep.add(f"object.{key}: {list(mine)} differs from the {name} grasp's {list(theirs)}")
        qa, qb = np.asarray(po.quat_xyzw, float), np.asarray(o.quat_xyzw, float)
        if abs(abs(float(qa @ qb)) / max(np.linalg.norm(qa) * np.linalg.norm(qb), 1e-300) - 1.0) > INPUT_TOL:
            rep.add(f"object.quat_xyzw: {list(qa)} differs from the {name} grasp's {list(qb)}")
        mass = o.mass_kg  # the given or the default density's, as the planner used (`planner.plan_data.Plan`)
        if not math.isclose(po.mass_kg, float(mass), rel_tol=1e-6):
            rep.add(f"object.mass_kg: {po.mass_kg} kg, the {name} grasp {'says' if o.mass_given else 'gives (default density)'} {mass:.6g} kg")
        f = spec.friction
        for key in ("mu", "gamma"):
            mine, theirs = getattr(plan.friction, key), getattr(f, key)
            if not math.isclose(mine, theirs, rel_tol=1e-6):
                rep.add(f"friction.{key}: {mine}, the {name} grasp says {theirs}")


def _check_hand(plan, hand, rep: AuditReport) -> bool:
    """The hand's files as recorded, joint names, step fingers and joints, limits. False: the
    states cannot be posed."""
    recorded = (plan.hand or {}).get("files")
    if isinstance(recorded, dict):
        now = hand_files_record(hand)
        rep.count("hand files", len(recorded))
        changed = [f for f in recorded if now.get(f) != recorded[f]]
        if changed:
            rep.add(f"hand.files: {', '.join(changed[:4])}{' ...' if len(changed) > 4 else ''} of hand {hand.name} "
                    f"{'is' if len(changed) == 1 else 'are'} not the file(s) the plan was made with (sha256 differs or "
                    f"gone): re-plan with the hand as it is now")
    names = list(hand.joint_names)
    missing = [j for j in names if j not in plan.joints]
    unknown = [j for j in plan.joints if j not in names]
    if missing or unknown:
        rep.add(f"joints: the plan's joints are not the hand {hand.name}'s (missing {missing[:4]}, unknown {unknown[:4]})")
        return False
    col = {j: plan.joints.index(j) for j in names}
    lo, hi = np.asarray(hand.lower, float), np.asarray(hand.upper, float)
    coupling_tol = hand.coupling_tolerances() if hand.couplings else None
    for i, st in enumerate(plan.states):
        q = np.array([st.q[col[j]] for j in names])
        bad = [names[k] for k in np.flatnonzero((q < lo - LIMIT_TOL) | (q > hi + LIMIT_TOL))]
        if bad:
            rep.add(f"states[{i}].q: {', '.join(bad[:4])} outside the hand's joint limits")
        if coupling_tol is not None:
            broken = _coupling_break(hand, q, coupling_tol)
            if broken:
                rep.add(f"states[{i}].q: {broken}")
        rep.count("states")
    for k, s in enumerate(plan.steps):
        rep.count("steps")
        if s.action == "repose" and s.finger == OBJECT:  # the joints of every touching finger
            st = plan.states[s.from_state] if s.from_state < len(plan.states) else None
            to = plan.states[s.to_state] if s.to_state < len(plan.states) else None
            # (a finger touching at one end only keeps still: `_check_repose`)
            held = [f for f in (st.patches if st is not None else ()) if f in hand.fingers
                    and (to is None or f in to.patches)]
            want = sorted(j for f in held for j in hand.fingers[f].joints)
            if sorted(s.joints) != want:
                rep.add(f"steps[{k}] (repose object): joints {list(s.joints)[:6]} are not the joints of the touching "
                        f"fingers {', '.join(held) or '(none)'}")
            continue
        if s.finger not in hand.fingers:
            rep.add(f"steps[{k}].finger: {s.finger!r} is not a finger of {hand.name} ({', '.join(hand.fingers)})")
            continue
        want = tuple(hand.fingers[s.finger].joints)
        if tuple(s.joints) != want:
            rep.add(f"steps[{k}].joints: {list(s.joints)} are not finger {s.finger}'s joints {list(want)}")
    return True


def _coupling_break(hand, q: np.ndarray, tol: np.ndarray) -> str:
    """The worst coupling of ``q`` (nq,) broken by more than its tolerance
    (`planner.hand.Hand.coupling_tolerances`), in words, or ""."""
    err = hand.coupling_errors(q)
    over = np.flatnonzero(err > tol)
    if not len(over):
        return ""
    k = int(over[np.argmax(err[over] / tol[over])])
    c = hand.couplings[k]
    ix = hand.joint_names.index
    want = c.multiplier * q[ix(c.follows)] + c.offset
    return (f"{c.joint} = {q[ix(c.joint)]:.6f} breaks its coupling {c.joint} = {c.multiplier:g} {c.follows} "
            f"{'+' if c.offset >= 0 else '-'} {abs(c.offset):g} ({c.source}; {c.follows} = {q[ix(c.follows)]:.6f} "
            f"gives {want:.6f}) by {err[k]:.3g}, tolerance {tol[k]:.3g}"
            + (f" ({len(over)} couplings broken)" if len(over) > 1 else ""))


def _q(plan, hand, state_q) -> np.ndarray:
    col = {j: i for i, j in enumerate(plan.joints)}
    return np.array([state_q[col[j]] for j in hand.joint_names], float)


def _objects(plan) -> list:
    """The object at every state's pose (`planner.plan_data.Plan.object_at`; one object per
    distinct pose)."""
    out, seen = [], {}
    for i, st in enumerate(plan.states):
        key = st.object_pose
        if key not in seen:
            seen[key] = plan.object_at(i)
        out.append(seen[key])
    return out


def _check_states(plan, hand, objs, rep: AuditReport) -> list:
    """Contacts on the surface, at the forward kinematics, no penetration, removable, closure;
    each state with the object at its own pose (``objs``, `_objects`).
    Returns every state's `HandState`."""

    friction = plan.friction
    poses = []
    fk_cache: dict = {}
    # a plan made with one mean contact per finger ("mean") or per touching link ("link")
    # records the mean of a patch: on a curved surface, or a patch over two links, it lies
    # below the surface, and its normal is the mean of the patch's normals
    model = (plan.parameters or {}).get("contact_model", "patch")
    modelled = model in ("mean", "link")
    palm_fks: dict = {}
    # plans written since whole-hand grasps (their patches name their links) count a touching
    # palm as a contact; older ones could not
    whole_hand = any(getattr(p, "links", None) is not None for st in plan.states for p in st.patches.values())
    palm_ignored: list[int] = []
    for i, st in enumerate(plan.states):
        obj = objs[i]
        q = _q(plan, hand, st.q)
        hs = hand.state(q)
        poses.append(hs)
        fk = {}
        for f, fg in hand.fingers.items():  # a finger's contact depends on its own joints (and the object's pose) only
            key = (f, st.object_pose, tuple(np.round(q[list(fg.q_index)], 12)))
            if key not in fk_cache:
                fk_cache[key] = contact_patches(hand, hs, obj, fingers=[f]).get(f)
            if fk_cache[key] is not None:
                fk[f] = fk_cache[key]
        if st.object_pose not in palm_fks:  # the palm does not move: its contact is the same at one object pose
            palm_fks[st.object_pose] = contact_patches(hand, hs, obj, fingers=[], palm=True).get(PALM)
        palm_fk = palm_fks[st.object_pose]
        if palm_fk is not None:
            fk[PALM] = palm_fk
        for f, patch in st.patches.items():
            pts, nrm = patch
            rep.count("contacts", len(pts))
            if f not in hand.fingers and f != PALM:
                rep.add(f"states[{i}].patches.{f}: not a finger of {hand.name} (nor {PALM})")
                continue
            refs = _references(fk.get(f), model, patch) if modelled else [None] * len(pts)
            worst_d, worst_a = 0.0, 0.0
            # every patch's first point (the contact itself) and a spread of the ring points:
            # an edit moves a patch as a whole, and a mesh's surface query costs per triangle
            pick = sorted(set(np.linspace(0, len(pts) - 1, min(len(pts), POINTS_PER_PATCH)).round().astype(int)))
            tol = SURFACE_TOL_M
            for k in pick:
                p_obj, n_in = np.asarray(pts[k], float), np.asarray(nrm[k], float)
                ps, _, _ = obj.closest_surface(p_obj)
                d = float(np.linalg.norm(np.asarray(ps) - p_obj))
                a = _normal_error_deg(obj, np.asarray(ps, float), n_in)
                tol_k = SURFACE_TOL_M
                if refs[k] is not None:
                    # a mean contact lies below a curved surface by construction, and its normal
                    # is the mean of its patch's normals: where the patch spans two faces (a box
                    # edge) it is no face's normal; its reference is the hand's own contact (of
                    # that link) at the state's joints, under the same model
                    ref_p, ref_n = refs[k]
                    a = min(a, _angle_deg(n_in, ref_n))
                    tol_k += abs(obj.closest_surface(ref_p)[2])
                    tol = max(tol, tol_k)
                if d > tol_k:
                    worst_d = max(worst_d, d)
                worst_a = max(worst_a, a)
            if worst_d > 0:
                rep.add(f"states[{i}].patches.{f}: a contact point lies {worst_d * 1000:.1f} mm off the object's "
                        f"surface (tolerance {tol * 1000:.1f} mm)")
            if worst_a > NORMAL_TOL_DEG:
                rep.add(f"states[{i}].patches.{f}: a contact normal is {worst_a:.0f} deg from the surface's inward "
                        f"normal there (tolerance {NORMAL_TOL_DEG:.0f} deg)")
        for f in st.patches:
            if f not in hand.fingers and f != PALM:
                continue
            if f not in fk:
                d = hs.palm_object_distance(obj) if f == PALM else hs.finger_object_distance(obj, f)
                d = math.inf if d is None else d
                rep.add(f"states[{i}].patches.{f}: at the state's joints {'the palm' if f == PALM else 'finger ' + f} "
                        f"is {d * 1000:.1f} mm from the object: it does not touch where the plan says")
                continue
            mine = _as_recorded(fk[f], model, st.patches[f])
            off = float(np.linalg.norm(np.mean(st.patches[f][0], axis=0) - np.mean(mine[0], axis=0)))
            if off > FK_TOL_M:
                rep.add(f"states[{i}].patches.{f}: the {'palm' if f == PALM else 'finger'} touches the object "
                        f"{off * 1000:.1f} mm from its recorded contact (forward kinematics at the state's joints; "
                        f"tolerance {FK_TOL_M * 1000:.0f} mm)")
        for f in fk:
            if f not in st.patches:
                if f == PALM:
                    if whole_hand:  # plans since whole-hand grasps count a touching palm
                        palm_ignored.append(i)
                elif not FingerScene(hand, obj, q, f, TOUCH_TOL_M).lifted_as_far_as_it_goes(
                        q[list(hand.fingers[f].q_index)]):
                    # (a link no closing joint moves, where the open finger has it, carries nothing)
                    rep.add(f"states[{i}]: finger {f} touches the object at the state's joints but the plan has it lifted")
        for link, ld in hs.link_object(obj, [l for f in hand.fingers for l in hand.fingers[f].links]
                                       + list(hand.collision.finger_links(None))).items():
            if ld.distance_m < -PENETRATION_TOL_M:
                rep.add(f"states[{i}]: link {link} is {-ld.distance_m * 1000:.1f} mm inside the object "
                        f"(tolerance {PENETRATION_TOL_M * 1000:.1f} mm)")
        for a, b, depth in hs.self_collisions():
            if depth > SELF_TOL_M:
                rep.add(f"states[{i}]: links {a} and {b} overlap by {depth * 1000:.1f} mm")
        patches = st.patches
        for f in st.removable:
            if f == PALM:
                rep.add(f"states[{i}].removable: the palm is never removable (it is not lifted)")
                continue
            if f not in patches:  # a lifted finger is trivially removable
                continue
            rest = {g: v for g, v in patches.items() if g != f}
            if not rest or not grasp_closure(rest, friction).is_force_closure:
                rep.add(f"states[{i}].removable: {f} is marked removable but the other fingers are not force "
                        f"closure without it")
    if palm_ignored:
        which = f"states[{palm_ignored[0]}]" if len(palm_ignored) == 1 else \
            f"states {', '.join(map(str, palm_ignored[:6]))}{' ...' if len(palm_ignored) > 6 else ''}"
        rep.add(f"{which}: the palm touches the object but the plan does not count it as a contact")
    return poses


def _check_steps(plan, hand, objs, poses, rep: AuditReport) -> None:
    """Waypoints of every finger path: out of the object and of the other fingers and palm;
    every reposing move (`_check_repose`)."""
    for k, s in enumerate(plan.steps):
        if s.action == "repose" and s.finger == OBJECT:
            _check_repose(plan, hand, objs, poses, k, s, rep)
            continue
        if s.finger not in hand.fingers or tuple(s.joints) != tuple(hand.fingers[s.finger].joints):
            continue
        obj = objs[s.from_state]  # a finger's move never moves the object
        if s.action == "lift" and s.to_state < len(plan.states) and s.finger in plan.states[s.to_state].patches:
            rep.add(f"steps[{k}]: lift {s.finger}, but state {s.to_state} still has it on the object")
        if s.action == "land" and s.to_state < len(plan.states) and s.finger not in plan.states[s.to_state].patches:
            rep.add(f"steps[{k}]: land {s.finger}, but state {s.to_state} has it off the object")
        if s.action == "lift" and not plan.states[s.to_state].is_force_closure:
            rep.add(f"steps[{k}]: lifting {s.finger} leaves state {s.to_state}, which is not force closure")
        base = poses[s.from_state]
        links = list(hand.fingers[s.finger].links)
        ends = []
        for end in (s.from_state, s.to_state):
            d = poses[end].link_object(obj, links)
            ends.append(min((v.distance_m for v in d.values()), default=0.0))
        allowed = min(-PENETRATION_TOL_M, min(ends) - PENETRATION_TOL_M)
        path = np.asarray(s.path, float)
        cols = [hand.joint_names.index(j) for j in s.joints]
        if hand.couplings and len(path):  # the waypoints (a line between two coupled ones is coupled)
            tol = hand.coupling_tolerances()
            q = np.asarray(poses[s.from_state].q, float).copy()
            for w, row in enumerate(path):
                q[cols] = row
                broken = _coupling_break(hand, q, tol)
                if broken:
                    rep.add(f"steps[{k}] ({s.action} {s.finger}): path waypoint {w}: {broken}")
                    break
        lo, hi = np.asarray(hand.lower, float)[cols], np.asarray(hand.upper, float)[cols]
        out = np.flatnonzero(np.any((path < lo - LIMIT_TOL) | (path > hi + LIMIT_TOL), axis=0))
        if len(out):
            rep.add(f"steps[{k}] ({s.action} {s.finger}): the path takes {', '.join(s.joints[c] for c in out)} outside "
                    f"the hand's joint limits")
        dense = [path[0]]
        for a, b in zip(path[:-1], path[1:]):
            n = max(1, int(math.ceil(float(np.max(np.abs(b - a))) / PATH_STEP_RAD)))
            dense.extend(a + (b - a) * t for t in np.linspace(0.0, 1.0, n + 1)[1:])
        rep.count("waypoints", len(dense))
        deepest, overlap = (0.0, None), (0.0, None)
        for w in dense:
            hs = base.with_finger(s.finger, w)
            for link, ld in hs.link_object(obj, links).items():
                if ld.distance_m < allowed and -ld.distance_m > deepest[0]:
                    deepest = (-ld.distance_m, link)
            for a, b, depth in hs.self_collisions(fingers={s.finger}):
                if depth > SELF_TOL_M and depth > overlap[0]:
                    overlap = (depth, f"{a} and {b}")
        if deepest[1] is not None:
            rep.add(f"steps[{k}] ({s.action} {s.finger}): the path takes link {deepest[1]} {deepest[0] * 1000:.1f} mm "
                    f"into the object")
        if overlap[1] is not None:
            rep.add(f"steps[{k}] ({s.action} {s.finger}): the path makes links {overlap[1]} overlap by "
                    f"{overlap[0] * 1000:.1f} mm")


def _check_repose(plan, hand, objs, poses, k: int, s, rep: AuditReport) -> None:
    """A reposing step (schema 4): its object path starts and ends at its states' poses and
    moves at most `REPOSE_STEP_M` / `REPOSE_STEP_RAD` between waypoints; at every waypoint
    where the object moves each holding finger's contact point (its outermost touching
    link's, fixed in the link, where it touches at one end of the move: `link_contacts`)
    stays on the object point it holds, carried by the object path, within
    `REPOSE_FOLLOW_TOL_M` (the planner makes that contact stick; a finger's inner contacts
    follow as well as its joints allow and are checked for penetration only); at waypoints
    before or after the move with the object still (the fingers re-posturing, their pads
    rolling on their points) that link touches the object within `REPOSE_FOLLOW_TOL_M` of
    where it touches it when the move starts (ends); the joints stay within their limits and couplings; no link
    is deeper in the object (at the waypoint's pose) than `PENETRATION_TOL_M`, no two links of
    the hand overlap; a finger touching at one end only (released: the object carried away
    from it, or carried onto it; the palm likewise) keeps still."""
    tag = f"steps[{k}] (repose object)"
    n = len(plan.states)
    if not (0 <= s.from_state < n and 0 <= s.to_state < n):
        return
    a, b = plan.states[s.from_state], plan.states[s.to_state]
    fa, fb = set(a.patches) - {PALM}, set(b.patches) - {PALM}
    held = [f for f in a.patches if f in hand.fingers and f in fb]
    # a finger touching at one end only: the object carried away from it (released) or onto it;
    # it keeps still (its joints are not the step's and equal in both states)
    for f in sorted(fa ^ fb):
        if f not in hand.fingers:
            continue
        moved = [j for j in hand.fingers[f].joints if j in s.joints]
        ia = [plan.joints.index(j) for j in hand.fingers[f].joints if j in plan.joints]
        if moved or np.any(np.abs(np.asarray(a.q)[ia] - np.asarray(b.q)[ia]) > INPUT_TOL):
            rep.add(f"{tag}: {f} touches at state {s.from_state if f in fa else s.to_state} only, yet its joints move: "
                    f"a reposing move keeps its fingers on the object, or carries it away from (onto) a finger "
                    f"that keeps still")
    path = np.asarray(s.path, float)
    opath = np.asarray(s.object_path or (), float)
    if not len(path) or len(opath) != len(path):
        rep.add(f"{tag}: {len(opath)} object poses for {len(path)} waypoints: expected one per waypoint")
        return
    Ts = [pose_matrix(p) for p in opath]
    rep.count("reposing waypoints", len(Ts))
    # (a) the object path: from the from-state's pose to the to-state's, in small steps
    for end, T, which in ((s.from_state, Ts[0], "starts"), (s.to_state, Ts[-1], "ends")):
        mm, deg = pose_distance(objs[end].T_palm_obj, T)
        if mm > INPUT_TOL * 1e3 * 10 or deg > math.degrees(INPUT_TOL * 10):
            rep.add(f"{tag}: the object path {which} {mm:.3f} mm / {deg:.3f} deg from state {end}'s object pose")
    jumps = []
    for w in range(1, len(Ts)):
        mm, deg = pose_distance(Ts[w - 1], Ts[w])
        if mm > REPOSE_STEP_M * 1e3 or math.radians(deg) > REPOSE_STEP_RAD:
            jumps.append((max(mm / (REPOSE_STEP_M * 1e3), math.radians(deg) / REPOSE_STEP_RAD), w, mm, deg))
    if jumps:
        _, w, mm, deg = max(jumps, key=lambda j: j[0])  # the largest (the first of equal ones)
        rep.add(f"{tag}: object path waypoint {w}: the object jumps {mm:.2f} mm / {deg:.2f} deg from waypoint {w - 1} "
                f"(at most {REPOSE_STEP_M * 1e3:.0f} mm / {math.degrees(REPOSE_STEP_RAD):.0f} deg)"
                + (f" ({len(jumps)} jumps)" if len(jumps) > 1 else ""))
    # (c) joints within their limits and couplings
    try:
        cols = [hand.joint_names.index(j) for j in s.joints]
    except ValueError:
        return  # named by _check_hand
    lo, hi = np.asarray(hand.lower, float)[cols], np.asarray(hand.upper, float)[cols]
    out = np.flatnonzero(np.any((path < lo - LIMIT_TOL) | (path > hi + LIMIT_TOL), axis=0))
    if len(out):
        w = int(np.flatnonzero(np.any((path[:, out] < lo[out] - LIMIT_TOL) | (path[:, out] > hi[out] + LIMIT_TOL),
                                      axis=1))[0])
        rep.add(f"{tag}: path waypoint {w}: {', '.join(s.joints[c] for c in out)} outside the hand's joint limits")
    tol = hand.coupling_tolerances() if hand.couplings else None
    base = np.asarray(poses[s.from_state].q, float)
    states = []
    coupled = True
    for w, row in enumerate(path):
        q = base.copy()
        q[cols] = row
        if tol is not None and coupled:
            broken = _coupling_break(hand, q, tol)
            if broken:
                rep.add(f"{tag}: path waypoint {w}: {broken}")
                coupled = False
        states.append(hand.state(q))
    # (b) every holding contact fixed on the object while it moves: anchored at either end of
    # the move (the planner moves from a grasp; a move back to the final grasp is one computed
    # from it, reversed). Waypoints before and after the object moves, with it still, re-posture
    # the fingers (`planner.pose_search._reposture`: two postures touching the same points, the
    # pads rolling on them): there each holding finger's outermost link must still touch the
    # object point it holds while the object moves.
    same = [object_still(opath[w - 1], opath[w]) for w in range(1, len(Ts))]
    m0 = 0
    while m0 < len(same) and same[m0]:
        m0 += 1
    m1 = len(Ts) - 1
    while m1 > m0 and same[m1 - 1]:
        m1 -= 1
    ends = [(poses[s.from_state], objs[s.from_state], s.from_state), (poses[s.to_state], objs[s.to_state], s.to_state)]
    ends += [(states[w], objs[s.from_state].with_pose(Ts[w]), f"path waypoint {w}") for w in dict.fromkeys((m0, m1))
             if 0 < w < len(Ts) - 1]
    best = None
    for hs_end, obj_end, end in ends:
        T_end = np.asarray(obj_end.T_palm_obj, float)
        anchors, outer = [], {}
        for c in link_contacts(hand, hs_end, obj_end, fingers=held):
            order = hand.fingers[c.finger].contact_links
            rank = order.index(c.link) if c.link in order else -1
            if c.finger in outer and outer[c.finger] >= rank:
                continue  # the finger's outermost touching link (its tip side) holds
            outer[c.finger] = rank
            p_palm = T_end[:3, :3] @ np.asarray(c.point, float) + T_end[:3, 3]
            T_link = hs_end.link_pose(c.link)
            anchors = [a for a in anchors if a[0] != c.finger]
            anchors.append((c.finger, c.link, T_link[:3, :3].T @ (p_palm - T_link[:3, 3]), np.asarray(c.point, float)))
        worst = (0.0, None, None, None)
        for w in range(m0, m1 + 1):
            hs, T = states[w], Ts[w]
            for finger, link, p_link, p_obj in anchors:
                T_link = hs.link_pose(link)
                err = float(np.linalg.norm(T_link[:3, :3] @ p_link + T_link[:3, 3] - (T[:3, :3] @ p_obj + T[:3, 3])))
                if err > worst[0]:
                    worst = (err, w, finger, link)
        missing = sorted(set(held) - {a[0] for a in anchors})
        if best is None or (len(missing), worst[0]) < (len(best[1]), best[0][0]):
            best = (worst, missing, end, anchors)
    worst, missing, end, anchors = best
    rep.count("reposing contacts", len(held))
    if missing:
        where = f"state {end}" if isinstance(end, int) else end
        rep.add(f"{tag}: finger {', '.join(missing)} does not touch the object at {where} (forward kinematics): it "
                f"cannot hold it")
    if worst[0] > REPOSE_FOLLOW_TOL_M:
        err, w, finger, link = worst
        rep.add(f"{tag}: path waypoint {w}: finger {finger}'s contact on link {link} is {err * 1e3:.2f} mm from the "
                f"object point it holds (forward kinematics against the object path; tolerance "
                f"{REPOSE_FOLLOW_TOL_M * 1e3:.1f} mm): it does not stay fixed on the object")
    def touching(w):  # (finger, link) -> where it touches the object at waypoint w (object frame)
        obj_w = objs[s.from_state].with_pose(Ts[w])
        return {(c.finger, c.link): np.asarray(c.point, float) for c in link_contacts(hand, states[w], obj_w, fingers=held)}

    rolled = (0.0, None, None, None)
    for ref, still in ((m0, range(0, m0)), (m1, range(m1 + 1, len(Ts)))):
        if not len(still):
            continue
        at_ref = touching(ref)  # where the move starts (ends): the points the re-posturing keeps
        for w in still:
            at_w = touching(w)
            for finger, link, _, _ in anchors:
                if (finger, link) not in at_ref:
                    continue  # (named above: the move's anchor does not touch there)
                err = float(np.linalg.norm(at_w[finger, link] - at_ref[finger, link])) if (finger, link) in at_w \
                    else math.inf
                if err > rolled[0]:
                    rolled = (err, w, finger, link)
    if rolled[0] > REPOSE_FOLLOW_TOL_M:
        err, w, finger, link = rolled
        rep.add(f"{tag}: path waypoint {w} (the object still, the fingers re-posturing): finger {finger}'s link {link} "
                + (f"touches the object {err * 1e3:.2f} mm from the point it holds (tolerance "
                   f"{REPOSE_FOLLOW_TOL_M * 1e3:.1f} mm)" if math.isfinite(err) else "does not touch the object"))
    # (d) no link in the object at the waypoint's pose, no links overlapping
    links = [l for f in hand.fingers for l in hand.fingers[f].links] + list(hand.collision.finger_links(None))
    deepest, overlap = (0.0, None, None), (0.0, None, None)
    for w, (hs, T) in enumerate(zip(states, Ts)):
        obj = objs[s.from_state].with_pose(T)
        for link, ld in hs.link_object(obj, links).items():
            if ld.distance_m < -PENETRATION_TOL_M and -ld.distance_m > deepest[0]:
                deepest = (-ld.distance_m, w, link)
        for la, lb, depth in hs.self_collisions():
            if depth > SELF_TOL_M and depth > overlap[0]:
                overlap = (depth, w, f"{la} and {lb}")
    if deepest[1] is not None:
        rep.add(f"{tag}: path waypoint {deepest[1]}: link {deepest[2]} is {deepest[0] * 1e3:.1f} mm inside the object "
                f"(tolerance {PENETRATION_TOL_M * 1e3:.1f} mm)")
    if overlap[1] is not None:
        rep.add(f"{tag}: path waypoint {overlap[1]}: links {overlap[2]} overlap by {overlap[0] * 1e3:.1f} mm")


def _check_reposing_summary(plan, rep: AuditReport) -> None:
    """summary.reposing (schema 4): the number of reposing moves and the object's path length
    (sum over the moves of the distance and angle between their ends, mm and deg)."""
    moves = [s for s in plan.steps if s.action == "repose" and s.object_path]
    record = (plan.summary or {}).get("reposing")
    if record is None:
        if moves:
            rep.add(f"summary.reposing: missing, but the plan has {len(moves)} reposing move(s)")
        return
    rep.count("claims")
    if not isinstance(record, dict):
        rep.add("summary.reposing: not a mapping")
        return
    mm = sum(pose_distance(pose_matrix(s.object_path[0]), pose_matrix(s.object_path[-1]))[0] for s in moves)
    deg = sum(pose_distance(pose_matrix(s.object_path[0]), pose_matrix(s.object_path[-1]))[1] for s in moves)
    if record.get("moves") != len(moves):
        rep.add(f"summary.reposing.moves: the file says {record.get('moves')!r}, its steps have {len(moves)}")
    for key, mine in (("object_path_mm", mm), ("object_path_deg", deg)):
        v = record.get(key)
        if not isinstance(v, (int, float)) or isinstance(v, bool) or abs(float(v) - mine) > REPOSE_SUM_TOL:
            rep.add(f"summary.reposing.{key}: the file says {v!r}, its object paths give {mine:.3f}")


def _check_order(plan, rep: AuditReport) -> None:
    """summary.order, the gait sequence other tools read from a plan (``finger:lift``,
    ``finger:land>label``, ``object:repose``, in step order), is the plan's own steps: a lift
    and a landing per step (the landing with the label its finger has in the state it
    reaches), a reposing move; finger moves between them are not listed."""
    summary = plan.summary or {}
    if "order" not in summary:  # (no claim made: other tools read the steps)
        return
    rep.count("claims")
    order = summary["order"]
    if not (isinstance(order, (list, tuple)) and all(isinstance(o, str) for o in order)):
        rep.add("summary.order: not a list of moves ('finger:lift', 'finger:land>label', 'object:repose')")
        return
    mine = [order_entry(s.finger, s.action, plan.states[s.to_state].fingers.get(s.finger))
            for s in plan.steps if s.action in ("lift", "land", "repose")]
    if list(order) != mine:
        k = next((i for i, (a, b) in enumerate(zip(order, mine)) if a != b), min(len(order), len(mine)))
        said = order[k] if k < len(order) else "nothing more"
        rep.add(f"summary.order[{k}]: the file says {said!r}, its steps give "
                f"{mine[k] if k < len(mine) else 'nothing more'!r} ({len(order)} entries, the steps {len(mine)})")


def _close(a, b) -> bool:
    """Two recorded numbers agree (plans round floats to `planner.plan_data.FLOAT_DIGITS`
    digits; the linear programs agree far better than ``CLAIM_RTOL``)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = float(a), float(b)
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= CLAIM_ATOL + CLAIM_RTOL * max(abs(a), abs(b))


def _directions(plan, hand, rep: AuditReport, obj=None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, gravity in the object frame, the weight's wrench there) of every direction the plan
    was made for (the loads `planner.slots.build_problem` gives the planner), the object at
    ``obj``'s pose (default the plan's; a reposed state's own: `planner.plan_data.Plan.object_at`)."""
    rows = (plan.parameters or {}).get("gravity_directions") or []
    out = []
    R = np.asarray((plan.object if obj is None else obj).T_palm_obj, dtype=float)[:3, :3]
    for k, row in enumerate(rows):
        try:
            name, g = str(row["name"]), np.asarray(row["gravity"], dtype=float).reshape(3)
        except (KeyError, TypeError, ValueError):
            rep.add(f"parameters.gravity_directions[{k}]: not a name and a 3-vector")
            continue
        if not np.all(np.isfinite(g)):
            rep.add(f"parameters.gravity_directions[{k}]: the gravity is not finite")
            continue
        g_obj = R.T @ g
        out.append((name, g_obj, np.r_[float(plan.object.mass_kg) * g_obj, np.zeros(3)]))
    return out


def _check_gravity_directions(plan, hand, rep: AuditReport) -> None:
    """The directions a plan lists hold the ones its ``gravity`` or ``gravity_set`` gives for
    its hand (`planner.options.gravity_directions_of`): the claims are recomputed for the listed
    ones, so a file listing fewer (or others) than its parameters ask would be checked against
    less. More is stricter, and some plans wrote it (``--gravity-set 1`` listed palm up too
    until 2026-11-30). A list needs the parameters it comes from; plans older than the list
    (``--gravity`` plans before 2026-11-30) are not checked."""
    params = plan.parameters or {}
    if "gravity_directions" not in params:
        return
    rep.count("claims")
    if "gravity" not in params and "gravity_set" not in params:
        rep.add("parameters.gravity_directions: listed without the gravity or gravity_set they come from")
        return
    from types import SimpleNamespace

    from planner.options import gravity_directions_of

    try:
        want = [(n, np.asarray(g, dtype=float).reshape(3)) for n, g in gravity_directions_of(
            SimpleNamespace(gravity=params.get("gravity"), gravity_set=params.get("gravity_set")), hand)]
    except (PlannerError, TypeError, ValueError):
        rep.add(f"parameters.gravity: {params.get('gravity')!r} is not a 3-vector in m/s^2")
        return
    rows = params.get("gravity_directions") or []
    try:
        have = {str(row["name"]): np.asarray(row["gravity"], dtype=float).reshape(3) for row in rows}
    except (KeyError, TypeError, ValueError):
        return  # (`_directions` names the row)
    missing = [n for n, g in want if n not in have or not np.allclose(have[n], g, rtol=0.0, atol=1e-9)]
    if missing:
        given = f"gravity_set {params.get('gravity_set')}" if params.get("gravity") is None \
            else f"gravity {params.get('gravity')}"
        rep.add(f"parameters.gravity_directions: {sorted(have) or 'none'}, but {given} gives "
                f"{[n for n, _ in want]} for {hand.name} ({', '.join(missing)} missing or other)")


def _check_claims(plan, hand, poses, rep: AuditReport, objs=None, verified: bool = True) -> None:
    """What the plan says of its states and of itself, recomputed from its contacts and the
    hand: every state's force closure and metric, its grip forces and hold factors (per
    planned gravity direction), the summary's bottleneck and mean metric and largest grip
    force, and the shape of a recorded verification. A file cannot claim a number the
    planner's own models do not give."""
    params = plan.parameters or {}
    friction = plan.friction
    for name, (low, high, open_low) in PLAN_OPTION_LIMITS.items():  # the parameters a planner could have used
        value = params.get(name)
        if name in params and value is not None and not all(
                in_range(v, low, high, open_low) for v in (value if isinstance(value, (list, tuple)) else (value,))):
            rep.add(f"parameters.{name}: {value!r} is not a value the planner takes ({option_range(low, high, open_low)})")
    margin = params.get("friction_margin", 1.0)
    if not (isinstance(margin, (int, float)) and not isinstance(margin, bool) and 0 < margin <= 1):
        rep.add(f"parameters.friction_margin: {margin!r} is not in (0, 1]")
        margin = 1.0
    margin = float(margin)
    # a plan for execution holds at least its hold factor in every planned direction, and no
    # file makes that less than execution mode's own
    wanted = params.get("hold_factor")
    wanted = float(wanted) if isinstance(wanted, (int, float)) and not isinstance(wanted, bool) else None
    if params.get("execution") and wanted is not None and wanted < HOLD_FACTOR:
        rep.add(f"parameters.hold_factor: {wanted:g}, below execution mode's {HOLD_FACTOR:g}")
    grip_friction = friction if margin == 1 else Friction(friction.mu * margin, friction.gamma * margin, friction.edges)
    sides = int(params.get("grip_cone_sides") or GRIP_CONE_SIDES)
    cap = params.get("max_finger_force_n")
    _check_gravity_directions(plan, hand, rep)
    directions = _directions(plan, hand, rep)
    # a reposed state's loads in its own object frame (the same gravity in the palm frame)
    by_pose = {None: directions}
    metrics: list[float] = []
    every: list[float] = []  # every state's metric (a reposing plan's summary means these: `planner.pose_search.compose`)
    grips: list[float] = []
    previous = None
    for i, st in enumerate(plan.states):
        rep.count("claims")
        try:
            c = grasp_closure(st.patches, friction)
        except PlannerError as e:
            rep.add(f"states[{i}]: its contacts cannot be evaluated: {e}")
            continue
        if bool(c.is_force_closure) != bool(st.is_force_closure):
            rep.add(f"states[{i}].closure.is_force_closure: the file says {bool(st.is_force_closure)}, its contacts "
                    f"give {bool(c.is_force_closure)}")
        if not _close(c.metric, st.metric):
            rep.add(f"states[{i}].closure.metric: the file says {st.metric:.6g}, its contacts give {c.metric:.6g}")
        every.append(float(c.metric))
        key = tuple((f, np.asarray(p[0]).round(9).tobytes()) for f, p in sorted(st.patches.items()))
        if key != previous:  # a lift and the move after it end in the same graph state
            metrics.append(float(c.metric))
        previous = key
        if objs is not None and st.object_pose is not None and directions:
            if st.object_pose not in by_pose:
                by_pose[st.object_pose] = _directions(plan, hand, AuditReport(""), objs[i])
            directions = by_pose[st.object_pose]
        else:
            directions = by_pose[None]
        if not directions:
            if st.grip_force_n is not None or st.hold_factor_by_gravity:
                rep.add(f"states[{i}]: grip forces or hold factors recorded for a plan made without gravity")
            continue
        forces = {n: min_grip_force(st.patches, grip_friction, load, cone_sides=sides) for n, _, load in directions}
        recorded = dict(st.grip_force_by_gravity_n or {})
        if set(recorded) != set(forces):
            rep.add(f"states[{i}].grip_force_by_gravity_n: directions {sorted(recorded)}, the plan's parameters "
                    f"{sorted(forces)}")
        for n, f in forces.items():
            if n in recorded and not _close(recorded[n], f):
                rep.add(f"states[{i}].grip_force_by_gravity_n.{n}: the file says {recorded[n]:.6g} N, its contacts "
                        f"give {f:.6g} N")
        if not _close(st.grip_force_n, max(forces.values())):
            rep.add(f"states[{i}].grip_force_n: the file says {st.grip_force_n}, its contacts give "
                    f"{max(forces.values()):.6g} N")
        grips.append(max(forces.values()))
        if st.hold_factor_by_gravity is not None:
            q = np.asarray(poses[i].q, dtype=float) if i < len(poses) else None
            T_obj = (plan.object if objs is None else objs[i]).T_palm_obj
            statics = {f: finger_statics(hand, f, q, p[0], T_obj, links=getattr(p, "links", None))
                       for f, p in st.patches.items() if f in hand.fingers}
            program = grip_program(st.patches, statics, friction, margin=margin, cone_sides=sides)
            held = dict(st.hold_factor_by_gravity)
            for n, g, load in directions:
                mine = hold_capacity(st.patches, statics, friction, load, g,
                                     force_cap_n=cap, program=program, witness=False).factor
                if n not in held:
                    rep.add(f"states[{i}].hold_factor_by_gravity: no factor for the planned direction {n}")
                elif not _close(held[n], mine):
                    rep.add(f"states[{i}].hold_factor_by_gravity.{n}: the file says {held[n]:.6g}x, the hand's "
                            f"joints hold {mine:.6g}x its weight")
                if wanted is not None and mine < wanted * (1 - CLAIM_RTOL) - CLAIM_ATOL:
                    rep.add(f"states[{i}]: holds {mine:.6g}x its weight in {n}, the plan asks {wanted:g}x "
                            f"(parameters.hold_factor)")
    s = plan.summary or {}
    if metrics and "bottleneck_metric" in s and not _close(s["bottleneck_metric"], min(metrics)):
        rep.add(f"summary.bottleneck_metric: the file says {s['bottleneck_metric']}, its states give {min(metrics):.6g}")
    if metrics and "mean_metric" in s and not _close(s["mean_metric"], float(np.mean(metrics))) and not (
            plan.reposes and _close(s["mean_metric"], float(np.mean(every)))):
        rep.add(f"summary.mean_metric: the file says {s['mean_metric']}, its states give {float(np.mean(metrics)):.6g}")
    if "bottleneck_grip_force_n" in s and not _close(s["bottleneck_grip_force_n"], max(grips) if grips else None):
        rep.add(f"summary.bottleneck_grip_force_n: the file says {s['bottleneck_grip_force_n']}, its states give "
                f"{max(grips) if grips else None}")
    _check_reposing_summary(plan, rep)
    _check_order(plan, rep)
    _check_verification(plan, [n for n, _, _ in by_pose[None]], rep, verified)


def _check_verification(plan, planned: list[str], rep: AuditReport, verified: bool = True) -> None:
    """A recorded verification is a claim the audit cannot re-run (``regrasp replay
    --gravity-set`` does): it must at least be one the planner could have written: asked for
    by the parameters, over the planned directions, every one held."""
    record = (plan.summary or {}).get("verification")
    params = plan.parameters or {}
    if record is None:
        # the planner records every verification it runs (`planner.regrasp.plan_gaits`: the graph
        # search, with gravity; `planner.pose_search`: every reposing plan)
        if verified and verifies(params.get("verify"), params.get("strategy", "graph"), planned, bool(plan.reposes)):
            rep.count("claims")
            rep.add("summary.verification: missing, yet the plan's parameters say it was verified in the simulator "
                    "(parameters.verify: true)")
        return
    rep.count("claims")
    rep.recorded_verification = True
    if not params.get("verify"):
        rep.add("summary.verification: recorded, but the plan's parameters say it was made without verification")
        return
    directions = record.get("directions") if isinstance(record, dict) else None
    if not isinstance(directions, dict):
        rep.add("summary.verification.directions: missing or not a mapping of direction -> verdict")
        return
    if sorted(directions) != sorted(planned):
        rep.add(f"summary.verification.directions: {sorted(directions)}, the plan was made for {sorted(planned)}")
    failed = [n for n, v in directions.items() if not (isinstance(v, dict) and v.get("passed") is True)]
    if failed:
        rep.add(f"summary.verification: {', '.join(map(str, failed))} not held, yet the plan was returned")
    # the engine(s) it was verified in (a record without one, written before MuJoCo, was pybullet's)
    engine = record.get("engine", "pybullet")
    if engine not in VERIFY_ENGINES:
        rep.add(f"summary.verification.engine: {engine!r} is no physics engine; valid: {', '.join(VERIFY_ENGINES)}")
    elif engine == "both" and sorted(record.get("engines") or ()) != ["mujoco", "pybullet"]:
        rep.add("summary.verification.engines: verified in both engines, yet the record has not each engine's verdicts")


def _check_chain(plan, hand, rep: AuditReport, grasps: dict) -> None:
    """The plan starts at the initial grasp and ends at the final one."""
    if not plan.states:
        rep.add("states: the plan has no state")
        return
    last = plan.steps[-1].to_state if plan.steps else 0
    for name, index in (("initial", 0), ("final", last)):
        spec = grasps.get(name)
        if spec is None:
            continue
        try:
            g = realize(spec, hand, suggest=False)  # (its warnings are not shown)
        except PlannerError:
            continue
        rep.count("grasp ends")
        st = plan.states[index]
        want, have = sorted(g.patches), sorted(st.patches)
        if want != have:
            rep.add(f"states[{index}]: the plan's {'first' if index == 0 else 'last'} state touches with "
                    f"{', '.join(have) or 'no finger'}, the {name} grasp with {', '.join(want)}: the plan does not "
                    f"{'start' if index == 0 else 'end'} at the {name} grasp")
            continue
        model = (plan.parameters or {}).get("contact_model", "patch")
        for f in want:
            ref = _as_recorded(g.patches[f], model, st.patches[f])
            off = float(np.linalg.norm(np.mean(st.patches[f][0], axis=0) - np.mean(ref[0], axis=0)))
            if off > FK_TOL_M:
                rep.add(f"states[{index}].patches.{f}: {off * 1000:.1f} mm from the {name} grasp's contact: the plan "
                        f"does not {'start' if index == 0 else 'end'} at the {name} grasp")


def audit_plan(plan, hand=None, paths: bool = True, verified: bool = True) -> AuditReport:
    """Check a plan against physics and its inputs (see the module's docstring).

    Args:
        plan: a `planner.plan_data.Plan` (e.g. `read_plan`'s) or the path of a plan file.
        hand: the plan's `planner.hand.Hand`; default the one its ``hand.spec`` names.
        paths: check the finger paths' waypoints (False: states, chain and inputs only).
        verified: a plan asking for verification has its record (False: the planner's own
            check of a plan it is still verifying).

    Returns:
        `AuditReport`: ``ok``, ``problems`` (one line each), ``checked`` counts.
    """
    if not isinstance(plan, Plan):
        plan = read_plan(plan)
    src = plan.source or "<plan>"
    rep = AuditReport(str(src))
    if hand is None:
        hand = plan_hand(plan)
    objs = _objects(plan)  # every state's object at its own pose (schema 4)
    grasps = _input_grasps(plan)
    _check_inputs(plan, rep, grasps)
    if not _check_hand(plan, hand, rep):
        return rep
    poses = _check_states(plan, hand, objs, rep)
    if paths:
        _check_steps(plan, hand, objs, poses, rep)
    _check_claims(plan, hand, poses, rep, objs, verified)
    _check_chain(plan, hand, rep, grasps)
    return rep


def require_sound(plan, hand=None) -> AuditReport:
    """`audit_plan`, raising `planner.errors.AuditError` (one line: the first problem and how
    many there are) when the plan fails a check; ``replay`` and ``view`` call it first."""
    if not isinstance(plan, Plan):
        plan = read_plan(plan)
    # every path is checked whatever the file's parameters say (a plan made with --no-motion
    # has straight joint-space segments: they are refused like any path if they cut the
    # object or a finger)
    rep = audit_plan(plan, hand)
    if not rep.ok:
        more = f" (and {rep.total - 1} more: regrasp verify lists them)" if rep.total > 1 else ""
        raise AuditError(rep.source, "", f"the plan fails a physics check: {rep.problems[0]}{more}")
    return rep
