"""The collision view of one moving finger, and the path helpers of finger motions.

`FingerScene` is what a finger path (`planner.motion`: the OMPL move; `planner.retreat`:
the lift and land) asks of the collision layer: the hand held at a configuration with one
finger moving, its distances to the object and its validity against margins. The helpers
densify joint paths (no joint moves more than a resolution between rows) and check the
configurations and numbers a path planner is given. No OMPL here.
"""

from __future__ import annotations

import math

import numpy as np

from planner.collision import LINK_EPS_M
from planner.contacts import TOUCH_TOL_M
from planner.errors import InputError, MotionError, UnknownNameError

DEFAULT_CLEARANCE_M = 0.002
"""Distance a moving finger keeps from the object outside the lift/land steps."""
DEFAULT_TOUCH_TOL_M = TOUCH_TOL_M
"""Finger-object penetration tolerated at a contact (the lift/land ends), as in contacts."""


# ---------------------------------------------------------------- collision scene


class FingerScene:
    """One moving finger of a hand held at ``q_ref``: its paths' view of the collision layer.

    The queries are `planner.collision.HandState` queries on ``hand.state(q_ref)`` with the
    finger moved by `HandState.with_finger` (only its chain re-posed; the palm, the other
    fingers and the object keep their pose, and their side of the clearance check is built
    once). A configuration is valid (`HandState.clearance`) when every link of the finger
    is at least ``object_margin_m`` from the object (negative: tolerated penetration, a
    signed distance on a mesh object too, `planner.signed_distance.signed_distance_geometry`) and
    does not penetrate the palm, the other fingers or the non-adjacent links of its own
    finger (touching is fine; the allowed pairs and the 1 um threshold of
    ``planner.contacts.collisions``).

    ``others`` False: the hand as if it had no other finger (`HandState.clearance`): every
    configuration valid with them is valid without them.

    A link the finger's closing joints do not move (`base_links`: the Allegro's abduction and
    thumb-base links; none on the iCub) cannot be taken away from the object by opening the
    finger: its distance is set by where the object lies, as the palm's is. Such a link is
    asked no more than it has with the finger at its open posture (`required`), the lifted
    finger of every grasp state (a finger with no contact is placed there), so a lift, a land
    or a move demands no more of it than the state it starts or ends in has; but never less
    than the touch tolerance (nearer, the link counts as touching). It matters for
    objects held against the palm: the Allegro's abduction links stay 1.4-1.5 mm from such an
    object whatever the finger does, inside the 2 mm clearance.
    """

    def __init__(self, hand, obj, q_ref: np.ndarray, finger: str, touch_tol_m: float, others: bool = True):
        self.hand = hand
        self.others = bool(others)  # False: the other fingers are not there (`HandState.clearance`)
        self.finger = hand.fingers[finger]
        self.idx = np.asarray(self.finger.q_index, dtype=int)
        self.q_ref = np.array(q_ref, dtype=float)
        self.touch_tol_m = float(touch_tol_m)
        self.obj = obj
        self.T_palm_obj = np.asarray(obj.T_palm_obj, dtype=float)
        self.moving_links = hand.collision.finger_links(finger)
        if not self.moving_links:
            raise MotionError(f"finger {finger!r} has no collision geometry")
        self.base = hand.state(self.q_ref)
        self._open: dict[str, float] | None = None
        self._base_links: tuple[str, ...] | None = None

    def state(self, q_finger: np.ndarray):
        """The hand with this finger at ``q_finger`` (`HandState.with_finger`)."""
        return self.base.with_finger(self.finger.name, q_finger)

    def full_q(self, q_finger: np.ndarray) -> np.ndarray:
        q = self.q_ref.copy()
        q[self.idx] = q_finger
        return q

    def link_poses(self, q_finger: np.ndarray) -> np.ndarray:
        """``T_palm_link`` of the moving links, (k, 4, 4)."""
        return self.state(q_finger).finger_link_poses(self.finger.name)

    # -- queries
    def open_distances(self) -> dict[str, float]:
        """Each moving link's distance to the object (its nearest geometry) with the finger at
        its open posture (``hand.q_open``, the lifted finger of the grasp states)."""
        if self._open is None:
            q = np.clip(np.asarray(self.hand.q_open, dtype=float)[self.idx],
                        np.asarray(self.hand.lower, dtype=float)[self.idx],
                        np.asarray(self.hand.upper, dtype=float)[self.idx])
            out: dict[str, float] = {}
            for d, link, _, _ in self.state(q).object_distances(self.obj, self.finger.name):
                out[link] = min(d, out.get(link, math.inf))
            self._open = out
        return self._open

    def base_links(self) -> tuple[str, ...]:
        """The moving links no closing joint moves (`Finger.close_joints`, every joint if none
        is named): the columns of those joints in the link's Jacobian are zero."""
        if self._base_links is None:
            f = self.finger
            cols = [f.q_index[f.joints.index(j)] for j in (f.close_joints or f.joints)]
            self._base_links = tuple(
                link for link in self.moving_links
                if not np.any(np.asarray(self.base.frame_jacobian(link), dtype=float)[:, cols]))
        return self._base_links

    def required(self, link: str, margin_m: float) -> float:
        """The distance from the object ``link`` must keep where ``margin_m`` is asked: the
        margin; for a `base_links` link no more than it has at the finger's open posture (less
        the collision layer's 1 um resolution, `planner.collision.LINK_EPS_M`), but never inside
        the object. Such a link is where the open finger puts it: a lifted finger is lifted as
        far as it goes with it there, and the plan's audit counts it lifted
        (`planner.audit`: a link of it within the touch tolerance then carries nothing; the
        Allegro thumb's link_12.0 lies 0.88 mm from a box against the palm at every thumb
        posture)."""
        if link not in self.base_links():
            return margin_m
        return min(margin_m, max(self.open_distances()[link] - LINK_EPS_M, 0.0))

    def lifted_as_far_as_it_goes(self, q_finger: np.ndarray) -> bool:
        """Whether the finger at ``q_finger`` touches the object (within the touch tolerance)
        only with `base_links` links no nearer to it than at the open posture (`required`):
        lifted, as far as the finger can be."""
        touching = [(d, link) for d, link, _, _ in self.object_distances(q_finger) if d < self.touch_tol_m]
        return bool(touching) and all(link in self.base_links() and d >= self.required(link, self.touch_tol_m)
                                      for d, link in touching)

    def is_clear(self, st, margin_m: float) -> bool:
        """`HandState.clearance` of the state ``st`` (this scene's finger moved) with the
        object margin of each link capped by `required` (see class doc)."""
        name = self.finger.name
        if st.clearance(self.obj, name, margin_m, self.others):
            return True
        floor = min(self.required(link, margin_m) for link in self.moving_links)
        if floor >= margin_m or not st.clearance(self.obj, name, floor, self.others):
            return False  # (the palm, the other fingers and its own links: no margin)
        return all(d >= self.required(link, margin_m) for d, link, _, _ in st.object_distances(self.obj, name))

    def is_lifted(self, st, link: str, lift_m: float, clearance_m: float) -> bool:
        """A lift's end in the state ``st``: ``link`` (the contact's) ``lift_m`` and every link
        ``clearance_m`` from the object, each capped by `required` (the contact link's distance
        first, the whole finger's only then, and `is_clear`)."""
        name = self.finger.name
        return (all(d >= self.required(link, lift_m) for d, _, _, _ in st.object_distances(self.obj, name, links=(link,)))
                and all(d >= self.required(other, clearance_m) for d, other, _, _ in st.object_distances(self.obj, name))
                and self.is_clear(st, clearance_m))

    def is_valid(self, q_finger: np.ndarray, object_margin_m: float) -> bool:
        """True when the finger at ``q_finger`` respects the margins (see class doc)."""
        return self.is_clear(self.state(q_finger), object_margin_m)

    def object_distances(self, q_finger: np.ndarray) -> list[tuple[float, str, np.ndarray, np.ndarray]]:
        """Signed distance of every moving geometry to the object (negative: penetration).

        Returns a list of ``(distance_m, link, p_link_palm (3,), p_object_palm (3,))``:
        the nearest points on the link and on the object, palm frame.
        """
        return self.state(q_finger).object_distances(self.obj, self.finger.name)

    def object_distance(self, q_finger: np.ndarray) -> tuple[float, str, np.ndarray, np.ndarray]:
        """The entry of :meth:`object_distances` nearest to the object."""
        return min(self.object_distances(q_finger), key=lambda r: r[0])

    def point_on_link(self, q_finger: np.ndarray, link: str, p_palm: np.ndarray) -> np.ndarray:
        """Palm-frame point ``p_palm`` expressed in the frame of ``link`` at ``q_finger``."""
        T = self.link_poses(q_finger)[self.moving_links.index(link)]
        return T[:3, :3].T @ (np.asarray(p_palm, dtype=float) - T[:3, 3])

    def explain(self, q_finger: np.ndarray, object_margin_m: float) -> str:
        """A short human-readable reason why ``q_finger`` is invalid."""
        st = self.state(q_finger)
        name = self.finger.name
        if min(self.required(link, object_margin_m) for link in self.moving_links) >= object_margin_m:
            reasons = st.clearance_violations(self.obj, name, object_margin_m, self.others)
        else:  # the object's lines with each link's own margin, then the hand's (no object margin)
            reasons = [f"{link} is {d * 1000:.1f} mm from the object (needs {self.required(link, object_margin_m) * 1000:.1f})"
                       for d, link, _, _ in st.object_distances(self.obj, name) if d < self.required(link, object_margin_m)]
            reasons += st.clearance_violations(self.obj, name, -math.inf, self.others)
        return "; ".join(reasons) or "no collision found"


# ------------------------------------------------------------------- path helpers


def densify(waypoints: np.ndarray, resolution_rad: float) -> np.ndarray:
    """Insert points so no joint moves more than ``resolution_rad`` between rows."""
    waypoints = np.asarray(waypoints, dtype=float)
    rows = [waypoints[0]]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        steps = max(1, int(math.ceil(np.max(np.abs(b - a)) / resolution_rad - 1e-9)))
        t = np.arange(1, steps)[:, None] / steps
        rows.extend(a + t * (b - a))
        rows.append(b)  # waypoints exactly, not a + 1.0 * (b - a)
    return np.array(rows)


def first_invalid(scene: FingerScene, path: np.ndarray, margins) -> int | None:
    margins = np.broadcast_to(np.asarray(margins, dtype=float), (len(path),))
    for k, (q, m) in enumerate(zip(path, margins)):
        if not scene.is_valid(q, m):
            return k
    return None


def as_q(hand, q, what: str) -> np.ndarray:
    nq = len(hand.joint_names)
    arr = np.array(q, dtype=float)
    if arr.shape != (nq,):
        raise InputError(f"{what} must have shape ({nq},) (hand joints {', '.join(hand.joint_names)}); got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what} has non-finite values")
    return arr


def finger_of(hand, finger: str):
    try:
        return hand.fingers[finger]
    except KeyError:
        raise UnknownNameError("finger", finger, hand.fingers) from None


def check_limits(hand, finger, q_finger: np.ndarray, what: str) -> np.ndarray:
    idx = list(finger.q_index)
    lo = np.asarray(hand.lower, dtype=float)[idx]
    hi = np.asarray(hand.upper, dtype=float)[idx]
    tol = 1e-6
    bad = [(j, v) for j, v, a, b in zip(finger.joints, q_finger, lo, hi) if v < a - tol or v > b + tol]
    if bad:
        j, v = bad[0]
        raise InputError(f"{what}: joint {j} = {v:.4f} rad is outside its limits")
    return np.clip(q_finger, lo, hi)


def check_positive(**values: float) -> None:
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be positive and finite; got {v!r}")
