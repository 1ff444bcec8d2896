"""Realization of a grasp: a `planner.grasp.GraspSpec` turned into a hand configuration.

Realization (``realize``) turns a spec into a hand configuration: contact fingers are
placed by IK of the pad onto the point with the pad facing into the object, then closed
with the closing procedure (thesis eqs. (8)-(9)) until they touch without penetrating;
posture fingers are closed from their posture; free fingers stay open. The contacts are
then measured from the geometry (several points per touching link) and scored with the
force-closure test and metric (thesis eqs. (1)-(7)) and Algorithm 1 (removable fingers).
The result is a `RealizedGrasp`; `grasp_findings` says where it differs from its file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from planner.closure import apply_contact_model, grasp_closure, removable_fingers
from planner.contacts import TOUCH_TOL_M, collisions, contact_patches, link_contacts, touching_links
from planner.errors import KinematicsError, PlannerError, UnknownNameError
from planner.grasp import GraspSpec, input_record, load_grasp, load_hand
from planner.gravity import gravity_directions
from planner.grip import grasp_hold
from planner.ik import UnreachableError
from planner.model import PALM, Patch

#: Contact fingers are placed this far out along the surface normal, then closed onto it.
APPROACH_M = 0.004
#: A closed finger landing farther than this from its contact point is re-placed along the normal.
LANDING_TOL_M = 0.004
#: `check` fails a grasp with a link deeper than this in the object, the palm or another finger.
PENETRATION_TOL_M = 5e-4
#: `check` warns when a contact point is realized farther than this from where the file put it.
CONTACT_WARN_M = 3e-3
#: A joint within this of a limit is at the limit.
AT_LIMIT_RAD = 1e-3
#: `check` warns when a contact's pad faces farther than this from the contact normal.
NORMAL_WARN_RAD = math.radians(45.0)
#: The contact models (`planner.closure.CONTACT_MODELS`) in words.
CONTACT_MODEL_WORDS = {"patch": "every patch point", "mean": "one mean contact per finger",
                       "link": "one contact per touching link"}


# --------------------------------------------------------------------------- data


@dataclass(frozen=True, eq=False)
class RealizedGrasp:
    """A grasp turned into a hand configuration, with its measured contacts.

    Attributes:
        spec: the grasp spec.
        hand: the `planner.hand.Hand`.
        obj: the `planner.objects.GraspObject`.
        friction: `planner.model.Friction`.
        q: (nq,) whole-hand joint configuration, read-only.
        finger_q: finger -> (n_joints,) values of that finger's joints.
        patches: finger -> (p_obj (n, 3), n_in_obj (n, 3)) for touching fingers only.
        touching: finger -> links touching the object.
        closure: `planner.closure.Closure` of all patches.
        removable: fingers whose contacts can all be dropped keeping force closure.
        collisions: (name_a, name_b, depth_m) finger-finger / finger-palm / penetration.
        missing: fingers the file wants on the object that do not touch it.
        contacts: one `planner.model.Contact` per touching link (`planner.contacts.link_contacts`:
            finger, link, point, inward normal in the object frame, distance_m).
        problems: why the grasp is not what the file asks (a placed finger that does not
            touch, a penetration beyond `PENETRATION_TOL_M`, a closing joint at its closing
            limit the file did not ask for): `check` exits 1 when there is any.
        warnings: what the user should know but does not fail the check (a contact realized
            more than `CONTACT_WARN_M` from its point or by another link than the pad, IK
            placed position-only, other joints at a limit).
    """

    spec: GraspSpec
    hand: Any
    obj: Any
    friction: Any
    q: np.ndarray
    finger_q: Mapping[str, np.ndarray]
    patches: Mapping[str, tuple[np.ndarray, np.ndarray]]
    touching: Mapping[str, tuple[str, ...]]
    closure: Any
    removable: frozenset
    collisions: tuple = field(default=())
    missing: tuple[str, ...] = field(default=())
    contacts: tuple = field(default=())
    problems: tuple[str, ...] = field(default=())
    warnings: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        """Force closure and as written (no `problems`): what `check` exits 0 for."""
        return self.is_force_closure and not self.problems

    def require_placed(self) -> "RealizedGrasp":
        """This grasp, or PlannerError (one line) when a finger the file places does not touch
        the object (a plan must not treat it as lifted) or the palm is not what the file's
        ``palm:`` says (held and not touching, or free and touching)."""
        palm = [p for p in self.problems if p.startswith("palm: ")]
        if palm:
            raise PlannerError(f"{self.spec.path}: {palm[0]}; run regrasp check on it")
        if self.missing:
            name = self.missing[0]
            gap = self.hand.state(self.q).finger_object_distance(self.obj, name)
            raise PlannerError(
                f"{self.spec.path}: fingers.{name}: the file places it but it does not touch the object "
                f"(misses it by {gap * 1e3:.1f} mm){'; so do ' + ', '.join(self.missing[1:]) if self.missing[1:] else ''}; "
                f"run regrasp check on it, then fix its contact/posture or make it free")
        return self

    @property
    def is_force_closure(self) -> bool:
        return bool(self.closure.is_force_closure)

    @property
    def metric(self) -> float:
        return float(self.closure.metric)

    @property
    def finger_collisions(self) -> tuple:
        """Collisions between two hand parts (finger-finger, finger-palm), not the object."""
        return tuple(c for c in self.collisions if not _is_object_name(c[0]) and not _is_object_name(c[1]))

    def closure_under(self, contact_model: str):
        """`planner.closure.Closure` of the grasp under a contact model (`CONTACT_MODELS`);
        "patch" is ``self.closure``."""
        if contact_model == "patch":
            return self.closure
        return grasp_closure(apply_contact_model(self.patches, contact_model), self.friction)

    def mean_contact_closure(self, contact_model: str = "mean") -> dict:
        """Closure with one mean contact per finger (contact model "mean", or another one):
        whether the grasp also holds with the point contacts rigid links give in the simulator."""
        if not self.patches:
            return {"force_closure": False, "metric": float("nan")}
        c = self.closure_under(contact_model)
        return {"force_closure": bool(c.is_force_closure), "metric": float(c.metric)}

    def hold(self, contact_model: str = "link", directions=None) -> list:
        """How the grasp holds its object in the six hand orientations of execution mode
        (`planner.gravity`, gravity set 6), or in ``directions`` ([(name, (3,) gravity, palm
        frame)]): `planner.grip.DirectionHold` per direction (the joints' torque limits, 3/4
        of the friction, under ``contact_model``); [] when not force closure under it."""
        if not self.patches or not self.closure_under(contact_model).is_force_closure:
            return []
        patches = apply_contact_model(self.patches, contact_model)
        return grasp_hold(self.hand, self.q, patches, self.obj.T_palm_obj, self.obj.mass_kg, self.friction,
                          gravity_directions(self.hand.palm_normal, 6) if directions is None else directions)

    def hold_unavailable(self, contact_model: str = "link") -> str | None:
        """Why `hold` gives no load table under ``contact_model`` (no contact, not force
        closure under it), None when it gives one."""
        if not self.patches:
            return "no finger touches the object"
        c = self.closure_under(contact_model)
        if c.is_force_closure:
            return None
        return (f"not force closure with {CONTACT_MODEL_WORDS.get(contact_model, contact_model)} (metric {c.metric:.4g}): "
                f"no contact forces hold every load, so no multiple of the weight is held in every direction")

    def palm_summary(self) -> dict:
        """Whether the palm touches and holds: the file's ``palm:`` mode, the palm links within
        the touch tolerance, its contact points (0 when it does not hold: not touching, or
        ``palm: free``) and the nearest palm-object distance, m."""
        links = [c.link for c in self.contacts if c.finger is None]
        gap = self.hand.state(self.q).palm_object_distance(self.obj)
        pts = self.patches.get(PALM)
        return {"mode": self.spec.palm, "touching": bool(links), "touching_links": links,
                "holds": pts is not None, "contact_points": 0 if pts is None else int(len(pts[0])),
                "distance_m": None if gap is None else float(gap)}

    def summary(self, hold: list | None = None, verdict: "ExecutionVerdict | None" = None) -> dict:
        """Plain-data report (what ``regrasp check --json`` prints); ``hold``: `hold`'s result
        when already computed; ``verdict``: `execution_verdict`'s, reported as ``execution``."""
        fingers = {}
        for f in self.spec.fingers:
            pts = self.patches.get(f.name)
            fingers[f.name] = {
                "kind": f.kind,
                "touching_links": list(self.touching.get(f.name, ())),
                "contact_points": 0 if pts is None else int(len(pts[0])),
                "removable": f.name in self.removable,
                "q": [float(v) for v in self.finger_q[f.name]],
            }
        return {
            "grasp": self.spec.name,
            "file": self.spec.path,
            "hand": self.hand.name,
            "object": self.spec.object.to_data(),
            "friction": {"mu": self.friction.mu, "gamma": self.friction.gamma, "edges": self.friction.edges},
            "force_closure": self.is_force_closure,
            "metric": self.metric,
            "removable": sorted(self.removable),
            "mean_contact_closure": self.mean_contact_closure(),
            "link_contact_closure": self.mean_contact_closure("link"),
            "fingers": fingers,
            "palm": self.palm_summary(),
            "missing": list(self.missing),
            "collisions": [[a, b, float(d)] for a, b, d in self.collisions],
            "joints": {n: float(v) for n, v in zip(self.hand.joint_names, self.q)},
            "object_extents_m": [float(v) for v in self.obj.extents],
            "contacts": [c.to_data() for c in self.contacts],
            "hold": {h.name: {"holds": h.holds, "factor": h.capacity.factor, "words": h.words(),
                              "limit": None if h.capacity.limit is None else vars(h.capacity.limit)}
                     for h in (self.hold() if hold is None else hold)},
            "hold_note": self.hold_unavailable(),
            **({} if verdict is None else {"execution": verdict.to_data()}),
            "as_written": not self.problems,
            "problems": list(self.problems),
            "warnings": list(self.warnings),
            "tolerances": {"penetration_m": PENETRATION_TOL_M, "contact_warn_m": CONTACT_WARN_M,
                           "at_limit_rad": AT_LIMIT_RAD},
        }


@dataclass(frozen=True)
class ExecutionVerdict:
    """Whether ``plan --execution`` accepts a grasp as its initial or final grasp
    (`execution_verdict`), with the load table that explains it.

    Attributes:
        directions: the gravity directions execution mode plans for: ((name, (3,) palm frame), ...).
        contact_model: execution mode's (`planner.options.EXECUTION_CONTACT_MODEL`).
        hold_factor: the multiple of the weight every direction must hold.
        reason: the planner's own words for refusing the grasp (`planner.graph.Evaluator.blocked_reason`
            of the grasp as a plan state, or `RealizedGrasp.require_placed`'s), None when it accepts it.
        hold: `planner.grip.DirectionHold` per direction under ``contact_model`` (() when not
            force closure under it: `RealizedGrasp.hold`).
    """

    directions: tuple
    contact_model: str
    hold_factor: float
    reason: str | None
    hold: tuple = ()

    @property
    def ok(self) -> bool:
        return self.reason is None

    @property
    def failing(self) -> tuple:
        """The `DirectionHold`s below ``hold_factor``, in direction order."""
        return tuple(h for h in self.hold if h.capacity.factor < self.hold_factor)

    def brief(self) -> str:
        """The refusal in a few words: every failing direction with the joint that limits it
        (``palm_down 0.44x: thumb joint thumb_1``), else the planner's reason; "" when accepted."""
        if self.ok:
            return ""
        if not self.failing:
            return self.reason
        return f"below {self.hold_factor:g}x the weight in " + ", ".join(
            f"{h.name} ({h.capacity.factor:.3g}x" + ("" if h.capacity.limit is None else
                                                     f": {h.capacity.limit.finger} joint {h.capacity.limit.joint}"
                                                     if h.capacity.limit.joint else f": {h.capacity.limit.finger}'s force cap")
            + ")" for h in self.failing)

    def to_data(self) -> dict:
        """Plain data (``regrasp check --json``'s ``execution``): the verdict, the planner's
        reason, and per failing direction its factor and the joint that limits it."""
        return {"accepted": self.ok, "reason": self.reason, "contact_model": self.contact_model,
                "hold_factor": self.hold_factor, "directions": [n for n, _ in self.directions],
                "failing": [{"direction": h.name, "factor": h.capacity.factor,
                             "limit": None if h.capacity.limit is None else vars(h.capacity.limit)}
                            for h in self.failing]}


def execution_verdict(grasp: RealizedGrasp, gravity=None, name: str = "gravity") -> ExecutionVerdict:
    """Whether ``plan --execution`` (``gravity``: ``plan --execution --gravity``, a (3,)
    palm-frame vector) accepts ``grasp`` as an end grasp, by the planner's own test, not a
    copy of it: the fingers placed as the file says (`RealizedGrasp.require_placed`, what
    `planner.api.plan` asks first), then the grasp as a state of the plan's problem
    (`planner.slots.build_problem` with `PlanOptions.for_execution`) judged by the search's
    `planner.graph.Evaluator.blocked_reason`: fingers not colliding, force closure with the
    execution contact model, and ``hold_factor`` times the weight held in every planned
    direction within the joints' torque limits (`planner.graph.GaitProblem.load_refusal`)."""
    from planner.errors import PlannerError as _Refused  # the planner's one-line refusal
    from planner.graph import Evaluator  # deferred: networkx
    from planner.options import PlanOptions, gravity_directions_of
    from planner.slots import build_problem

    opts = PlanOptions.for_execution(gravity=None if gravity is None else tuple(float(v) for v in gravity),
                                     motion=False, verify=False)
    directions = tuple(gravity_directions_of(opts, grasp.hand))
    if gravity is not None:  # the planner names its one direction "gravity"; the report, as the user did
        directions = ((name, directions[0][1]),)
    hold = tuple(grasp.hold(opts.contact_model, list(directions)))
    try:
        grasp.require_placed()
    except _Refused as err:
        return ExecutionVerdict(directions, opts.contact_model, opts.hold_factor, str(err), hold)
    problem = build_problem(grasp, grasp, opts)
    ev = Evaluator(problem)
    ev.evaluate([problem.start])
    reason = ev.blocked_reason(problem.start)
    if reason is not None and gravity is not None and reason.startswith("gravity: "):
        reason = f"{name}: {reason[len('gravity: '):]}"
    return ExecutionVerdict(directions, opts.contact_model, opts.hold_factor, reason, hold)


def unheld_weight(grasp: RealizedGrasp, contact_model: str = "link") -> list:
    """The grasp's `planner.grip.DirectionHold`s, among the six hand orientations of
    execution mode, in which it does not hold its own weight (1x, with the whole friction
    cone, under ``contact_model``) within the joints' torque limits; [] when it holds it in
    all six."""
    if not grasp.patches:
        return []
    hold = grasp_hold(grasp.hand, grasp.q, apply_contact_model(grasp.patches, contact_model), grasp.obj.T_palm_obj,
                      grasp.obj.mass_kg, grasp.friction, gravity_directions(grasp.hand.palm_normal, 6), margin=1.0,
                      demand=False)
    return [h for h in hold if h.capacity.factor < 1.0]


def weight_warning(grasps: Mapping[str, RealizedGrasp], planned_with: str = "patch",
                   contact_model: str = "link") -> str | None:
    """One line for a plan made without a gravity (force closure only, under the contact
    model ``planned_with``) whose end grasps (``{"initial": grasp, "final": grasp}``) do not
    hold their own weight in some hand orientation (`unheld_weight`; by default with one
    contact per touching link, as the simulator's rigid links push): which grasp, which
    directions, the weakest with the joint that limits it; None when both hold it in all six.
    A grasp that is not force closure under ``planned_with`` is left to the planner's refusal."""
    parts = []
    for which, g in grasps.items():
        if not g.closure_under(planned_with).is_force_closure:
            continue
        low = unheld_weight(g, contact_model)
        if low:
            worst = min(low, key=lambda h: h.capacity.factor)
            parts.append(f"the {which} grasp {g.spec.name!r} does not hold its own weight ({g.obj.mass_kg * 1e3:.4g} g) "
                         f"within the joints' torque limits in {', '.join(h.name for h in low)} (worst {worst.name}: "
                         f"{worst.capacity.words()}; {CONTACT_MODEL_WORDS[contact_model]}, all the friction)")
    if not parts:
        return None
    return ("; ".join(parts) + "; this plan asks force closure only: plan --execution (or --gravity NAME) requires "
            "the weight held, regrasp check --execution says whether a grasp can be executed")


def _is_object_name(name: str) -> bool:
    return str(name).lower() in ("object", "obj")


# --------------------------------------------------------------------------- realization


def _finger_of(hand, finger):
    """A `Finger` from a name or a Finger (UnknownNameError with the valid names)."""
    if isinstance(finger, str):
        if finger not in hand.fingers:
            raise UnknownNameError("finger", finger, list(hand.fingers))
        return hand.fingers[finger]
    return finger


def _approach_along_normal(hand, obj, f, p_palm, n_out_palm, q, link, iters: int = 12):
    """Slide the IK target along the surface normal until the finger just touches.

    Used when closing the finger (which curls it) does not land it on the requested point,
    e.g. a lateral contact with the side of a phalanx: the finger is moved straight toward
    the surface instead, keeping the pad facing it.
    """
    offset = APPROACH_M
    best = None
    for _ in range(iters):
        try:
            q = hand.ik(f, p_palm + offset * n_out_palm, q, link=link, normal_palm=-n_out_palm)
        except KinematicsError:
            break
        d = hand.state(q).finger_object_distance(obj, f.name)
        if 0.0 <= d <= 0.5 * TOUCH_TOL_M:
            return q
        if d >= 0.0:
            best = q
        # the finger surface moves with the target: step by the measured gap (or depth)
        offset -= d - 0.25 * TOUCH_TOL_M
    return best


def realize_contact(hand, obj, finger, p_obj, q_seed, link=None):
    """Place one finger on an object-frame point, touching without penetration.

    The point is projected onto the surface. IK puts the contact link's pad (default:
    the fingertip pad) `APPROACH_M` outside it with the pad facing into the object
    (inward normal), then the closing procedure (thesis eqs. (8)-(9)) flexes the finger
    until it touches. When the closed finger does not touch within `LANDING_TOL_M` of the
    point (closing curls the finger, which suits pads but not e.g. the side of a phalanx),
    the finger is instead moved straight along the surface normal until it touches.
    Only that finger's joints change.

    Args:
        hand: `planner.hand.Hand`.
        obj: `planner.objects.GraspObject`.
        finger: finger name (or `Finger`).
        p_obj: (3,) target point, object frame, metres.
        q_seed: (nq,) configuration the other fingers keep and IK starts from.
        link: contact link of the finger; None means the fingertip pad.

    Returns:
        (q (nq,), patch) where patch is (p_obj (n, 3), n_in_obj (n, 3)) of that finger's
        measured contact, or None when the finger does not touch the object.

    Raises:
        KinematicsError: the point is out of the finger's reach.
    """
    q, patch, _ = place_contact(hand, obj, finger, p_obj, q_seed, link=link)
    return q, patch


def place_contact(hand, obj, finger, p_obj, q_seed, link=None):
    """`realize_contact` with its notes: ``(q, patch, notes)``.

    ``notes`` are one-line strings about how the placement went: the pad-normal task
    dropped (position-only IK), the pad facing far from the contact normal. An
    unreachable point raises `planner.ik.UnreachableError` whose message gives, in the
    object frame, the closest point the finger reached, the nearest surface point to it and
    the direction to move the target.
    """
    f = _finger_of(hand, finger)
    p_surf, n_out, _ = obj.closest_surface(np.asarray(p_obj, dtype=float).reshape(3))
    T = np.asarray(obj.T_palm_obj)
    R = T[:3, :3]
    n_out_palm = R @ np.asarray(n_out, dtype=float)
    p_palm = R @ np.asarray(p_surf, dtype=float) + T[:3, 3]
    q_seed = np.asarray(q_seed, dtype=float)
    ik, err = None, None
    # a pad that cannot stand off by APPROACH_M (e.g. under a face it only reaches when
    # almost extended) is tried closer to the surface
    for offset in (APPROACH_M, 0.5 * APPROACH_M, 0.25 * APPROACH_M):
        try:
            ik = hand.ik_solve(f, p_palm + offset * n_out_palm, q_seed, link=link, normal_palm=-n_out_palm)
            break
        except UnreachableError as e:
            err = err or e
    if ik is None:
        raise _unreachable_in_object_frame(err, obj, p_surf, _reachable_point(hand, obj, f, err, q_seed, link))
    notes = []
    if ik.normal_dropped:
        notes.append(f"{f.name}: the pad cannot face the contact normal there; placed position-only "
                     f"(pad normal {math.degrees(ik.normal_error_rad):.0f} deg from the contact normal)")
    elif ik.normal_error_rad is not None and ik.normal_error_rad > NORMAL_WARN_RAD:
        notes.append(f"{f.name}: the pad faces {math.degrees(ik.normal_error_rad):.0f} deg away from the contact normal")
    q_ik = ik.q
    q = np.asarray(hand.close_finger(f, q_ik, obj), dtype=float)
    patch = contact_patches(hand, q, obj, fingers=[f.name]).get(f.name)
    if patch is not None and _landing_error(patch, p_surf) <= LANDING_TOL_M:
        return q, patch, notes
    q_n = _approach_along_normal(hand, obj, f, p_palm, n_out_palm, q_ik, link)
    if q_n is not None:
        patch_n = contact_patches(hand, q_n, obj, fingers=[f.name]).get(f.name)
        if patch_n is not None and (patch is None or _landing_error(patch_n, p_surf) < _landing_error(patch, p_surf)):
            return np.asarray(q_n, dtype=float), patch_n, notes
    return q, patch, notes


#: Surface points `_reachable_point` tries, following the IK's closest reach each time.
REACH_HINT_STEPS = 8


def _reachable_point(hand, obj, f, err, q_seed, link):
    """A surface point the finger's pad does reach (the IK succeeds there, as `place_contact`
    places it): from where the failed IK got, projected onto the surface, again from where
    that one got, at most `REACH_HINT_STEPS` times. None when none of them is reachable."""
    T = np.asarray(obj.T_palm_obj)
    R, t = T[:3, :3], T[:3, 3]
    closest = R.T @ (err.closest_palm - t)
    tried = []
    for _ in range(REACH_HINT_STEPS):
        s, n_out, _ = obj.closest_surface(closest)
        if any(np.linalg.norm(s - o) < 1e-4 for o in tried):
            return None
        tried.append(np.asarray(s, float))
        n_palm = R @ np.asarray(n_out, float)
        p_palm = R @ np.asarray(s, float) + t
        for offset in (APPROACH_M, 0.5 * APPROACH_M, 0.25 * APPROACH_M):
            try:
                hand.ik_solve(f, p_palm + offset * n_palm, q_seed, link=link, normal_palm=-n_palm)
                return np.asarray(s, float)
            except UnreachableError as e:
                last = e
        closest = R.T @ (last.closest_palm - t)
    return None


def _unreachable_in_object_frame(err, obj, p_surf, reachable=None):
    """The IK's `UnreachableError` re-worded in the object frame, with a surface point the
    finger does reach (`_reachable_point`), or the advice to move the object."""
    T = np.asarray(obj.T_palm_obj)
    R, t = T[:3, :3], T[:3, 3]
    closest = R.T @ (err.closest_palm - t)
    direction = R.T @ err.direction_palm
    f3 = lambda v: "[" + ", ".join(f"{x:.4f}" for x in v) + "]"  # noqa: E731
    if reachable is not None:
        move = float(np.linalg.norm(reachable - np.asarray(p_surf)))
        tail = (f"a surface point it does reach (checked): {f3(reachable)} (object frame), {move * 1e3:.1f} mm from "
                "the requested one")
    else:
        tail = ("no surface point near where it gets is in reach: move the object toward the finger (object."
                f"position, palm frame: along {f3(R @ direction)}) or use another finger")
    msg = (f"{str(err).split(';')[0]}; the finger gets within {err.distance_m * 1e3:.1f} mm, at {f3(closest)} "
           f"(object frame): move the point along {f3(direction)} (object frame); {tail}")
    return UnreachableError(msg, target_palm=err.target_palm, closest_palm=err.closest_palm,
                            direction_palm=err.direction_palm, distance_m=err.distance_m)


def _landing_error(patch, p_obj) -> float:
    """Distance (m) from a requested contact point to the nearest point of a patch."""
    return float(np.min(np.linalg.norm(np.asarray(patch[0]) - np.asarray(p_obj), axis=1)))


def realized_grasp(g) -> tuple["RealizedGrasp", dict | None]:
    """A grasp given as a file (path), a `GraspSpec` or a `RealizedGrasp`, realized with its
    fingers placed (`RealizedGrasp.require_placed`), and the plan's record of its file
    (`input_record`; None when it was not given as a file)."""
    if isinstance(g, RealizedGrasp):
        return g, None
    if isinstance(g, GraspSpec):
        return realize(g).require_placed(), None
    return realize(load_grasp(g)).require_placed(), input_record(g)


def realize(spec: GraspSpec, hand=None) -> RealizedGrasp:
    """Turn a grasp spec into a hand configuration and measure its contacts and closure.

    Contact fingers: `realize_contact`. Posture fingers: the closing procedure from the
    posture. Free fingers: the open posture. Then contact patches (several points per
    touching link), force closure and metric (thesis eqs. (1)-(7)), removable fingers
    (Algorithm 1) and self-collisions of the hand.

    Args:
        spec: a validated `GraspSpec`.
        hand: the `Hand`; None loads ``spec.hand_ref``.

    Returns:
        The `RealizedGrasp`.

    Raises:
        KinematicsError: a contact point is out of its finger's reach (the message names
            the file and the key).
    """
    hand = load_hand(spec.hand_ref) if hand is None else hand
    obj = spec.object
    q = np.array(hand.q_open, dtype=float, copy=True)
    notes = []
    unreachable = []  # every finger out of reach is named, not only the first
    for fs in spec.fingers:
        f = hand.fingers[fs.name]
        idx = list(f.q_index)
        if fs.kind == "contact":
            try:
                q, _, n = place_contact(hand, obj, f, fs.point_obj, q, link=fs.link)
            except UnreachableError as err:
                unreachable.append((fs.name, err))
                continue
            except KinematicsError as err:
                raise KinematicsError(f"{spec.path}: fingers.{fs.name}.contact.point: {err}") from err
            notes.extend(f"fingers.{fs.name}.contact: {m.split(': ', 1)[1]}" for m in n)
        elif fs.kind == "posture":
            q[idx] = fs.posture
            q = np.asarray(hand.close_finger(f, q, obj), dtype=float)
        else:
            q[idx] = np.asarray(hand.q_open)[idx]
    if unreachable:
        name, err = unreachable[0]
        others = "".join(f" | fingers.{n}.contact.point: {e}" for n, e in unreachable[1:])
        raise UnreachableError(f"{spec.path}: fingers.{name}.contact.point: {err}{others}", target_palm=err.target_palm,
                               closest_palm=err.closest_palm, direction_palm=err.direction_palm,
                               distance_m=err.distance_m)
    # one state, queried once: link-object distances are computed once for all four queries
    state = hand.state(q)
    q = state.q
    patches = contact_patches(hand, state, obj, palm=True)
    palm_touches = PALM in patches
    if spec.palm == "free":  # the file keeps the palm out of the grasp (a problem if it touches)
        patches.pop(PALM, None)
    patches = {k: Patch(_ro(v.points), _ro(v.normals), v.links) for k, v in patches.items()}
    closure = grasp_closure(patches, spec.friction)
    removable = frozenset(removable_fingers(patches, spec.friction)) if patches else frozenset()
    touching = {k: tuple(v) for k, v in touching_links(hand, state, obj).items()}
    if PALM in patches:
        touching[PALM] = tuple(dict.fromkeys(patches[PALM].links))
    finger_q = {}
    for name, f in hand.fingers.items():
        finger_q[name] = _ro(q[list(f.q_index)])
    missing = tuple(fs.name for fs in spec.fingers if fs.kind != "free" and fs.name not in patches)
    colls = tuple((str(a), str(b), float(d)) for a, b, d in collisions(hand, state, obj, touch_tol_m=PENETRATION_TOL_M))
    contacts = tuple(link_contacts(hand, state, obj, palm=True))
    problems, warnings = grasp_findings(spec, hand, obj, state, contacts, missing, colls)
    if spec.palm == "hold" and not palm_touches:
        gap = state.palm_object_distance(obj)
        if gap is None:
            problems.append(f"palm: hold, but hand {hand.name} has no palm collision geometry (no link of its base "
                            f"has a <collision>): the palm cannot hold")
        else:
            problems.append(f"palm: hold, but the palm does not touch the object (misses it by {gap * 1e3:.1f} mm; "
                            f"touching is within {TOUCH_TOL_M * 1e3:g} mm)")
    elif spec.palm == "free" and palm_touches:
        problems.append(f"palm: free, but the palm touches the object (within {TOUCH_TOL_M * 1e3:g} mm): it would "
                        f"carry part of the load; move the object away from it or say palm: auto or hold")
    return RealizedGrasp(
        spec=spec,
        hand=hand,
        obj=obj,
        friction=spec.friction,
        q=q,
        finger_q=MappingProxyType(finger_q),
        patches=MappingProxyType(patches),
        touching=MappingProxyType(touching),
        closure=closure,
        removable=removable,
        collisions=colls,
        missing=missing,
        contacts=contacts,
        problems=tuple(problems),
        warnings=tuple(notes + warnings),
    )


def grasp_findings(spec: GraspSpec, hand, obj, state, contacts, missing, colls) -> tuple[list[str], list[str]]:
    """What makes a realized grasp differ from its file: (problems, warnings), one line each.

    ``state`` is the realized hand (`planner.collision.HandState`, ``hand.state(q)``).

    Problems (``check`` exits 1): a placed finger that does not touch; a link deeper than
    `PENETRATION_TOL_M` in the object, the palm or another finger; a closing joint of a
    placed finger at its closing (upper) limit that a posture did not ask for (the finger
    closed to the end of its range without being stopped by the object: curled past it or
    into the palm, and it cannot press harder). Warnings: a contact point realized more than
    `CONTACT_WARN_M` from where the file put it, or by another link than the one asked for
    (default the pad); other joints of placed fingers at a limit nobody asked for.
    """
    problems, warnings = [], []
    q = state.q
    for name in missing:
        gap = state.finger_object_distance(obj, name)
        problems.append(f"fingers.{name}: placed by the file but does not touch the object (misses it by {gap * 1e3:.1f} mm)")
    for a, b, depth in colls:
        if depth > PENETRATION_TOL_M:
            problems.append(f"collision {a} - {b}: {depth * 1e3:.2f} mm deep (tolerance {PENETRATION_TOL_M * 1e3:.1f} mm)")
    for fs in spec.fingers:
        if fs.kind == "free":
            continue
        f = hand.fingers[fs.name]
        for k, (joint, i) in enumerate(zip(f.joints, f.q_index)):
            for side, limit in (("lower", hand.lower[i]), ("upper", hand.upper[i])):
                if abs(q[i] - limit) > AT_LIMIT_RAD:
                    continue
                if fs.kind == "posture" and abs(fs.posture[k] - limit) <= AT_LIMIT_RAD:
                    continue  # asked for by the file
                text = f"fingers.{fs.name}: joint {joint} = {q[i]:.4f} rad is at its {side} limit"
                if side == "upper" and joint in f.close_joints:
                    problems.append(text + " (closed to the end of its range: the object does not stop it)")
                else:
                    warnings.append(text)
        if fs.kind == "contact":
            mine = [c for c in contacts if c.finger == fs.name]
            if not mine:
                continue
            want = fs.link or f.pad_link
            d = [float(np.linalg.norm(c.point - np.asarray(fs.point_obj))) for c in mine]
            c = mine[int(np.argmin(d))]
            where = "[" + ", ".join(f"{v:.4f}" for v in c.point) + "]"
            if min(d) > CONTACT_WARN_M:
                warnings.append(f"fingers.{fs.name}.contact: realized {min(d) * 1e3:.1f} mm from the file's point, "
                                f"at {where} (object frame) by {c.link} (warning beyond {CONTACT_WARN_M * 1e3:.0f} mm)")
            elif c.link != want and want in f.contact_links:
                warnings.append(f"fingers.{fs.name}.contact: realized by {c.link}, not {want}, at {where} (object frame)")
    return problems, warnings


def _ro(a) -> np.ndarray:
    a = np.array(a, dtype=float, copy=True)
    a.setflags(write=False)
    return a
