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
from planner.ik import UnreachableError, ik_solve
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


class _Removable:
    """`planner.closure.removable_fingers` of the patches a grasp was measured with, computed
    once, when first asked."""

    __slots__ = ("patches", "friction", "_value")

    def __init__(self, patches, friction):
        self.patches, self.friction, self._value = patches, friction, None

    def value(self) -> frozenset:
        if self._value is None:
            self._value = frozenset(removable_fingers(self.patches, self.friction)) if self.patches else frozenset()
        return self._value


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
    collisions: tuple = field(default=())
    missing: tuple[str, ...] = field(default=())
    contacts: tuple = field(default=())
    problems: tuple[str, ...] = field(default=())
    warnings: tuple[str, ...] = field(default=())
    # `removable`, computed on first use from the patches measured (a copy made with
    # dataclasses.replace shares it, as it shared the value): synthesis never asks it of the
    # candidates it drops (3-4 % of its time, a hull per finger)
    _removable: "_Removable" = field(default=None, repr=False)

    @property
    def removable(self) -> frozenset:
        """Fingers whose contacts can all be dropped keeping force closure (Algorithm 1)."""
        return self._removable.value() if self._removable is not None else frozenset()

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
    opts, directions = _execution_options(grasp, gravity, name)
    hold = tuple(grasp.hold(opts.contact_model, list(directions)))
    return ExecutionVerdict(directions, opts.contact_model, opts.hold_factor,
                            execution_refusal(grasp, gravity, name, _opts=opts), hold)


def _execution_options(grasp: RealizedGrasp, gravity, name: str):
    """Execution mode's options for `execution_verdict` and the directions it reports."""
    from planner.options import PlanOptions, gravity_directions_of

    opts = PlanOptions.for_execution(gravity=None if gravity is None else tuple(float(v) for v in gravity),
                                     motion=False, verify=False)
    directions = tuple(gravity_directions_of(opts, grasp.hand))
    if gravity is not None:  # the planner names its one direction "gravity"; the report, as the user did
        directions = ((name, directions[0][1]),)
    return opts, directions


def execution_refusal(grasp: RealizedGrasp, gravity=None, name: str = "gravity", *, _opts=None) -> str | None:
    """`execution_verdict`'s ``reason`` alone (None: ``plan --execution`` accepts the grasp),
    without its load table (`RealizedGrasp.hold`, which explains a refusal but does not
    decide it): what synthesis ranks its grasps by, computed by the same code."""
    from planner.errors import PlannerError as _Refused  # the planner's one-line refusal
    from planner.graph import Evaluator  # deferred: networkx
    from planner.slots import build_problem

    opts = _execution_options(grasp, gravity, name)[0] if _opts is None else _opts
    try:
        grasp.require_placed()
    except _Refused as err:
        return str(err)
    problem = build_problem(grasp, grasp, opts)
    ev = Evaluator(problem)
    ev.evaluate([problem.start])
    reason = ev.blocked_reason(problem.start)
    if reason is not None and gravity is not None and reason.startswith("gravity: "):
        reason = f"{name}: {reason[len('gravity: '):]}"
    return reason


def wedged_fingers(grasp: RealizedGrasp) -> dict[str, str]:
    """Touching fingers that cannot back off their contact whatever the other fingers do
    (`planner.retreat.retreat_blocked`: the planner's own lift, every other finger open):
    finger -> why. A plan can neither lift such a finger from this grasp nor land it here,
    so a regrasp that must move it is refused at once (``finger ... must leave its initial
    contact, and no finger path can``); the grasp itself may still hold."""
    from planner.retreat import retreat_blocked  # deferred: the lift's finger scene

    out = {}
    for name in grasp.hand.fingers:
        if name in grasp.patches:
            why = retreat_blocked(grasp.hand, grasp.obj, grasp.finger_q[name], name)
            if why is not None:
                out[name] = why
    return out


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


def place_contact(hand, obj, finger, p_obj, q_seed, link=None, suggest: bool = True):
    """`realize_contact` with its notes: ``(q, patch, notes)``.

    The point is projected onto the surface (outward normal n). For each pad core of the
    link (`_pad_cores`: the centre of curvature of its pad, a sphere's centre or an end of a
    capsule's axis, with the pad normal leaned so that end is the lowest), IK over position
    AND orientation puts the core `APPROACH_M` off the surface at point + (radius + APPROACH_M)
    n with the pad facing -n, then closes along the normal until the link touches
    (`_touch_along_normal`). The result is measured (`_verify`): the asked link touches
    within `CONTACT_TOL_M` of the point, its pad within `PAD_FACING_RAD` of the contact
    normal, nothing of the finger deeper than `PENETRATION_TOL_M` in the object, the palm or
    another finger. The first core that passes is the placement, unless the closing
    procedure's placement (`_place_by_closing`: IK of the pad, then closing) lands within
    `CONTACT_WARN_M` with more of the finger's links touching.

    When none passes, the finger is placed as before (`_place_by_closing`) and ``notes``
    says which constraint failed (reach, orientation, collision with which link, landing)
    and a surface point this same function does realize (`_realized_point_near`, checked
    through this function), or that none nearby is. ``notes`` also says when the pad faces
    more than 45 deg away. Placements are cached (same hand, object, point, seed, link).

    Raises:
        planner.ik.UnreachableError: no placement reaches the point; its message gives, in
            the object frame, the closest point the finger reached, the direction to move the
            target and a surface point it does realize (checked) or the advice to move the object.
    """
    f = _finger_of(hand, finger)
    key = _cache_key(hand, obj, f, p_obj, q_seed, link, suggest)
    hit = _PLACEMENTS.get(key) if key is not None else None
    if hit is None:
        hit = _place_contact(hand, obj, f, p_obj, q_seed, link, suggest)
        if key is not None:
            if len(_PLACEMENTS) >= 512:
                _PLACEMENTS.pop(next(iter(_PLACEMENTS)))
            _PLACEMENTS[key] = hit
    if isinstance(hit, Exception):
        raise hit
    q, patch, notes = hit
    return np.array(q, dtype=float), patch, list(notes)


#: Placements already made: (hand, object, finger, point, seed, link) -> (q, patch, notes) or the error.
_PLACEMENTS: dict = {}


def _cache_key(hand, obj, f, p_obj, q_seed, link, suggest):
    try:
        return (str(getattr(hand, "spec_path", id(hand))), id(hand), hash(obj), repr(obj.to_data()), f.name,
                tuple(np.round(np.asarray(p_obj, float).reshape(3), 12)), np.asarray(q_seed, float).tobytes(),
                link, suggest)
    except (TypeError, AttributeError, ValueError):
        return None


def _surface(obj, p_obj):
    """(point, outward normal) on the surface nearest p_obj, object and palm frames."""
    p_surf, n_out, _ = obj.closest_surface(np.asarray(p_obj, dtype=float).reshape(3))
    T = np.asarray(obj.T_palm_obj)
    R = T[:3, :3]
    return np.asarray(p_surf, float), np.asarray(n_out, float), R @ np.asarray(p_surf, float) + T[:3, 3], \
        R @ np.asarray(n_out, dtype=float)


def _place_contact(hand, obj, f, p_obj, q_seed, link, suggest):
    q_seed = np.asarray(q_seed, dtype=float)
    p_surf, n_out, p_palm, n_out_palm = _surface(obj, p_obj)
    placed = _place_verified(hand, obj, f, p_surf, q_seed, link)
    want = link or f.pad_link
    try:
        q, patch, notes = _place_by_closing(hand, obj, f, p_surf, n_out_palm, p_palm, q_seed, link)
    except UnreachableError as err:
        if placed.why is None:
            return placed.q, placed.patch, placed.notes
        hint = _realized_point_near(hand, obj, f, p_surf, n_out, q_seed, link, err) if suggest else None
        return _unreachable_in_object_frame(err, obj, p_surf, hint, placed.why)
    if placed.why is None:
        # the closing procedure's placement when it lands within `CONTACT_WARN_M` (where `check`
        # takes the point as written) with more of the finger on the object (e.g. a thumb lying
        # on a face with two phalanges): stiffer, and the files written for it hold as they did
        links = lambda qq: len(touching_links(hand, qq, obj, fingers=[f.name]).get(f.name, ()))  # noqa: E731
        if (_verify(hand, obj, f, want, q, p_surf, n_out_palm, CONTACT_WARN_M).why is None
                and links(q) > links(placed.q)):
            return q, patch, [n for n in notes if "position-only" not in n]
        return placed.q, placed.patch, placed.notes
    check = _verify(hand, obj, f, want, q, p_surf, n_out_palm)
    if check.why is None:
        return q, patch, notes
    why = placed.why or check.why
    if why.startswith("out of reach"):  # the pad reaches the point, but not facing the surface
        why = f"orientation: {want} reaches the point only with its pad facing away ({why})"
    if suggest:
        hint = _realized_point_near(hand, obj, f, p_surf, n_out, q_seed, link, None)
        tail = ("no surface point within 20 mm is realized either: move the object or use another finger" if hint is None
                else f"a surface point it does reach (checked): {_f3(hint)} (object frame), realized there as asked, "
                     f"{np.linalg.norm(hint - p_surf) * 1e3:.1f} mm from the requested one")
    else:
        tail = ""
    notes = [n for n in notes if "position-only" not in n]
    notes.append(f"{f.name}: not realized as asked ({want} within {CONTACT_TOL_M * 1e3:g} mm, its pad within "
                 f"{math.degrees(PAD_FACING_RAD):.0f} deg of the contact normal): {why}" + (f"; {tail}" if tail else ""))
    return q, patch, notes


def _f3(v) -> str:
    return "[" + ", ".join(f"{x:.4f}" for x in v) + "]"


#: A contact point is realized when the asked link touches within this of it: twice the
#: touch tolerance (a link counts as touching up to `TOUCH_TOL_M` away, so its witness point
#: may sit that far along a curved surface from where the pad was aimed).
CONTACT_TOL_M = 2.0 * TOUCH_TOL_M
#: The pad faces the surface when its normal is within this of the contact normal.
PAD_FACING_RAD = math.radians(45.0)


#: IK from the seed, then from this many - 1 seeded random postures of the finger, when the
#: placement collides or faces away.
PLACE_ATTEMPTS = 3


@dataclass(frozen=True)
class _Placement:
    """One placement attempt: q (None: out of reach), patch, notes, why it is not as asked
    (None: it is), the reach error when out of reach."""

    q: Any
    patch: Any = None
    notes: tuple = ()
    why: str | None = None
    err: Any = None


def _place_verified(hand, obj, f, p_surf, q_seed, link, attempts: int = 0, cores: int = 0) -> _Placement:
    """IK of each pad core over position and orientation, closing along the normal, measured
    (`_verify`): the first placement that passes, else the most telling failure (a collision
    or an orientation before a landing error before out of reach)."""
    _, _, p_palm, n_out_palm = _surface(obj, p_surf)
    want = link or f.pad_link
    fails = []
    idx = list(f.q_index)
    for attempt in range(attempts or PLACE_ATTEMPTS):
        seed = np.array(q_seed, dtype=float)
        if attempt:  # IK from other postures of the finger: another branch may not collide
            seed[idx] = np.random.default_rng(attempt).uniform(hand.lower[idx], hand.upper[idx])
        for core in _pad_cores(hand, f, want)[:cores or None]:
            try:
                q = _touch_along_normal(hand, obj, f, want, core, p_palm, n_out_palm, seed)
            except UnreachableError as err:
                fails.append((3, _Placement(None, why=f"out of reach of {want} with its pad facing the surface "
                                                      f"(closest approach {err.distance_m * 1e3:.1f} mm)", err=err)))
                continue
            check = _verify(hand, obj, f, want, q, p_surf, n_out_palm)
            patch = contact_patches(hand, q, obj, fingers=[f.name]).get(f.name)
            if check.why is None:
                return _Placement(q, patch, ())
            fails.append((check.rank, _Placement(q, patch, (), check.why)))
        if all(r == 3 for r, _ in fails):
            break  # out of reach from the seed's IK starts (8 of them): other seeds do not help
    if not fails:
        return _Placement(None, why=f"{want} has no pad to place")
    return min(fails, key=lambda t: t[0])[1]


@dataclass(frozen=True)
class _Check:
    why: str | None
    rank: int = 0
    landing_m: float = math.inf
    normal_rad: float = math.inf


def _verify(hand, obj, f, link, q, p_surf, n_out_palm, tol_m: float = 0.0) -> _Check:
    """Whether a placement realizes the point as asked: no link of the finger deeper than
    `PENETRATION_TOL_M` in the object, the palm or another finger (rank 0), the pad facing
    the contact normal within `PAD_FACING_RAD` (rank 1), ``link`` touching within
    ``tol_m`` (default `CONTACT_TOL_M`) of the point (rank 2)."""
    tol_m = tol_m or CONTACT_TOL_M
    state = hand.state(q)
    deep = [(a, b, d) for a, b, d in collisions(hand, state, obj, fingers=[f.name], touch_tol_m=PENETRATION_TOL_M)
            if d > PENETRATION_TOL_M]
    mine = [c for c in link_contacts(hand, state, obj, fingers=[f.name]) if c.link == link]
    land = min((float(np.linalg.norm(c.point - p_surf)) for c in mine), default=math.inf)
    n_pad = _pad_normal_palm(hand, f, link, state)
    nerr = math.inf if n_pad is None else math.acos(float(np.clip(n_pad @ -n_out_palm, -1.0, 1.0)))
    if deep:
        a, b, d = max(deep, key=lambda c: c[2])
        other = b if a in f.links else a
        mine_l = a if a in f.links else b
        return _Check(f"collision: {mine_l} is {d * 1e3:.1f} mm inside {'the object' if _is_object_name(other) else other}",
                      0, land, nerr)
    if n_pad is not None and nerr > PAD_FACING_RAD:
        return _Check(f"orientation: the pad of {link} faces {math.degrees(nerr):.0f} deg from the contact normal "
                      f"(at most {math.degrees(PAD_FACING_RAD):.0f})", 1, land, nerr)
    if not mine:
        gap = state.link_object(obj, [link]).get(link)
        return _Check(f"landing: {link} does not touch the object" + ("" if gap is None else
                      f" (misses it by {gap.distance_m * 1e3:.1f} mm)"), 2, land, nerr)
    if land > tol_m:
        return _Check(f"landing: {link} touches {land * 1e3:.1f} mm from the point", 2, land, nerr)
    return _Check(None, 0, land, nerr)


def _link_frame(hand, link):
    """(frame id, pinocchio Frame) of a link."""
    fid = hand.model.getFrameId(link)
    return fid, hand.model.frames[fid]


def _pad_normal_link(hand, f, link):
    """The outward pad normal of ``link`` in its own frame: the finger's pad normal, carried
    to another link of the finger by their relative rotation at the open posture."""
    if f.pad_n_link is None:
        return None
    n = np.asarray(f.pad_n_link, dtype=float)
    if link == f.pad_link:
        return n
    kin = hand.kinematics(hand.q_open)
    km = hand.collision.kinematic_model
    R_pad = kin.frame_pose(km.frame_id(f.pad_link))[:3, :3]
    R_link = kin.frame_pose(km.frame_id(link))[:3, :3]
    return R_link.T @ R_pad @ n


def _pad_normal_palm(hand, f, link, state):
    n = _pad_normal_link(hand, f, link)
    if n is None:
        return None
    km = hand.collision.kinematic_model
    return state.kinematics.frame_pose(km.frame_id(link))[:3, :3] @ n if hasattr(state, "kinematics") else \
        hand.kinematics(state.q).frame_pose(km.frame_id(link))[:3, :3] @ n


def _pad_cores(hand, f, link):
    """Where IK puts ``link``: [(core point (3,) link frame, radius m, direction (3,) link
    frame turned to face the surface)].

    A pad's core is its centre of curvature: a sphere's centre, a point of a capsule's axis.
    The core placed at point + radius * n (outward normal) makes the link touch the tangent
    plane exactly at the point, whatever the orientation (a sphere) or for every orientation
    that keeps that end of the capsule the lowest: the capsule's pad normal is leaned along
    its axis by asin(2 `TOUCH_TOL_M` / axis length), so that the other end stands clear of the
    touch tolerance and the contact is a point, not a line. A flat link (box, mesh) has its
    pad point (or the support point of its shape toward the pad normal) with radius 0."""
    n_p = _pad_normal_link(hand, f, link)
    fid, frame = _link_frame(hand, link)
    T_jl = frame.placement
    geoms = [g for g in hand.collision.geometries if g.link == link]
    pad = np.asarray(f.pad_p_link, float) if link == f.pad_link else None
    if not geoms or n_p is None:
        return [(np.zeros(3) if pad is None else pad, 0.0, n_p)]
    to_link = lambda g, x: np.asarray(T_jl.actInv(g.placement.act(np.asarray(x, float))), float)  # noqa: E731

    def score(g):  # the geometry holding the pad point, or the one farthest along the pad normal
        c = to_link(g, np.zeros(3))
        return np.linalg.norm(c - pad) if pad is not None else -(c @ n_p)
    g = min(geoms, key=score)
    shape = g.shape
    name = type(shape).__name__
    if name == "Sphere":
        r = float(shape.radius)
        return [(to_link(g, np.zeros(3)), r, n_p)]
    if name == "Capsule":
        r, h = float(shape.radius), float(shape.halfLength)
        e = [to_link(g, [0.0, 0.0, s * h]) for s in (-1.0, 1.0)]
        length = float(np.linalg.norm(e[1] - e[0]))
        ref = pad - r * n_p if pad is not None else 0.5 * (e[0] + e[1])
        order = sorted(range(2), key=lambda i: np.linalg.norm(e[i] - ref))
        out = []
        lean = math.asin(min(1.0, 2.0 * TOUCH_TOL_M / max(length, 1e-9))) if length > 1e-6 else 0.0
        for i in order:
            u = (e[1 - i] - e[i]) / length if length > 1e-6 else np.zeros(3)
            u = u - (u @ n_p) * n_p
            v = math.cos(lean) * n_p - math.sin(lean) * u
            out.append((e[i], r, v / np.linalg.norm(v)))
        out.append((0.5 * (e[0] + e[1]), r, n_p))
        return out
    if pad is not None:
        return [(pad, 0.0, n_p)]
    return [(to_link(g, np.zeros(3)), 0.0, n_p)]


def _touch_along_normal(hand, obj, f, link, core, p_palm, n_out_palm, q_seed, iters: int = 6):
    """IK of the core `APPROACH_M` off the surface, pad facing it (position and
    orientation), then along the normal until ``link`` touches (0 to 0.5 `TOUCH_TOL_M` away,
    measured). Raises `UnreachableError` when no stand-off is reached."""
    c_link, r, v_link = core
    n_in = -n_out_palm
    res, err = None, None
    for offset in (APPROACH_M, 0.25 * TOUCH_TOL_M):
        try:
            res = ik_solve(hand, f, p_palm + (r + offset) * n_out_palm, q_seed, link=link, p_link=c_link,
                           normal_palm=n_in, n_link=v_link)
            break
        except UnreachableError as e:
            err = err or e
    if res is None:
        raise err
    q = res.q
    s = 0.25 * TOUCH_TOL_M
    best = None
    for _ in range(iters):
        try:
            q = ik_solve(hand, f, p_palm + (r + s) * n_out_palm, q, link=link, p_link=c_link, normal_palm=n_in,
                         n_link=v_link, restarts=3).q
        except UnreachableError:
            break
        d = hand.state(q).link_object(obj, [link])[link].distance_m
        if 0.0 <= d <= 0.5 * TOUCH_TOL_M:
            return q
        if d >= 0.0 or best is None:
            best = q
        s -= d - 0.25 * TOUCH_TOL_M
    if best is None:
        raise err or UnreachableError(f"finger {f.name!r}: {link} cannot be placed on the point", target_palm=p_palm,
                                      closest_palm=p_palm, direction_palm=np.zeros(3), distance_m=0.0)
    return best


def _place_by_closing(hand, obj, f, p_surf, n_out_palm, p_palm, q_seed, link):
    """The placement before the pad cores: IK of the pad point `APPROACH_M` off the surface
    (position-only when the normal task keeps it off), then the closing procedure, or the
    approach along the normal when that lands farther than `LANDING_TOL_M`."""
    ik, err = None, None
    for offset in (APPROACH_M, 0.5 * APPROACH_M, 0.25 * APPROACH_M):
        try:
            ik = hand.ik_solve(f, p_palm + offset * n_out_palm, q_seed, link=link, normal_palm=-n_out_palm)
            break
        except UnreachableError as e:
            err = err or e
    if ik is None:
        raise err
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


#: Surface points `_realized_point_near` tries at most.
REACH_HINT_TRIES = 33
#: Distances (m) from the requested point at which `_realized_point_near` tries surface points.
HINT_RADII_M = (0.003, 0.006, 0.012, 0.02)


def _realized_point_near(hand, obj, f, p_surf, n_out, q_seed, link, err=None):
    """A surface point near ``p_surf`` that `_place_verified` realizes as asked (so that
    `place_contact` does too: it tries the same placement first, from the same seed), or
    None. Tried in order: where the failed IK got (projected onto the surface, when out of
    reach), then rings of surface points at `HINT_RADII_M` around the point."""
    T = np.asarray(obj.T_palm_obj)
    R, t = T[:3, :3], T[:3, 3]
    cands = []
    if err is not None:
        cands.append(obj.closest_surface(R.T @ (err.closest_palm - t))[0])
    a = np.array([1.0, 0.0, 0.0]) if abs(n_out[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n_out, a)
    u /= np.linalg.norm(u)
    v = np.cross(n_out, u)
    for rho in HINT_RADII_M:
        for k in range(4):
            th = 0.5 * math.pi * k + (0.25 * math.pi if rho in HINT_RADII_M[1::2] else 0.0)
            cands.append(obj.closest_surface(p_surf + rho * (math.cos(th) * u + math.sin(th) * v))[0])
    if err is not None:  # around where the finger got, too
        c0 = np.asarray(cands[0], float)
        n0 = obj.closest_surface(c0)[1]
        a0 = np.array([1.0, 0.0, 0.0]) if abs(n0[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u0 = np.cross(n0, a0)
        u0 /= np.linalg.norm(u0)
        v0 = np.cross(n0, u0)
        for rho in HINT_RADII_M[:2]:
            for k in range(4):
                th = 0.5 * math.pi * k
                cands.append(obj.closest_surface(c0 + rho * (math.cos(th) * u0 + math.sin(th) * v0))[0])
    # and seeded surface points, nearest first (other faces of a box, the far side of an edge)
    pts, _ = obj.sample_surface(64, np.random.default_rng(0))
    pts = np.asarray(pts, float)
    cands.extend(pts[np.argsort(np.linalg.norm(pts - p_surf, axis=1))][:8])
    tried = []
    for c in cands[:REACH_HINT_TRIES]:
        c = np.asarray(c, float)
        if any(np.linalg.norm(c - o) < 1e-4 for o in tried) or np.linalg.norm(c - p_surf) < 1e-4:
            continue
        tried.append(c)
        # one attempt (IK from the seed) of the first core, then `place_contact` itself (which may
        # prefer the closing procedure's placement): its result must realize the point as asked
        if _place_verified(hand, obj, f, c, q_seed, link, attempts=1, cores=1).why is None:
            q, _, _ = place_contact(hand, obj, f, c, q_seed, link=link, suggest=False)
            _, _, _, n_palm = _surface(obj, c)
            if _verify(hand, obj, f, link or f.pad_link, q, c, n_palm).why is None:
                return c
    return None


def _unreachable_in_object_frame(err, obj, p_surf, reachable=None, why=None):
    """The IK's `UnreachableError` re-worded in the object frame, with the failing
    constraint, a surface point the finger does realize (`_realized_point_near`), or the
    advice to move the object."""
    T = np.asarray(obj.T_palm_obj)
    R, t = T[:3, :3], T[:3, 3]
    closest = R.T @ (err.closest_palm - t)
    direction = R.T @ err.direction_palm
    if reachable is not None:
        move = float(np.linalg.norm(reachable - np.asarray(p_surf)))
        tail = (f"a surface point it does reach (checked): {_f3(reachable)} (object frame), realized there as asked, "
                f"{move * 1e3:.1f} mm from the requested one")
    else:
        tail = ("no surface point near it is realized: move the object toward the finger (object."
                f"position, palm frame: along {_f3(R @ direction)}) or use another finger")
    head = str(err).split(";")[0]
    if why and not why.startswith("out of reach"):
        head += f" (and with its pad facing the surface: {why})"
    msg = (f"reach: {head}; the finger gets within {err.distance_m * 1e3:.1f} mm, at {_f3(closest)} "
           f"(object frame): move the point along {_f3(direction)} (object frame); {tail}")
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
    # (planning shows no realization warnings: no reachable point is searched for them)
    if isinstance(g, GraspSpec):
        return realize(g, suggest=False).require_placed(), None
    return realize(load_grasp(g), suggest=False).require_placed(), input_record(g)


def realize(spec: GraspSpec, hand=None, *, suggest: bool = True) -> RealizedGrasp:
    """Turn a grasp spec (or a grasp file: `planner.grasp.load_grasp`) into a hand configuration and measure its contacts and closure.

    Contact fingers: `realize_contact`. Posture fingers: the closing procedure from the
    posture. Free fingers: the open posture. Then contact patches (several points per
    touching link), force closure and metric (thesis eqs. (1)-(7)), removable fingers
    (Algorithm 1) and self-collisions of the hand.

    Args:
        spec: a validated `GraspSpec`.
        hand: the `Hand`; None loads ``spec.hand_ref``.
        suggest: a contact not realized as asked gets, in its warning (or its reach error), a
            surface point the finger does realize (`place_contact`'s search, seconds per
            contact). False for a caller that does not show the warnings (`plan`, the audit):
            the same placement, the warning without the point (a reach error still has it).

    Returns:
        The `RealizedGrasp`.

    Raises:
        KinematicsError: a contact point is out of its finger's reach (the message names
            the file and the key).
    """
    if not isinstance(spec, GraspSpec):  # a grasp file, as `plan_regrasp` takes (an AttributeError before)
        spec = load_grasp(spec)
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
                q, _, n = place_contact(hand, obj, f, fs.point_obj, q, link=fs.link, suggest=suggest)
            except UnreachableError as err:
                if not suggest:  # an error is always shown: with the point the finger does reach
                    try:
                        place_contact(hand, obj, f, fs.point_obj, q, link=fs.link)
                    except UnreachableError as hinted:
                        err = hinted
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
    return measure(spec, hand, q, notes)


def measure(spec: GraspSpec, hand, q, notes=()) -> RealizedGrasp:
    """The grasp ``spec`` with the hand at ``q``: contacts, closure, removable fingers,
    collisions and findings measured at the spec's object pose (what `realize` does once it
    has placed the fingers; a reposing move measures every waypoint so, with the object at
    the waypoint's pose, `planner.repose`)."""
    obj = spec.object
    # one state, queried once: link-object distances are computed once for all four queries
    state = hand.state(q)
    q = state.q
    patches = contact_patches(hand, state, obj, palm=True)
    palm_touches = PALM in patches
    if spec.palm == "free":  # the file keeps the palm out of the grasp (a problem if it touches)
        patches.pop(PALM, None)
    patches = {k: Patch(_ro(v.points), _ro(v.normals), v.links) for k, v in patches.items()}
    closure = grasp_closure(patches, spec.friction)
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
        _removable=_Removable(patches, spec.friction),
        collisions=colls,
        missing=missing,
        contacts=contacts,
        problems=tuple(problems),
        warnings=tuple(list(notes) + warnings),
    )


def grasp_findings(spec: GraspSpec, hand, obj, state, contacts, missing, colls) -> tuple[list[str], list[str]]:
    """What makes a realized grasp differ from its file: (problems, warnings), one line each.

    ``state`` is the realized hand (`planner.collision.HandState`, ``hand.state(q)``).

    Problems (``check`` exits 1): a placed finger that does not touch; a link deeper than
    `PENETRATION_TOL_M` in the object, the palm or another finger; a closing joint of a
    placed finger at its closing limit (`planner.hand.Finger.closes_toward`) that a posture did not ask for (the finger
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
                if joint in f.close_joints and side == f.closes_toward(joint):
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
