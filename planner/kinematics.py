"""The kinematic state of a hand at one configuration (in the spirit of pink's ``Configuration``).

Two types:

- `KinematicModel`, built once per hand and never written afterwards: the pinocchio model,
  the pose of its root in the palm frame and the frame names (and the spare
  ``pinocchio.Data`` of states no longer in use, see below).
- `Kinematics`, the hand at a configuration ``q``: the **only** holder of a
  ``pinocchio.Data`` in the planner. Forward kinematics runs once at construction (and on an
  explicit `Kinematics.update`); ``q`` is a read-only copy; every query (frame poses, frame
  and point Jacobians, gravity torques) reads that state. Nothing is shared between two
  `Kinematics`: gravity is given to each query and applied to a private copy of the model,
  the shared model's ``gravity`` is never written.

A ``pinocchio.Data`` costs about 20 us to allocate (and as much as a whole FK + collision
query of a finger): a `Kinematics` that is no longer referenced hands its Data back to its
`KinematicModel`, and the next `Kinematics` of that hand takes it instead of allocating one.
That is memory reuse, not shared state: a Data belongs to one live `Kinematics` at a time
and is overwritten by forward kinematics before anything reads it (Jacobians are marked
stale, frame placements are recomputed by every query that reads one).

All poses and Jacobians are in the palm frame.
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Iterable, Mapping

import numpy as np
import pinocchio as pin

from planner.errors import InputError, UnknownNameError


def checked_q(nq: int, q, copy: bool = False) -> np.ndarray:
    """``q`` as a float array of shape (nq,) (a copy when ``copy``), or InputError."""
    q = np.array(q, dtype=float) if copy else np.asarray(q, dtype=float)
    # q @ q is finite only when every entry is (squares cannot cancel); 4x cheaper than isfinite
    if q.shape != (nq,) or not (math.isfinite(q @ q) or np.isfinite(q).all()):
        raise InputError(f"q must be {nq} finite numbers in the order of hand.joint_names, got shape {q.shape}")
    return q


def skew(v) -> np.ndarray:
    """The cross-product matrix of a 3-vector: ``skew(a) @ b == np.cross(a, b)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


_SPARE_DATA = 16  # spare pinocchio.Data kept per hand (see the module docstring)


class KinematicModel:
    """The immutable part of a hand's kinematics, built once per hand.

    Attributes:
        model: the pinocchio model (read only: nothing writes to it, not even ``gravity``).
        T_palm_world: pose of the pinocchio root frame in the palm frame.
        palm_is_root: True when that pose is the identity (the palm is the URDF root).
        frame_ids: frame name -> pinocchio frame id (the first frame of that name).
    """

    __slots__ = ("model", "T_palm_world", "palm_is_root", "frame_ids", "_spare")

    def __init__(self, model, T_palm_world: pin.SE3):
        self.model = model
        self.T_palm_world = pin.SE3(T_palm_world)
        self.palm_is_root = self.T_palm_world.isIdentity(1e-12)
        ids: dict[str, int] = {}
        for i, frame in enumerate(model.frames):
            ids.setdefault(frame.name, i)
        self.frame_ids: Mapping[str, int] = MappingProxyType(ids)
        # pinocchio.Data of dead states, and (model copy, Data) pairs of their gravity
        # queries: each to be taken by one new state
        self._spare: tuple[list, list] = ([], [])

    def _take(self, gravity: bool = False):
        try:
            return self._spare[gravity].pop()  # atomic: no two states can take the same one
        except IndexError:
            if not gravity:
                return pin.Data(self.model)
            model = pin.Model(self.model)
            return model, pin.Data(model)

    def _give(self, item, gravity: bool = False) -> None:
        if len(self._spare[gravity]) < _SPARE_DATA:
            self._spare[gravity].append(item)

    def frame_id(self, name: str) -> int:
        """The pinocchio id of a link or frame, or UnknownNameError."""
        fid = self.frame_ids.get(name)
        if fid is None:
            raise UnknownNameError("link", str(name), sorted(self.frame_ids))
        return fid

    def at(self, q) -> "Kinematics":
        """The hand at ``q`` (nq,)."""
        return Kinematics(self, q)


class Kinematics:
    """The hand at one configuration: one ``pinocchio.Data`` of its own, FK run once.

    ``q`` is a read-only copy. `update` moves the state to another configuration explicitly
    (an iterative solver updates one state instead of allocating one per iteration): every
    query afterwards reads the new ``q``. Joint Jacobians are computed on the first query
    that needs them, once per configuration. Not thread-safe (one state, one caller).

    Attributes:
        kinematic_model: the hand's `KinematicModel`.
        q: (nq,) read-only joint configuration.
        generation: how many times `update` was called (a `planner.collision.HandState`
            reading this state checks it has not moved on).
    """

    __slots__ = ("kinematic_model", "q", "generation", "_data", "_jacobians", "_gravity")

    def __init__(self, kinematic_model: KinematicModel, q):
        self.kinematic_model = kinematic_model
        self._data = kinematic_model._take()  # overwritten by update's FK before any read
        self._gravity = None  # (private model copy, its data), on the first gravity query
        self.generation = -1
        self.update(q)

    def __del__(self):
        data = getattr(self, "_data", None)  # unset when __init__ failed
        if data is not None:
            self.kinematic_model._give(data)
        if getattr(self, "_gravity", None) is not None:
            self.kinematic_model._give(self._gravity, gravity=True)

    def update(self, q) -> "Kinematics":
        """Move this state to ``q`` (nq,): forward kinematics at ``q``; returns self."""
        q = checked_q(self.kinematic_model.model.nq, q, copy=True)
        q.flags.writeable = False
        self.q = q
        pin.forwardKinematics(self.kinematic_model.model, self._data, q)
        self._jacobians = False
        self.generation += 1
        return self

    # ----------------------------------------------------------------- placements
    def joint_placement(self, joint_id: int) -> pin.SE3:
        """oMi: pose of a joint frame in the model's root frame (not the palm frame)."""
        return self._data.oMi[joint_id]

    def root_frame_placement(self, frame_id: int) -> pin.SE3:
        """oMf: pose of a frame in the model's root frame (not the palm frame)."""
        return pin.updateFramePlacement(self.kinematic_model.model, self._data, frame_id)

    def frame_pose(self, frame_id: int) -> np.ndarray:
        """T_palm_frame (4, 4) of a frame."""
        km = self.kinematic_model
        M = self.root_frame_placement(frame_id)
        if not km.palm_is_root:
            M = km.T_palm_world * M
        return M.homogeneous

    def place_geometries(self, geometry_model, geometry_data) -> None:
        """Pose a pinocchio geometry model of this hand (e.g. its visual meshes) at this
        state: ``geometry_data.oMg`` in the model's root frame."""
        pin.updateGeometryPlacements(self.kinematic_model.model, self._data, geometry_model, geometry_data)

    # ------------------------------------------------------------------ Jacobians
    def _joint_jacobians(self):
        if not self._jacobians:
            pin.computeJointJacobians(self.kinematic_model.model, self._data)
            self._jacobians = True
        return self._data

    def frame_jacobian(self, frame_id: int, p_link=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Jacobian of a point of a frame, palm-aligned, linear rows first.

        Args:
            frame_id: pinocchio frame id.
            p_link: (3,) point in the frame (default its origin).
        Returns:
            (J (6, nq): rows 0-2 d(p_palm)/dq, rows 3-5 the frame's angular velocity, palm frame;
            p (3,) the point, palm frame; R (3, 3) the frame's rotation, palm frame).
        """
        km = self.kinematic_model
        data = self._joint_jacobians()
        M = pin.updateFramePlacement(km.model, data, frame_id)
        J = pin.getFrameJacobian(km.model, data, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).copy()
        p = M.translation.copy()
        if p_link is not None:
            r = M.rotation @ np.asarray(p_link, dtype=float)
            p = p + r
            # v_p = v_o + w x r
            J[:3] -= skew(r) @ J[3:]
        R = M.rotation
        if not km.palm_is_root:
            Rp = km.T_palm_world.rotation
            J[:3] = Rp @ J[:3]
            J[3:] = Rp @ J[3:]
            p = km.T_palm_world.act(p)
            R = Rp @ R
        return J, p, R

    def point_jacobians(self, points: Iterable[tuple[int, np.ndarray]], angular: bool = False) -> list[np.ndarray]:
        """Linear Jacobians (3, nq) of points fixed to frames, palm frame; (6, nq) with
        ``angular`` (rows 3-5 the frame's angular velocity).

        Args:
            points: (frame id, (3,) point in the PALM frame) pairs.
        """
        km = self.kinematic_model
        data = self._joint_jacobians()
        out = []
        for fid, p_palm in points:
            M = pin.updateFramePlacement(km.model, data, fid)
            J = pin.getFrameJacobian(km.model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            Jv, Jw, o = J[:3], J[3:], M.translation
            if not km.palm_is_root:
                Rp = km.T_palm_world.rotation
                Jv, Jw, o = Rp @ Jv, Rp @ Jw, km.T_palm_world.act(o)
            Jp = Jv - skew(np.asarray(p_palm, dtype=float) - o) @ Jw  # v_p = v_o + w x (p - o)
            out.append(np.vstack([Jp, Jw]) if angular else Jp)
        return out

    # -------------------------------------------------------------------- gravity
    def gravity_torques(self, g_palm) -> np.ndarray:
        """Joint torques (nq,) that hold the hand's own links still under gravity ``g_palm``
        ((3,) m/s^2, palm frame): pinocchio's generalized gravity of the URDF's masses, on a
        private copy of the model that carries this gravity (the shared model's is never written)."""
        km = self.kinematic_model
        g = np.asarray(g_palm, dtype=float).reshape(3)
        if not km.palm_is_root:
            g = km.T_palm_world.rotation.T @ g
        if self._gravity is None:
            self._gravity = km._take(gravity=True)
        model, data = self._gravity
        model.gravity.linear = g  # the private copy's, set by every call
        return pin.computeGeneralizedGravity(model, data, self.q).copy()
