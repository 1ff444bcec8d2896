"""Contacts between a hand configuration and the object, and collision checks (coal).

A finger touches the object through a patch of several points (thesis section VII: the
simulator reports every point the link and the object have in common, and the closure
test uses all of them). Here a link touches when its signed distance to the object is
at most ``touch_tol_m`` (or it penetrates). Its patch is the witness point of the
link-object distance query, projected on the object surface, plus a ring of object-surface
points around it that are within ``touch_tol_m`` of the link surface. Points are in the
object frame; normals point INTO the object (minus the outward surface normal).
"""

from __future__ import annotations

import numpy as np

from planner.collision import HandState
from planner.errors import InputError, UnknownNameError
from planner.model import PALM, Contact, Patch

TOUCH_TOL_M = 1e-3
RING_RADII_M = (1.5e-3, 3.0e-3)
RING_DIRECTIONS = 8
_MIN_SPACING_M = 2e-4


def _state(hand, q) -> HandState:
    """``q`` as a state of ``hand``: a `HandState` is used as it is (its queries are cached)."""
    if isinstance(q, HandState):
        if q.model is not hand.collision:
            raise InputError("the HandState given as q belongs to another hand")
        return q
    return hand.state(q)


def _fingers(hand, fingers):
    if fingers is None:
        return list(hand.fingers)
    out = []
    for f in fingers:
        if f not in hand.fingers:
            raise UnknownNameError("finger", str(f), hand.fingers)
        out.append(f)
    return out


def touching_links(hand, q, obj, touch_tol_m: float = TOUCH_TOL_M, fingers=None) -> dict[str, tuple[str, ...]]:
    """Contact links within ``touch_tol_m`` of the object (or penetrating), per finger.

    Args:
        hand: planner.hand.Hand.
        q: (nq,) joint angles, or a `planner.collision.HandState` of ``hand`` (as in every
            function here: one state queried several times computes FK and distances once).
    Returns:
        finger -> tuple of touching links (only fingers that touch).
    """
    state = _state(hand, q)
    out = {}
    for f in _fingers(hand, fingers):
        links = hand.fingers[f].contact_links
        res = state.link_object(obj, links)
        touching = tuple(l for l in links if l in res and res[l].distance_m <= touch_tol_m)
        if touching:
            out[f] = touching
    return out


def _witness_obj(T_obj_palm, query) -> np.ndarray:
    """Midpoint of a link-object distance query's witness points (`LinkDistance`), object frame."""
    return T_obj_palm[:3, :3] @ (0.5 * (query.p_link_palm + query.p_obj_palm)) + T_obj_palm[:3, 3]


def _link_patch(state, obj, T_obj_palm, T_palm_obj, query, touch_tol_m):
    """Patch of one touching link: (points (n,3), inward normals (n,3)) in the object frame."""
    p0, n0, _ = obj.closest_surface(_witness_obj(T_obj_palm, query))
    pts, nrm = [p0], [n0]
    a = np.array([1.0, 0.0, 0.0]) if abs(n0[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n0, a)
    u /= np.linalg.norm(u)
    v = np.cross(n0, u)
    R, t = T_palm_obj[:3, :3], T_palm_obj[:3, 3]
    for rho in RING_RADII_M:
        for k in range(RING_DIRECTIONS):
            th = 2.0 * np.pi * k / RING_DIRECTIONS
            ps, ns, _ = obj.closest_surface(p0 + rho * (np.cos(th) * u + np.sin(th) * v))
            if _too_close(ps, pts):
                continue
            if state.point_distance(R @ ps + t, query.geometries) <= touch_tol_m:
                pts.append(ps)
                nrm.append(ns)
    return np.array(pts), -np.array(nrm)


def _too_close(p: np.ndarray, pts: list) -> bool:
    """``min(np.linalg.norm(p - x) for x in pts) < _MIN_SPACING_M``: the squared distances at
    once, the one-point norms only when the nearest is within rounding (1e-9) of the spacing."""
    d = np.asarray(pts) - p
    m2 = float((d * d).sum(1).min())
    if abs(m2 - _MIN_SPACING_M**2) > 1e-9 * _MIN_SPACING_M**2 and m2 == m2:
        return m2 < _MIN_SPACING_M**2
    return min(np.linalg.norm(p - x) for x in pts) < _MIN_SPACING_M


def _owner_links(hand, owner: str) -> tuple[str, ...]:
    """The contact links of a finger, or the palm's links with geometry (`PALM`)."""
    return hand.collision.finger_links(None) if owner == PALM else hand.fingers[owner].contact_links


def contact_patches(hand, q, obj, touch_tol_m: float = TOUCH_TOL_M, fingers=None, palm: bool = False
                    ) -> dict[str, Patch]:
    """Contact patches of a hand configuration on the object.

    Args:
        hand: planner.hand.Hand.
        q: (nq,) joint angles, or a `planner.collision.HandState` of ``hand``.
        obj: planner.objects.GraspObject.
        touch_tol_m: a link touches when its distance to the object is at most this.
        fingers: restrict to these fingers (default all).
        palm: also the palm's patch (key `PALM`) when a palm link touches.
    Returns:
        owner -> `Patch` (points (n, 3), inward unit normals (n, 3), the link of every point)
        for touching fingers (and the palm) only, several points per touching link, object
        frame. Ready for planner.closure.grasp_closure.
    """
    state = _state(hand, q)
    T_palm_obj = obj.T_palm_obj
    T_obj_palm = np.linalg.inv(T_palm_obj)
    out = {}
    owners = _fingers(hand, fingers) + ([PALM] if palm else [])
    for f in owners:
        links = _owner_links(hand, f)
        queries = state.link_object(obj, links)
        P, N, L = [], [], []
        for link in links:
            qy = queries.get(link)
            if qy is None or qy.distance_m > touch_tol_m:
                continue
            p, n = _link_patch(state, obj, T_obj_palm, T_palm_obj, qy, touch_tol_m)
            P.append(p)
            N.append(n)
            L.extend([link] * len(p))
        if P:
            out[f] = Patch(np.vstack(P), np.vstack(N), L)
    return out


def collisions(hand, q, obj=None, touch_tol_m: float = TOUCH_TOL_M, fingers=None
               ) -> list[tuple[str, str, float]]:
    """Collisions of a hand configuration.

    Finger-finger and finger-palm link pairs that interpenetrate (adjacent links and pairs
    overlapping by design at q = 0 / the open posture are excluded), and links penetrating
    the object deeper than ``touch_tol_m``.

    Args:
        fingers: only pairs involving these fingers (default all; then the palm-object pair too).
    Returns:
        list of (name_a, name_b, depth_m), names are link names or "object"; depth > 0.
    """
    state = _state(hand, q)
    sel = None if fingers is None else set(_fingers(hand, fingers))
    out = state.self_collisions(fingers=sel)
    if obj is not None:
        links = []
        for f in _fingers(hand, fingers):
            links.extend(hand.fingers[f].links)
        if fingers is None:
            links.extend(hand.collision.finger_links(None))
        for link, ld in state.link_object(obj, links).items():
            if ld.distance_m < -touch_tol_m:
                out.append((link, "object", -ld.distance_m))
    return out


def link_contacts(hand, q, obj, touch_tol_m: float = TOUCH_TOL_M, fingers=None, palm: bool = False) -> list[Contact]:
    """One realized contact per touching link: where, with which normal, how deep.

    Args:
        hand, q, obj: as `contact_patches`.
        touch_tol_m: a link touches when its signed distance to the object is at most this.
        fingers: restrict to these fingers (default all).
        palm: also the palm's touching links (``finger`` None), after the fingers'.
    Returns:
        list (hand finger order, then the finger's contact_links order) of
        `planner.model.Contact` in the object frame: ``point`` the link's closest
        object-surface point, ``normal`` the inward unit surface normal there,
        ``distance_m`` the link-object signed distance (negative: penetration).
    """
    state = _state(hand, q)
    T_obj_palm = np.linalg.inv(obj.T_palm_obj)
    out = []
    for f in _fingers(hand, fingers) + ([PALM] if palm else []):
        links = _owner_links(hand, f)
        queries = state.link_object(obj, links)
        for link in links:
            qy = queries.get(link)
            if qy is None or qy.distance_m > touch_tol_m:
                continue
            d = qy.distance_m
            p, n_out, _ = obj.closest_surface(_witness_obj(T_obj_palm, qy))
            out.append(Contact(None if f == PALM else f, link, p, -np.asarray(n_out, dtype=float), frame="obj", distance_m=d))
    return out
