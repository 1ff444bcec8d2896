"""One collision layer over one kinematic state (coal, pinocchio; no pybullet, no OMPL).

Two types serve every distance and collision query of the planner (contacts, the closing
procedure, realization, the graph's finger checks and the OMPL validity check):

- `CollisionModel`, built once per hand (`Hand.collision`): the collision geometries (link,
  owner finger or palm, coal shape, placement in the parent joint frame, bounding sphere),
  the **allowed pairs** (link pairs never checked: adjacent links, pairs the hand spec
  lists, and shapes overlapping by design at q = 0 or at the open posture, as MoveIt's
  "default" allowed-collision matrix) and the geometry pairs that are checked, in a fixed
  order (plans record contacts and collisions in that order).
- `HandState`, a hand at a configuration ``q`` (in the spirit of pink's ``Configuration``):
  it reads one `planner.kinematics.Kinematics` (its own ``pinocchio.Data``, forward
  kinematics run once at construction, ``q`` copied and read-only); the geometry transforms
  are computed lazily, once, on the first query that needs them. `HandState.with_finger`
  moves one finger and re-poses only that finger's geometries.

All poses are in the palm frame. Signed distances are negative for penetration.
The pybullet replay is not built on this on purpose: its contacts are the simulator's
measurement, which the replay compares with the plan.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Iterable, Mapping

import coal
import numpy as np
import pinocchio as pin

from planner.errors import UnknownNameError
from planner.kinematics import KinematicModel, Kinematics
from planner.signed_distance import (bounding_sphere, object_transform, signed_distance_geometry, transform,
                                      transform_matrix)

LINK_EPS_M = 1e-6
"""Penetration between two links below this is not a collision (also: shapes closer than
this at q = 0 or the open posture overlap by design and their pair is allowed)."""
HAND_OVERLAP_TOL_M = 5e-4
"""Deepest two links of the hand (of different fingers, a finger and the palm, or a finger's
non-adjacent links) may overlap in a finger path the planner accepts (`HandState.clearance`):
what `check` accepts in a grasp (`planner.realization.PENETRATION_TOL_M`) and the audit in a
plan (`planner.audit.SELF_TOL_M`), so a grasp realized with two links that much inside each
other can be left; neither engine simulates the hand's contacts with itself."""

CULL_M = 1e-4
"""`HandState.finger_penetrates` skips a geometry whose bounding sphere is this far from the
object's (m): far above the error of coal's distances, so the answer is the same."""

_POINT = coal.Sphere(1e-7)  # a point, for point-to-link distances


@dataclass(frozen=True, eq=False)
class Geometry:
    """One collision shape of a hand.

    Attributes:
        index: position in `CollisionModel.geometries`.
        link: the link it belongs to.
        finger: the finger owning the link, None for the palm.
        shape: coal geometry in its own frame.
        joint_id: pinocchio id of its parent joint.
        placement: T_joint_geom, the shape's pose in its parent joint frame.
        center: (3,) bounding sphere centre in the parent joint frame.
        radius_m: bounding sphere radius.
    """

    index: int
    link: str
    finger: str | None
    shape: coal.CollisionGeometry
    joint_id: int
    placement: pin.SE3
    center: np.ndarray
    radius_m: float


@dataclass(frozen=True, eq=False)
class LinkDistance:
    """Signed distance between one link (its nearest geometry) and the object.

    Attributes:
        distance_m: signed distance (negative: penetration).
        p_link_palm, p_obj_palm: (3,) witness points on the link and on the object, palm frame.
        geometries: indices of the link's geometries.
    """

    distance_m: float
    p_link_palm: np.ndarray
    p_obj_palm: np.ndarray
    geometries: tuple[int, ...]




def object_sphere(obj) -> tuple[np.ndarray, float, coal.Transform3s]:
    """(palm-frame centre (3,), radius) of a sphere around the object (its local AABB's), and
    the object's pose as a coal transform (`object_transform`)."""
    c, r = bounding_sphere(obj.geometry)
    T = np.asarray(obj.T_palm_obj, dtype=float)
    return T[:3, :3] @ c + T[:3, 3], r, object_transform(obj)


def _pair_arrays(geoms, pairs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geometry index pairs as two int arrays, and each pair's bounding radii summed."""
    pairs = list(pairs)
    I = np.array([i for i, _ in pairs], dtype=int)
    J = np.array([j for _, j in pairs], dtype=int)
    reach = np.array([geoms[i].radius_m + geoms[j].radius_m for i, j in pairs], dtype=float)
    return I, J, reach


class CollisionModel:
    """The collision geometry of one hand and its allowed pairs; built once per hand.

    Attributes:
        model: the pinocchio model the geometries hang on.
        kinematic_model: its `planner.kinematics.KinematicModel` (with the palm frame).
        geometries: every `Geometry`, in URDF order (capsules merged).
        links: links with geometry, in order of first geometry.
        link_geometries: link -> indices of its geometries.
        allowed: link pairs never checked (frozensets of two link names).
        pairs: checked geometry index pairs (i < j): different links, not both on the palm,
            not allowed; in a fixed order.
    """

    def __init__(self, model, T_palm_world: pin.SE3, geometries: Iterable[Geometry],
                 finger_joints: Mapping[str, tuple[int, ...]], allowed, by_design_qs: Iterable[np.ndarray] = ()):
        """Args:
            model: pinocchio model.
            T_palm_world: pose of the pinocchio root frame in the palm frame.
            geometries: the hand's geometries (their ``index`` is their position).
            finger_joints: finger -> positions of its joints in q (the finger's joint order).
            allowed: link pairs allowed from the spec and the kinematic tree.
            by_design_qs: configurations at which overlapping pairs (distance below
                `LINK_EPS_M`) are allowed too (q = 0, the open posture).
        """
        self.model = model
        self.kinematic_model = KinematicModel(model, T_palm_world)
        self.T_palm_world = self.kinematic_model.T_palm_world
        self.palm_is_root = self.kinematic_model.palm_is_root
        self._T_palm_world_h = np.linalg.inv(self.T_palm_world.inverse().homogeneous)
        self.geometries = tuple(geometries)
        self.finger_joints: Mapping[str, tuple[int, ...]] = MappingProxyType(
            {f: tuple(int(i) for i in ix) for f, ix in finger_joints.items()})
        link_geoms: dict[str, list[int]] = {}
        for g in self.geometries:
            link_geoms.setdefault(g.link, []).append(g.index)
        self.link_geometries: Mapping[str, tuple[int, ...]] = MappingProxyType(
            {k: tuple(v) for k, v in link_geoms.items()})
        self.links = tuple(self.link_geometries)
        self._finger_geoms = {f: tuple(g.index for g in self.geometries if g.finger == f)
                              for f in dict.fromkeys(g.finger for g in self.geometries)}
        self._finger_links = {f: tuple(dict.fromkeys(self.geometries[i].link for i in ids))
                              for f, ids in self._finger_geoms.items()}
        self.allowed = frozenset(frozenset(p) for p in allowed)
        self.pairs = self._checked_pairs()
        by_design = set()
        for q in by_design_qs:
            for a, b, d in HandState(self, q).link_pair_distances(self.pairs):
                if d < LINK_EPS_M:
                    by_design.add(frozenset((a, b)))
        if by_design:
            self.allowed = self.allowed | by_design
            self.pairs = self._checked_pairs()
        self._checked = frozenset(self.pairs)
        self._compute: dict[tuple[int, int], coal.ComputeCollision] = {}

    def _checked_pairs(self) -> tuple[tuple[int, int], ...]:
        out = []
        n = len(self.geometries)
        for i in range(n):
            for j in range(i + 1, n):
                a, b = self.geometries[i], self.geometries[j]
                if a.link == b.link or (a.finger is None and b.finger is None):
                    continue
                if frozenset((a.link, b.link)) in self.allowed:
                    continue
                out.append((i, j))
        return tuple(out)

    def pair_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`pairs` as arrays: first and second geometry indices and their bounding radii's sum."""
        arr = self.__dict__.get("_pair_arrays")
        if arr is None or arr[0] is not self.pairs:
            arr = self.__dict__["_pair_arrays"] = (self.pairs, _pair_arrays(self.geometries, self.pairs))
        return arr[1]

    def is_checked(self, i: int, j: int) -> bool:
        """True when the geometry pair (i, j) is checked (not allowed to touch)."""
        return (min(i, j), max(i, j)) in self._checked

    def is_allowed(self, link_a: str, link_b: str) -> bool:
        """True when the two links may overlap (symmetric)."""
        return frozenset((link_a, link_b)) in self.allowed

    def finger_geometries(self, finger: str | None) -> tuple[int, ...]:
        """Indices of the geometries owned by a finger (None: the palm), in order."""
        return self._finger_geoms.get(finger, ())

    def finger_links(self, finger: str | None) -> tuple[str, ...]:
        """Links with geometry owned by a finger (None: the palm), in order."""
        return self._finger_links.get(finger, ())

    def compute_collision(self, i: int, j: int) -> coal.ComputeCollision:
        """coal's cached collision functor for the geometry pair (i, j) (built once)."""
        c = self._compute.get((i, j))
        if c is None:
            c = self._compute[(i, j)] = coal.ComputeCollision(self.geometries[i].shape, self.geometries[j].shape)
        return c

    def state(self, q) -> "HandState":
        """The hand at ``q`` (nq,)."""
        return HandState(self, q)


class HandState:
    """A hand at a configuration: immutable; FK once, geometry transforms once, lazily.

    Build with ``hand.state(q)`` (or ``hand.collision.state(q)``): the state makes its own
    `planner.kinematics.Kinematics` (one ``pinocchio.Data``, FK at construction). Every
    query reads this state: nobody calls a function that silently recomputes or reads a
    stale ``pinocchio.Data``. `HandState.on` reads a caller's `Kinematics` instead (an
    iterative procedure updating one): that state is valid until the caller updates it.
    Not thread-safe.

    Attributes:
        model: the hand's `CollisionModel`.
        q: (nq,) read-only joint configuration (order ``hand.joint_names``).
        kinematics: the `planner.kinematics.Kinematics` it reads.
    """

    __slots__ = ("model", "q", "kinematics", "_generation", "_tf", "_origin", "_moved", "_moved_T", "_cache")

    def __init__(self, model: CollisionModel, q):
        self._init(model, Kinematics(model.kinematic_model, q))

    @classmethod
    def on(cls, model: CollisionModel, kinematics: Kinematics) -> "HandState":
        """The hand as posed by ``kinematics`` (a `Kinematics` of ``model``'s hand), without a
        copy: valid until ``kinematics`` is updated (a query then raises RuntimeError)."""
        if kinematics.kinematic_model is not model.kinematic_model:
            raise ValueError("the Kinematics belongs to another hand")
        state = cls.__new__(cls)
        state._init(model, kinematics)
        return state

    def _init(self, model: CollisionModel, kinematics: Kinematics) -> None:
        self.model = model
        self.kinematics = kinematics
        self._generation = kinematics.generation
        self.q = kinematics.q
        self._tf: dict[int, coal.Transform3s] = {}
        # the state whose other fingers this one shares (see with_finger); None: this one
        # (not ``self``: no reference cycle, a state and its pinocchio.Data go when unused)
        self._origin: HandState | None = None
        self._moved: str | None = None
        self._moved_T: np.ndarray | None = None
        # computed once: ("center", i), ("links", id(obj)) -> (obj, {link: LinkDistance}),
        # ("kin", finger), ("clearance", finger, id(obj)) -> (obj, scene)
        self._cache: dict = {}

    # ------------------------------------------------------------------ kinematics
    def _kinematics(self) -> Kinematics:
        """The kinematics this state reads (RuntimeError when updated since, `HandState.on`)."""
        kin = self.kinematics
        if kin.generation != self._generation:
            raise RuntimeError("this HandState's Kinematics was updated to another configuration since")
        return kin

    def transform(self, i: int) -> coal.Transform3s:
        """T_palm_geom of geometry ``i`` as a coal transform (computed once)."""
        tf = self._tf.get(i)
        if tf is None:
            g = self.model.geometries[i]
            if self._moved is not None and g.finger == self._moved:
                kin = self._origin._finger_kinematics(self._moved)
                tf = transform(self._finger_poses(self._moved)[kin["geoms"].index(i)])
            else:
                M = self._kinematics().joint_placement(g.joint_id) * g.placement
                if not self.model.palm_is_root:
                    M = self.model.T_palm_world * M
                tf = coal.Transform3s(M.rotation, M.translation)
            self._tf[i] = tf
        return tf

    def center(self, i: int) -> np.ndarray:
        """(3,) bounding sphere centre of geometry ``i``, palm frame."""
        c = self._cache.get(("center", i))
        if c is None:
            g = self.model.geometries[i]
            c = self._kinematics().joint_placement(g.joint_id).act(g.center)
            if not self.model.palm_is_root:
                c = self.model.T_palm_world.act(c)
            self._cache[("center", i)] = c
        return c

    def link_pose(self, link: str) -> np.ndarray:
        """T_palm_link (4, 4) of a link or frame."""
        return self._kinematics().frame_pose(self.model.kinematic_model.frame_id(link))

    def frame_jacobian(self, link: str, p_link=None) -> np.ndarray:
        """Jacobian (6, nq) of a point of a link (`Hand.frame_jacobian`), palm-aligned,
        linear rows first; ``p_link`` in the link frame (default its origin)."""
        return self._kinematics().frame_jacobian(self.model.kinematic_model.frame_id(link), p_link)[0]

    def point_jacobians(self, points, angular: bool = False) -> list[np.ndarray]:
        """Linear Jacobians (3, nq) of points fixed to links (`Hand.point_jacobians`): points
        are (link or frame name, (3,) point in the PALM frame) pairs; (6, nq) with ``angular``."""
        km = self.model.kinematic_model
        return self._kinematics().point_jacobians([(km.frame_id(link), p) for link, p in points], angular)

    def gravity_torques(self, g_palm) -> np.ndarray:
        """Joint torques (nq,) holding the hand's own links under gravity ``g_palm`` ((3,)
        m/s^2, palm frame), N m (`planner.kinematics.Kinematics.gravity_torques`)."""
        return self._kinematics().gravity_torques(g_palm)

    def collision_objects(self) -> list[tuple[str, str | None, coal.CollisionGeometry, coal.Transform3s]]:
        """Every shape posed: (link, finger or None for the palm, coal shape, T_palm_geom)."""
        return [(g.link, g.finger, g.shape, self.transform(g.index)) for g in self.model.geometries]

    # --------------------------------------------------------------- one finger moved
    def with_finger(self, finger: str, q_finger) -> "HandState":
        """This hand with one finger's joints set to ``q_finger`` (the finger's joint order).

        Only that finger's geometries are re-posed: one frame-placement FK of its links, and
        each geometry placed on its link as in the first state of a chain of ``with_finger``
        calls on this finger (``T_link_geom`` measured there, once). Every other geometry is
        where it is in this state. Equal to a fresh state at the same q to rounding.
        """
        joints = self.model.finger_joints.get(finger)
        if joints is None:
            raise UnknownNameError("finger", str(finger), list(self.model.finger_joints))
        origin = self._origin if self._moved in (None, finger) and self._origin is not None else self
        q = np.array(self.q)
        q[list(joints)] = q_finger
        child = HandState(self.model, q)
        child._origin = origin
        child._moved = finger
        return child

    def _finger_kinematics(self, finger: str) -> dict:
        """A finger's link frames and T_link_geom, measured once in this state."""
        kin = self._cache.get(("kin", finger))
        if kin is None:
            geoms = self.model.finger_geometries(finger)
            if not geoms:
                raise UnknownNameError("finger with collision geometry", str(finger),
                                       [f for f in self.model.finger_joints if self.model.finger_geometries(f)])
            links = self.model.finger_links(finger)
            m = self.model.model
            kin = self._cache[("kin", finger)] = {
                "geoms": geoms,
                "links": links,
                "frames": [m.getFrameId(link) for link in links],
                "link_of": np.array([links.index(self.model.geometries[i].link) for i in geoms]),
                "T_link_geom": np.array([np.linalg.inv(self.link_pose(self.model.geometries[i].link))
                                         @ transform_matrix(self.transform(i)) for i in geoms]),  # (k, 4, 4)
            }
        return kin

    def finger_link_poses(self, finger: str) -> np.ndarray:
        """T_palm_link (k, 4, 4) of the finger's links with geometry (`CollisionModel.finger_links`)."""
        kin = self._origin._finger_kinematics(finger) if self._moved == finger else self._finger_kinematics(finger)
        kinematics = self._kinematics()
        return self.model._T_palm_world_h @ np.array([kinematics.root_frame_placement(f).homogeneous
                                                      for f in kin["frames"]])

    def _finger_poses(self, finger: str) -> np.ndarray:
        """T_palm_geom (k, 4, 4) of a finger's geometries, from its link poses."""
        if self._moved == finger:
            if self._moved_T is None:
                kin = self._origin._finger_kinematics(finger)
                self._moved_T = self.finger_link_poses(finger)[kin["link_of"]] @ kin["T_link_geom"]
            return self._moved_T
        kin = self._finger_kinematics(finger)
        return self.finger_link_poses(finger)[kin["link_of"]] @ kin["T_link_geom"]

    # --------------------------------------------------------------------- queries
    def link_object(self, obj, links: Iterable[str]) -> dict[str, LinkDistance]:
        """Signed distance of each link to the object (its nearest geometry), computed once.

        Args:
            obj: `planner.objects.GraspObject` (its own coal geometry).
            links: link names; links without geometry are left out.
        Returns:
            link -> `LinkDistance`, in the order of ``links``.
        """
        entry = self._cache.get(("links", id(obj)))
        if entry is None or entry[0] is not obj:
            entry = self._cache[("links", id(obj))] = (obj, {})
        known = entry[1]
        tf_obj = None
        req = coal.DistanceRequest()
        out = {}
        for link in links:
            ld = known.get(link)
            if ld is None:
                ids = self.model.link_geometries.get(link, ())
                if not ids:
                    continue
                tf_obj = tf_obj or object_transform(obj)
                best = None
                for i in ids:
                    res = coal.DistanceResult()
                    d = coal.distance(self.model.geometries[i].shape, self.transform(i), obj.geometry, tf_obj, req, res)
                    if best is None or d < best[0]:
                        best = (float(d), np.array(res.getNearestPoint1()), np.array(res.getNearestPoint2()))
                ld = known[link] = LinkDistance(best[0], best[1], best[2], ids)
            out[link] = ld
        return out

    def finger_object_distance(self, obj, finger: str) -> float:
        """Smallest signed distance between a finger's links and the object (m).

        The closing procedure's test (thesis eqs. 8-9): no witness points, nothing cached.
        """
        ids = self.model.finger_geometries(finger)
        if not ids:
            raise UnknownNameError("finger with collision geometry", str(finger),
                                   [f for f in self.model.finger_joints if self.model.finger_geometries(f)])
        tf_obj = object_transform(obj)
        req = coal.DistanceRequest()
        best = np.inf
        for i in ids:
            best = min(best, coal.distance(self.model.geometries[i].shape, self.transform(i), obj.geometry, tf_obj,
                                           req, coal.DistanceResult()))
        return float(best)

    def finger_penetrates(self, obj, finger: str, obj_sphere=None) -> bool:
        """``finger_object_distance(obj, finger) < 0.0`` with less work: the first geometry
        that penetrates answers (the finger's last geometries first), and with ``obj_sphere`` (`object_sphere`) a geometry whose
        bounding sphere is more than `CULL_M` from the object's is not queried (shapes that
        far apart cannot penetrate: coal's distance between them is positive)."""
        return self.finger_penetration(obj, finger, obj_sphere) is not None

    def finger_penetration(self, obj, finger: str, obj_sphere=None) -> tuple[int, float] | None:
        """`finger_penetrates`' answer with what it found: None when the finger does not
        penetrate the object, else (the geometry that answered, its penetration depth in m:
        coal's, exact for two convex shapes; 0.0 when either is a mesh (a BVH model), whose
        negative distances bound nothing)."""
        ids = self.model.finger_geometries(finger)
        if not ids:
            raise UnknownNameError("finger with collision geometry", str(finger),
                                   [f for f in self.model.finger_joints if self.model.finger_geometries(f)])
        oc, r_obj, tf_obj = (None, 0.0, None) if obj_sphere is None else obj_sphere
        req = coal.DistanceRequest()
        geoms = self.model.geometries
        for i in reversed(ids):  # from the tip: a closing finger meets the object there first
            if oc is not None:
                d = self.center(i) - oc
                reach = geoms[i].radius_m + r_obj + CULL_M
                if float(d @ d) > reach * reach:
                    continue
            if tf_obj is None:
                tf_obj = object_transform(obj)
            dist = coal.distance(geoms[i].shape, self.transform(i), obj.geometry, tf_obj, req, coal.DistanceResult())
            if dist < 0.0:
                convex = not isinstance(geoms[i].shape, coal.BVHModelBase) and not isinstance(obj.geometry, coal.BVHModelBase)
                return i, (-float(dist) if convex else 0.0)
        return None

    def palm_object_distance(self, obj) -> float | None:
        """Smallest signed distance between the palm's links and the object (m), from the
        cached link distances (`link_object`); None when the palm has no collision geometry."""
        dist = self.link_object(obj, self.model.finger_links(None))
        return min((ld.distance_m for ld in dist.values()), default=None)

    def point_distance(self, p_palm, geometries: Iterable[int]) -> float:
        """Distance from a palm-frame point to the nearest of the given geometries (m)."""
        tf_p = coal.Transform3s(np.eye(3), p_palm)
        req = coal.DistanceRequest()
        best = np.inf
        for i in geometries:
            res = coal.DistanceResult()
            best = min(best, coal.distance(_POINT, tf_p, self.model.geometries[i].shape, self.transform(i), req, res))
        return float(best)

    def link_pair_distances(self, pairs=None, fingers=None, margin_m: float = 0.0) -> list[tuple[str, str, float]]:
        """Signed distances of geometry pairs whose bounding spheres come within ``margin_m``.

        Args:
            pairs: geometry index pairs (default `CollisionModel.pairs`, the checked ones).
            fingers: only pairs with a geometry on one of these fingers (default all).
        Returns:
            [(link_a, link_b, distance_m)] in the order of ``pairs``.
        """
        return list(self._pair_distances(pairs, fingers, margin_m))

    def _pair_distances(self, pairs=None, fingers=None, margin_m: float = 0.0, nearest_first: bool = False):
        """`link_pair_distances` one pair at a time (in the order of ``pairs``, or with
        ``nearest_first`` the most overlapping bounding spheres first)."""
        geoms = self.model.geometries
        I, J, reach = self.model.pair_arrays() if pairs is None else _pair_arrays(geoms, pairs)
        if fingers is not None:
            on = np.array([g.finger in fingers for g in geoms], dtype=bool)
            sel = np.flatnonzero(on[I] | on[J])
            I, J, reach = I[sel], J[sel], reach[sel]
        # the bounding-sphere test of every pair at once; a pair whose centre distance is
        # within rounding (1e-12 relative) of its bound, or not finite, takes the one-pair
        # test: the pairs kept are the same to the bit
        centers = np.zeros((len(geoms), 3))
        for i in np.union1d(I, J).tolist():
            centers[i] = self.center(i)
        diff = centers[I] - centers[J]
        bound = reach + margin_m
        gap = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - bound
        tol = 1e-12 * (1.0 + np.abs(bound))
        near = gap < -tol
        req = coal.DistanceRequest()
        order = np.flatnonzero(~(gap > tol))
        if nearest_first:
            order = order[np.argsort(gap[order], kind="stable")]
        for k in order.tolist():
            i, j = int(I[k]), int(J[k])
            gi, gj = geoms[i], geoms[j]
            if not near[k] and np.linalg.norm(self.center(i) - self.center(j)) > gi.radius_m + gj.radius_m + margin_m:
                continue
            res = coal.DistanceResult()
            d = coal.distance(gi.shape, self.transform(i), gj.shape, self.transform(j), req, res)
            yield gi.link, gj.link, float(d)

    def self_collides(self, fingers=None) -> bool:
        """``bool(self_collisions(fingers))``, from the first pair found interpenetrating
        (the most overlapping bounding spheres tried first)."""
        return any(d < -LINK_EPS_M for _, _, d in self._pair_distances(fingers=fingers, nearest_first=True))

    def self_collisions(self, fingers=None) -> list[tuple[str, str, float]]:
        """Link pairs of the hand that interpenetrate (allowed pairs excluded).

        Args:
            fingers: only pairs involving these fingers (default all).
        Returns:
            [(link_a, link_b, depth_m)], the deepest geometry pair per link pair, depth above
            `LINK_EPS_M`, in the order of `CollisionModel.pairs`.
        """
        worst: dict[tuple[str, str], float] = {}
        for a, b, d in self.link_pair_distances(fingers=fingers):
            if d < -LINK_EPS_M:
                worst[(a, b)] = max(worst.get((a, b), 0.0), -d)
        return [(a, b, depth) for (a, b), depth in worst.items()]

    def object_distances(self, obj, finger: str, links=None) -> list[tuple[float, str, np.ndarray, np.ndarray]]:
        """Signed distance of each of a finger's geometries (those on ``links`` when given) to
        the object's signed-distance geometry (`signed_distance_geometry`; negative: penetration).

        Returns:
            [(distance_m, link, p_link_palm (3,), p_object_palm (3,))] in geometry order.
        """
        T = self._finger_poses(finger)
        kin = self._origin._finger_kinematics(finger) if self._moved == finger else self._finger_kinematics(finger)
        sdf, tf_obj = signed_distance_geometry(obj), object_transform(obj)
        out = []
        request = coal.DistanceRequest()
        for k, i in enumerate(kin["geoms"]):
            if links is not None and self.model.geometries[i].link not in links:
                continue
            result = coal.DistanceResult()
            d = coal.distance(self.model.geometries[i].shape, transform(T[k]), sdf, tf_obj, request, result)
            out.append((float(d), self.model.geometries[i].link, np.array(result.getNearestPoint1(), dtype=float),
                        np.array(result.getNearestPoint2(), dtype=float)))
        return out

    def clearance(self, obj, finger: str, object_margin_m: float, others: bool = True) -> bool:
        """True when the finger keeps ``object_margin_m`` from the object (negative: a tolerated
        penetration, a signed distance on a mesh too, `signed_distance_geometry`) and does not
        penetrate the palm, the other fingers (unless ``others`` is False: the hand as if it had
        no other finger, a test no stricter in any configuration) or its own non-adjacent links
        (by more than `HAND_OVERLAP_TOL_M`; allowed pairs excluded).

        The OMPL validity check: a vectorised bounding-sphere broad phase, then coal's cached
        collision functors. The rest of the hand is taken as posed in the state this one was
        made from by `with_finger` (its scene is built there once).
        """
        return self._clearance_scene(obj, finger, others).is_clear(self._finger_poses(finger), object_margin_m)

    def clearance_violations(self, obj, finger: str, object_margin_m: float, others: bool = True) -> list[str]:
        """Why `clearance` fails, in words: one line per offending link pair (empty when clear)."""
        return self._clearance_scene(obj, finger, others).violations(self._finger_poses(finger), object_margin_m)

    def _clearance_scene(self, obj, finger: str, others: bool = True) -> "_ClearanceScene":
        base = self._origin if self._moved == finger else self
        key = ("clearance", finger, id(obj), bool(others))
        entry = base._cache.get(key)
        if entry is None or entry[0] is not obj:
            entry = base._cache[key] = (obj, _ClearanceScene(base, obj, finger, others))
        return entry[1]


def _finger_pairs(model: CollisionModel, finger: str, moving: tuple) -> tuple:
    """What `_ClearanceScene` needs of the hand and one moving finger alone (built once per
    hand and finger): the static geometries, every geometry's bounding sphere (its own
    frame), the moving ones' centres and radii, the static radii, the checked moving-static
    pairs as a mask, the checked pairs of the finger's own geometries (and as two arrays)."""
    cache = model.__dict__.setdefault("_finger_pairs", {})
    entry = cache.get((finger, moving))
    if entry is None:
        geoms = model.geometries
        static = tuple(g.index for g in geoms if g.finger != finger)
        spheres = [bounding_sphere(g.shape) for g in geoms]
        static_mask = np.array([[model.is_checked(i, s) for s in static] for i in moving],
                               dtype=bool).reshape(len(moving), len(static))
        self_pairs = [(a, b) for a in range(len(moving)) for b in range(a + 1, len(moving))
                      if model.is_checked(moving[a], moving[b])]
        entry = cache[(finger, moving)] = (
            static, spheres, np.array([spheres[i][0] for i in moving]), np.array([spheres[i][1] for i in moving]),
            np.array([spheres[s][1] for s in static]), static_mask, self_pairs,
            np.array([a for a, _ in self_pairs], dtype=int), np.array([b for _, b in self_pairs], dtype=int))
        for arr in entry[2:6]:
            arr.flags.writeable = False  # shared by every scene of this finger
    return entry


class _ClearanceScene:
    """One moving finger against the object and the rest of the hand, as posed in ``base``.

    Everything that does not depend on the finger's joints is built once: the static
    geometries' transforms and bounding spheres (palm frame), the checked pairs as masks,
    the object's bounding sphere, coal's collision functors.
    """

    def __init__(self, base: HandState, obj, finger: str, others: bool = True):
        model = base.model
        self.moving = base._finger_kinematics(finger)["geoms"]
        # what depends on the hand and the finger only: once per hand
        (self.static, spheres, self.moving_centers, self.moving_radii, self.static_radii, self.static_mask,
         self.self_pairs, self.self_a, self.self_b) = _finger_pairs(model, finger, self.moving)
        if not others:  # the palm only (the geometries no finger owns)
            keep = [j for j, g in enumerate(self.static) if model.geometries[g].finger is None]
            self.static = tuple(self.static[j] for j in keep)
            self.static_radii, self.static_mask = self.static_radii[keep], self.static_mask[:, keep]
        self.static_tf = [base.transform(s) for s in self.static]
        T_static = [transform_matrix(tf) for tf in self.static_tf]
        self.static_centers = (np.array([T[:3, :3] @ spheres[s][0] + T[:3, 3] for s, T in zip(self.static, T_static)])
                               if self.static else np.zeros((0, 3)))
        self.model = model
        self.obj = obj
        T_palm_obj = np.asarray(obj.T_palm_obj, dtype=float)
        o_center, self.obj_radius = bounding_sphere(obj.geometry)
        self.obj_tf = transform(T_palm_obj)
        self.obj_center = T_palm_obj[:3, :3] @ o_center + T_palm_obj[:3, 3]
        self.obj_is_mesh = isinstance(obj.geometry, coal.BVHModelBase)
        self.obj_sdf = signed_distance_geometry(obj)
        self.collide_obj = [coal.ComputeCollision(model.geometries[i].shape, obj.geometry) for i in self.moving]
        self.touch_request = coal.CollisionRequest()
        self.touch_request.security_margin = -HAND_OVERLAP_TOL_M

    def is_clear(self, T: np.ndarray, object_margin_m: float) -> bool:
        """T: (k, 4, 4) poses of the moving geometries, palm frame."""
        centers = np.einsum("kij,kj->ki", T[:, :3, :3], self.moving_centers) + T[:, :3, 3]
        radii = self.moving_radii
        tfs = [None] * len(T)

        def tf(k):
            if tfs[k] is None:
                tfs[k] = transform(T[k])
            return tfs[k]

        # object, with its margin (the cheap bounding-sphere test first)
        d_obj = np.sqrt(((centers - self.obj_center) ** 2).sum(1)) - radii - self.obj_radius
        if object_margin_m >= 0 or not self.obj_is_mesh:
            request = coal.CollisionRequest()
            request.security_margin = float(object_margin_m)
            for k in np.flatnonzero(d_obj < object_margin_m):
                if self.collide_obj[k](tf(k), self.obj_tf, request, coal.CollisionResult()):
                    return False
        else:  # a mesh and a tolerated penetration: signed distance (signed_distance_geometry)
            request = coal.DistanceRequest()
            for k in np.flatnonzero(d_obj < object_margin_m):
                d = coal.distance(self.model.geometries[self.moving[k]].shape, tf(k), self.obj_sdf, self.obj_tf,
                                  request, coal.DistanceResult())
                if d < object_margin_m:
                    return False
        # palm and other fingers
        if len(self.static):
            d = (np.sqrt(((centers[:, None, :] - self.static_centers[None]) ** 2).sum(2))
                 - radii[:, None] - self.static_radii[None])
            for k, s in zip(*np.nonzero((d < 0.0) & self.static_mask)):
                i, j = self.moving[k], self.static[s]
                if self.model.compute_collision(i, j)(tf(k), self.static_tf[s], self.touch_request,
                                                      coal.CollisionResult()):
                    return False
        # own non-adjacent links: the bounding-sphere test of every pair at once; a pair within
        # rounding (1e-12 relative) of its bound takes the one-pair test (the same pairs to the bit)
        if self.self_pairs:
            A, B = self.self_a, self.self_b
            dc = centers[A] - centers[B]
            d2, r2 = (dc * dc).sum(1), (radii[A] + radii[B]) ** 2
            tol = 1e-12 * (r2 + d2)
            for k in np.flatnonzero(~(d2 - r2 > tol)).tolist():
                a, b = self.self_pairs[k]
                if not (r2[k] - d2[k] > tol[k]) and not ((centers[a] - centers[b]) ** 2).sum() < (radii[a] + radii[b]) ** 2:
                    continue
                if self.model.compute_collision(self.moving[a], self.moving[b])(
                        tf(a), tf(b), self.touch_request, coal.CollisionResult()):
                    return False
        return True

    def violations(self, T: np.ndarray, object_margin_m: float) -> list[str]:
        """Reasons (one line each, no repeats) why the moving geometries at T are not clear."""
        geoms = self.model.geometries
        reasons = []
        for k, i in enumerate(self.moving):
            gi = geoms[i]
            d = coal.distance(gi.shape, transform(T[k]), self.obj_sdf, self.obj_tf,
                              coal.DistanceRequest(), coal.DistanceResult())
            if d < object_margin_m:
                reasons.append(f"{gi.link} is {d * 1000:.1f} mm from the object (needs {object_margin_m * 1000:.1f})")
            for s, j in enumerate(self.static):
                if not self.static_mask[k, s]:
                    continue
                d = coal.distance(gi.shape, transform(T[k]), geoms[j].shape, self.static_tf[s],
                                  coal.DistanceRequest(), coal.DistanceResult())
                if d < -HAND_OVERLAP_TOL_M:
                    reasons.append(f"{gi.link} penetrates {geoms[j].link} by {-d * 1000:.2f} mm")
        for a, b in self.self_pairs:
            ga, gb = geoms[self.moving[a]], geoms[self.moving[b]]
            d = coal.distance(ga.shape, transform(T[a]), gb.shape, transform(T[b]),
                              coal.DistanceRequest(), coal.DistanceResult())
            if d < -HAND_OVERLAP_TOL_M:
                reasons.append(f"{ga.link} penetrates {gb.link} by {-d * 1000:.2f} mm")
        return list(dict.fromkeys(reasons))
