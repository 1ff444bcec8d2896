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
    """

    def __init__(self, hand, obj, q_ref: np.ndarray, finger: str, touch_tol_m: float):
        self.hand = hand
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
    def is_valid(self, q_finger: np.ndarray, object_margin_m: float) -> bool:
        """True when the finger at ``q_finger`` respects the margins (see class doc)."""
        return self.state(q_finger).clearance(self.obj, self.finger.name, object_margin_m)

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
        reasons = self.state(q_finger).clearance_violations(self.obj, self.finger.name, object_margin_m)
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
