"""The value types every module shares: friction, a contact, and a contact's tangent basis.

These are the nouns that cross module boundaries. Each has one type and one home here;
every other module (closure, grasp realization, the graph, plans, synthesis, replay,
pictures) holds these and nothing else for them:

- `Friction`: the soft-finger Coulomb model of a grasp (thesis eq. 1), validated once.
- `Contact`: one touching link: finger, link, a point and the inward unit normal (the
  direction the finger pushes, DESIGN "The maths"), in a frame the contact names.
- `Patch`: the contacts of one owner (a finger or the palm, `PALM`) as the closure reads
  them, ``(points, normals)``, with the link each point is on; a grasp state's contacts are
  ``{owner: Patch}`` (the "patches" of grasps, graph states, plans and the replay).
- `tangent_basis`: the one right-handed basis ``(t1, t2, n)`` of a contact normal, used by
  the closure's cone edges (thesis eq. 2) and by the grip force problem's pyramids alike.

The object of a grasp is `planner.objects.GraspObject` (its geometry needs coal, so it
lives with the shape code); its file form is `GraspObject.to_data` / `from_data`.
"""

import math
from dataclasses import dataclass
import numpy as np

from planner.errors import InputError

#: Input ranges (README "Hardening / plan integrity"): friction coefficients above
#: `MU_MAX` are not physical and make the cone rim overflow the wrench scale; torsional
#: friction is a length (m) of the order of the contact radius; every cone side multiplies
#: the wrench count (2 edges per point).
MU_MAX = 100.0
GAMMA_MAX_M = 1.0
EDGES_MAX = 256


@dataclass(frozen=True)
class Friction:
    """Soft-finger Coulomb friction (thesis eq. 1).

    Args:
        mu: static friction coefficient (dimensionless, 0 <= mu <= `MU_MAX`).
        gamma: torsional friction, torque per unit normal force (metres, 0 <= gamma <= `GAMMA_MAX_M`).
        edges: number of sides of the friction-cone polygon (3 <= edges <= `EDGES_MAX`; thesis uses 5).
    """

    mu: float
    gamma: float
    edges: int = 5

    def __post_init__(self):
        for name, high in (("mu", MU_MAX), ("gamma", GAMMA_MAX_M)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise InputError(f"friction {name} must be a number, got {type(value).__name__}")
            if not (math.isfinite(value) and 0 <= value <= high):
                raise InputError(f"friction {name} must be in [0, {high:g}], got {float(value):.6g}")
            object.__setattr__(self, name, float(value))
        edges = self.edges
        if isinstance(edges, bool) or not isinstance(edges, (int, np.integer)) or not 3 <= edges <= EDGES_MAX:
            shown = f"{edges:.6g}" if isinstance(edges, (int, float, np.integer)) else type(edges).__name__
            raise InputError(f"friction edges must be an integer in [3, {EDGES_MAX}], got {shown}")
        object.__setattr__(self, "edges", int(edges))

    def to_data(self) -> dict:
        """Plain-data form, the ``friction:`` block of grasp and plan files."""
        return {"mu": self.mu, "gamma": self.gamma, "edges": self.edges}


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis with broadcasting: np.cross's arithmetic (same bits)
    without its per-call overhead (~10 us)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic unit tangents of contact normals, ``(t1, t2, n)`` right-handed.

    ``t1`` is ``a x n`` normalised, with ``a`` the coordinate axis least aligned with ``n``;
    ``t2 = n x t1``. Every friction cone and pyramid of the planner and the controller is
    laid out on this basis (thesis eq. 2).

    Args:
        n: (m, 3) unit normals.
    Returns:
        t1, t2: (m, 3) each.
    """
    helper = np.zeros_like(n)
    helper[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0  # axis least aligned with n
    t1 = cross(helper, n)
    t1 /= np.sqrt(np.einsum("ij,ij->i", t1, t1))[:, None]
    t2 = cross(n, t1)
    return t1, t2


def _readonly(a) -> np.ndarray:
    out = np.array(a, dtype=float).reshape(3)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Contact:
    """One touching link of the hand and where it touches the object.

    Attributes:
        finger: the link's finger, or None for a link of no finger (the palm).
        link: the link's name (URDF), or its pybullet index in the simulator.
        point: (3,) read-only contact point on the object's surface, in ``frame``.
        normal: (3,) read-only unit surface normal INTO the object (the push direction), in ``frame``.
        frame: "obj" (object frame) or "palm" (palm frame, the simulator's world).
        distance_m: link-object signed distance (negative: penetration), or None when not measured.
        touching: False for an approach point (a holding finger near, not on, the surface).
    """

    finger: str | None
    link: str | int
    point: np.ndarray
    normal: np.ndarray
    frame: str = "obj"
    distance_m: float | None = None
    touching: bool = True

    def __post_init__(self):
        object.__setattr__(self, "point", _readonly(self.point))
        object.__setattr__(self, "normal", _readonly(self.normal))
        if self.distance_m is not None:
            object.__setattr__(self, "distance_m", float(self.distance_m))

    @property
    def penetration_m(self) -> float:
        """How deep the link is inside the object, m (0 when not measured or not penetrating)."""
        return 0.0 if self.distance_m is None else max(0.0, -self.distance_m)

    def to_data(self) -> dict:
        """Plain-data form (the ``contacts`` of `regrasp check --json`)."""
        return {"finger": self.finger, "link": self.link, "point": [float(v) for v in self.point],
                "normal": [float(v) for v in self.normal], "penetration_m": float(self.penetration_m)}


#: The owner key of the palm's contacts: a grasp state's patches are ``{owner: Patch}``,
#: the owner a finger or `PALM` (the links of the hand's base, no finger's). The palm is
#: rigid: it pushes only, inside its friction cone, with no joint limit, and is never lifted.
PALM = "palm"


class Patch(tuple):
    """The contact points of one owner (a finger or `PALM`), the closure's unit (thesis
    section IX-D: every point, not their mean). A pair, so ``points, normals = patch`` reads
    it; ``links`` says which link each point is on.

    Attributes:
        points: (n, 3) contact points on the object's surface, object frame, metres.
        normals: (n, 3) unit normals INTO the object at those points, object frame.
        links: None (not known: a schema 2 plan, a hand-made patch) or one link per point
            (its URDF name, or its simulator index), so the "link" contact model
            (`planner.closure.apply_contact_model`) can give every touching link its own
            contact.
    """

    __slots__ = ()
    #: A named pair for `dataclasses.asdict` and `json` (links are left out of those forms).
    _fields = ("points", "normals")

    def __new__(cls, points, normals, links=None):
        self = tuple.__new__(cls, (points, normals, None if links is None else tuple(links)))
        if links is not None and len(self[2]) != len(points):
            raise InputError(f"a patch has {len(points)} points but {len(self[2])} links")
        return self

    def __iter__(self):  # unpacks as (points, normals)
        yield self[0]
        yield self[1]

    def __len__(self) -> int:
        return 2

    def __eq__(self, other):
        return tuple.__eq__(self, other) if isinstance(other, Patch) else tuple(self) == other

    __hash__ = None

    def __reduce__(self):
        return (Patch, (self[0], self[1], self[2]))

    def __repr__(self) -> str:
        return f"Patch(points={self[0]!r}, normals={self[1]!r}, links={self[2]!r})"

    @property
    def points(self) -> np.ndarray:
        return self[0]

    @property
    def normals(self) -> np.ndarray:
        return self[1]

    @property
    def links(self) -> tuple | None:
        return self[2]

    def link_groups(self) -> list[tuple[object, np.ndarray]]:
        """``[(link, point indices)]`` in first-point order; one group (link None) when the
        links are not known."""
        if self[2] is None:
            return [(None, np.arange(len(self[0])))]
        order: dict = {}
        for i, link in enumerate(self[2]):
            order.setdefault(link, []).append(i)
        return [(link, np.asarray(idx)) for link, idx in order.items()]


def holders(patches) -> tuple[str, ...]:
    """The fingers of a state's patches (every owner but `PALM`), in order."""
    return tuple(k for k in patches if k != PALM)
