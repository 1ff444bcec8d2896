"""Contact wrenches, force closure and the signed Ferrari-Canny metric.

Thesis section II (eqs. 1-7) and Algorithm 1 (removable fingers).

A soft-finger contact at point ``p`` with inward unit normal ``n`` is represented by its
friction cone sampled on the rim with unit normal force (thesis eq. 2); every rim edge
``f`` appears twice, with torsional torque ``+gamma n`` and ``-gamma n``.  The wrench rows
are ``w = [f ; p x f (+/- gamma n)]``, torques about the object-frame origin.

Force closure holds iff the origin lies strictly inside ``conv(W)`` (thesis section II-A).

Signed metric (``Closure.metric``):

* force closure: the Ferrari-Canny epsilon (L1 / convex-hull version), the Euclidean
  distance from the origin to the nearest facet of ``conv(W)``; equivalently
  ``min_{|u|=1} max_i u . w_i``.
* not force closure: ``-dist(0, conv(W))`` (minus the Euclidean distance from the origin to
  the hull), which is ``0`` when the origin is on the boundary, or inside a hull that does
  not span 6-D.

How it is computed (numpy and one LAPACK call, no convex hull of the whole set):

1. ``_initial_simplex``: greedy farthest-point selection (QR with column pivoting, one LAPACK
   call) picks 7 affinely independent wrenches spread as far as possible.  If none exist
   (affine dimension < 6, tolerance ``RANK_RTOL * max|w_i|``) the set is never force closure.
2. ``_expand``: an incremental inner polytope ``Q = conv(S)``, ``S`` a subset of the rows,
   is kept as a simplicial facet list with neighbour links.  Facets are stored as
   ``a . (x - c) = 1`` around a fixed interior point ``c`` of ``Q`` (no orientation
   bookkeeping).  Each step takes the facet with the smallest signed distance ``d`` to the
   origin (the most violated one while the origin is outside ``Q``; the nearest one, as in
   EPA, once it is inside), queries the support value ``h(u) = max_i u . w_i`` along its unit
   normal ``u`` and either stops (``h(u) - d <= tol``: the facet plane supports ``conv(W)``)
   or adds the support point (beneath-beyond insertion: visible facets die, the horizon is
   read off the neighbour links and each horizon ridge is coned to the new point; the new
   plane is the convex combination of the two planes through the ridge that passes through
   the new point, and new facets are linked to each other by sorting exact ridge keys).
   Because ``Q`` is inside ``conv(W)``, the stop gives the exact answer:
   ``epsilon(Q) = d <= epsilon(W) <= h(u) <= d + tol``; the reported plane is solved afresh
   from its 6 vertices.  A numerically degenerate update (inconsistent horizon) falls back
   to an exact (never joggled) qhull hull of ``W``.
3. Not force closure: ``_min_norm_point`` (Wolfe's algorithm) gives ``dist(0, conv(W))``.

Tolerances (`planner.hull`, where the hull code lives): ``RANK_RTOL`` (rank / affine independence) and ``METRIC_RTOL`` (boundary and
stopping test), both relative to the largest wrench norm.  Algorithm 1 only needs booleans
and stops as soon as the origin is strictly inside ``Q``; ``batch_grasp_closure`` shares
wrench blocks and starts each grasp from the polytope of a grasp with one patch less.

Units: forces in newtons per unit normal force, torques in N m about the object origin; the
metric mixes both (no characteristic length is applied).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence

import numpy as np

from planner.errors import InputError, UnknownNameError
from planner.hull import Closure, Hull, is_force_closure, wrench_closure
from planner.lp import solve_highs_rhs
from planner.model import PALM, Friction, Patch, cross, tangent_basis

__all__ = [
    "CONTACT_MODELS",
    "GRIP_CONE_SIDES",
    "GripContacts",
    "apply_contact_model",
    "batch_grasp_closure",
    "closure_from_wrenches",
    "contact_wrenches",
    "grasp_closure",
    "min_grip_force",
    "removable_fingers",
]

#: How a finger's contact patch enters the closure test. "patch": every point of the
#: patch with its own friction cone (thesis section VII: all contact points of a link).
#: "mean": one contact per finger at the mean point with the mean normal (thesis fig. 13,
#: "mean"); this is what a rigid fingertip gives in a physics engine, so plans made with
#: it are the ones that hold in the replay. "link": one contact per touching link of each
#: owner (finger or palm) at the mean of that link's points, with their mean normal: a
#: finger holding with two phalanges pushes through two contacts, as it does in a physics
#: engine, instead of one point between them (inside the object on a convex one); a patch
#: whose links are not known (schema 2 plans) is one contact, as "mean". Execution mode's.
CONTACT_MODELS = ("patch", "mean", "link")

#: Largest contact point coordinate, m (object frames are centred on the object).
MAX_COORD_M = 1e3




def _as_points_normals(points, normals) -> tuple[np.ndarray, np.ndarray]:
    return _unit_normals(*_as_arrays(points, normals))


def _as_arrays(points, normals) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals as float (m, 3) arrays of the same shape (not yet checked finite)."""
    p, n = _real_array(points, "points"), _real_array(normals, "normals")
    if p.size == 0 and n.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3), got {p.shape}")
    if n.shape != p.shape:
        raise InputError(f"normals must have the shape of points {p.shape}, got {n.shape}")
    return p, n


def _real_array(value, name: str) -> np.ndarray:
    """A float array of real numbers; InputError for complex or non-numeric input (numpy
    would silently drop an imaginary part)."""
    try:
        a = np.asarray(value)
        if a.dtype.kind == "c" or (a.dtype == object and any(isinstance(v, complex) for v in a.ravel())):
            raise InputError(f"{name} must be real numbers, got complex values")
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError) as err:
        if isinstance(err, InputError):
            raise
        raise InputError(f"{name} must be a numeric array: {str(err).splitlines()[0][:80]}") from None


def _unit_normals(p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Check finiteness and non-zero normals of ``_as_arrays`` output; normalize the normals."""
    if not (np.isfinite(p).all() and np.isfinite(n).all()):
        raise InputError("points and normals must be finite (found NaN or inf)")
    if (np.abs(p) > MAX_COORD_M).any():
        raise InputError(f"contact points must lie within {MAX_COORD_M:g} m of the object origin")
    big = np.abs(n).max(axis=1, initial=0.0) > 1e100  # |n|^2 would overflow: scale first (exact: power of 2)
    if big.any():
        n = n.copy()
        n[big] = n[big] * 2.0 ** -400
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    if (length < 1e-12).any():
        bad = int(np.argmax(length < 1e-12))
        raise InputError(f"normal {bad} has zero length")
    return p, n / length[:, None]


def contact_wrenches(points, normals, friction: Friction) -> np.ndarray:
    """Soft-finger contact wrenches on the friction-cone rim (thesis eqs. 2-5).

    Args:
        points: (n, 3) contact points, object frame, metres.
        normals: (n, 3) contact normals pointing INTO the object (normalized here).
        friction: friction model; ``edges`` rim directions per point.

    Returns:
        (2 * edges * n, 6) wrench rows ``[f ; p x f + s gamma n]``, torques about the object
        origin; ordered point-major, then edge ``k`` (angle ``2 pi k / edges``), then torsion
        sign ``s = +1, -1``.  The normal force component is 1.
    """
    if not isinstance(friction, Friction):
        raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
    p, n = _as_points_normals(points, normals)
    return _wrench_rows(p, n, friction)


def _wrench_rows(p: np.ndarray, n: np.ndarray, friction: Friction) -> np.ndarray:
    """``contact_wrenches`` body for checked points and unit normals."""
    e = friction.edges
    if len(p) == 0:
        return np.zeros((0, 6))
    t1, t2 = tangent_basis(n)
    theta = 2.0 * np.pi * np.arange(e) / e
    # f[i, k] = n_i + mu (sin th_k t1_i + cos th_k t2_i)   (thesis eq. 2, f3 = 1)
    f = n[:, None, :] + friction.mu * (
        np.sin(theta)[None, :, None] * t1[:, None, :] + np.cos(theta)[None, :, None] * t2[:, None, :]
    )
    tau = cross(p[:, None, :], f)  # (n, e, 3)
    tors = friction.gamma * n[:, None, None, :] * np.array([1.0, -1.0])[None, None, :, None]
    w = np.empty((len(p), e, 2, 6))
    w[..., :3] = f[:, :, None, :]
    w[..., 3:] = tau[:, :, None, :] + tors
    return w.reshape(-1, 6)


# --------------------------------------------------------------------------- geometry core


def _check_wrenches(W) -> np.ndarray:
    W = _real_array(W, "wrenches")
    if W.ndim != 2 or W.shape[1] != 6:
        raise InputError(f"wrenches must have shape (k, 6), got {W.shape}")
    if not np.isfinite(W).all():
        raise InputError("wrenches must be finite (found NaN or inf)")
    return W


# --------------------------------------------------------------------------- public API


def closure_from_wrenches(W) -> Closure:
    """Force closure and signed Ferrari-Canny metric of a wrench set (thesis section II-A).

    Args:
        W: (k, 6) wrench rows ``[f ; tau]``.

    Returns:
        Closure: ``is_force_closure`` iff the origin is strictly inside conv(W) (sets of rank
        < 6 never are); ``metric`` = epsilon (distance from the origin to the nearest facet
        of conv(W)) when force closure, else ``-dist(0, conv(W))`` (0 on the boundary).
    """
    return wrench_closure(_check_wrenches(W))[0]


def _mean_contact(owner, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One contact at the mean point with the normalized mean normal, (1, 3) each."""
    m = n.mean(axis=0)
    norm = float(np.linalg.norm(m))
    if not norm > 1e-9:
        raise InputError(f"the normals of {owner!r} cancel out: no mean contact normal")
    return p.mean(axis=0, keepdims=True), (m / norm)[None, :]


def apply_contact_model(patches: Mapping[str, tuple], model: str) -> dict[str, Patch]:
    """Patches as the closure test sees them under a contact model (`CONTACT_MODELS`).

    "patch" returns the patches unchanged; "mean" replaces each by one point, the mean of
    its points, with the normalized mean of its normals; "link" does that per touching link
    (`Patch.links`; a patch without links is one contact), keeping the link of each.

    Raises:
        UnknownNameError: model is not one of `CONTACT_MODELS`.
        InputError: a patch is not a pair of (n, 3) arrays, or its normals cancel out.
    """
    if model not in CONTACT_MODELS:
        raise UnknownNameError("contact model", model, CONTACT_MODELS)
    out = {}
    for finger, points, normals in _patch_items(patches):
        links = getattr(patches[finger], "links", None)
        p, n = _as_arrays(points, normals)
        if model == "patch" or not len(p):
            out[finger] = Patch(p, n, links)
            continue
        p, n = _unit_normals(p, n)
        if model == "mean" or links is None:
            mp, mn = _mean_contact(finger, p, n)
            out[finger] = Patch(mp, mn, None if links is None or len(set(links)) > 1 else links[:1])
            continue
        ps, ns, ls = [], [], []
        for link, idx in Patch(p, n, links).link_groups():
            mp, mn = _mean_contact(f"{finger}/{link}", p[idx], n[idx])
            ps.append(mp)
            ns.append(mn)
            ls.append(link)
        out[finger] = Patch(np.vstack(ps), np.vstack(ns), ls)
    return out


def _patch_items(patches) -> list[tuple[str, object, object]]:
    if not isinstance(patches, Mapping):
        raise InputError(f"patches must be a mapping finger -> (points, normals), got {type(patches).__name__}")
    items = []
    for finger, patch in patches.items():
        try:
            points, normals = patch
        except (TypeError, ValueError) as err:
            raise InputError(f"patch of finger {finger!r} must be a pair (points, normals)") from err
        items.append((finger, points, normals))
    return items


class _WrenchCache:
    """Wrench blocks keyed by patch content, so patches shared between grasps are built once."""

    def __init__(self, friction: Friction):
        if not isinstance(friction, Friction):
            raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
        self.friction = friction
        self._by_id: dict[tuple[int, int], tuple[str, np.ndarray]] = {}
        self._by_key: dict[str, np.ndarray] = {}
        self._keep_alive: list[object] = []

    def block(self, finger, points, normals) -> tuple[str, np.ndarray]:
        ident = (id(points), id(normals))
        hit = self._by_id.get(ident)
        if hit is not None:
            return hit
        p = np.ascontiguousarray(_real_array(points, f"patch of finger {finger!r}: points"))
        n = np.ascontiguousarray(_real_array(normals, f"patch of finger {finger!r}: normals"))
        key = hashlib.blake2b(repr((p.shape, n.shape)).encode() + p.tobytes() + n.tobytes(), digest_size=16).hexdigest()
        W = self._by_key.get(key)
        if W is None:
            try:
                W = contact_wrenches(p, n, self.friction)
            except InputError as err:
                raise InputError(f"patch of finger {finger!r}: {err}") from err
            W.setflags(write=False)
            self._by_key[key] = W
        self._keep_alive.append((points, normals))  # ids stay valid while cached
        self._by_id[ident] = (key, W)
        return key, W


def _finger_wrenches(patches, friction: Friction) -> tuple[np.ndarray, dict]:
    """All wrenches of a grasp (k, 6) and finger -> its block (a view), built by one
    vectorized ``contact_wrenches`` pass (a call per patch costs ~60 us of numpy overhead)."""
    if not isinstance(friction, Friction):
        raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
    fingers, ps, ns = [], [np.zeros((0, 3))], [np.zeros((0, 3))]
    for finger, points, normals in _patch_items(patches):
        try:
            p, n = _as_arrays(points, normals)
        except InputError as err:
            raise InputError(f"patch of finger {finger!r}: {err}") from err
        fingers.append(finger)
        ps.append(p)
        ns.append(n)
    try:
        p, n = _unit_normals(np.concatenate(ps), np.concatenate(ns))
    except InputError:
        for finger, p, n in zip(fingers, ps[1:], ns[1:]):  # name the faulty patch
            try:
                _unit_normals(p, n)
            except InputError as err:
                raise InputError(f"patch of finger {finger!r}: {err}") from err
        raise  # pragma: no cover
    W = _wrench_rows(p, n, friction)
    ends = np.cumsum([0] + [2 * friction.edges * len(p) for p in ps[1:]])
    return W, {f: W[ends[i] : ends[i + 1]] for i, f in enumerate(fingers)}


def grasp_closure(patches: Mapping[str, tuple], friction: Friction) -> Closure:
    """Force closure of a grasp using every point of every finger patch (thesis VIII).

    Args:
        patches: finger -> (points (n, 3), normals (n, 3)), object frame, normals inward;
            an empty patch contributes nothing.
        friction: soft-finger friction model.

    Returns:
        Closure of all contact wrenches stacked (see ``closure_from_wrenches``).
    """
    return wrench_closure(_finger_wrenches(patches, friction)[0])[0]


def removable_fingers(patches: Mapping[str, tuple], friction: Friction) -> frozenset:
    """Fingers whose whole patch can be lifted with the rest still force closure (Algorithm 1).

    Args:
        patches: finger -> (points (n, 3), normals (n, 3)), object frame, normals inward.
        friction: soft-finger friction model.

    Returns:
        frozenset of finger names; fingers with an empty patch are removable; empty when the
        grasp itself is not force closure. The palm's patch (`PALM`) holds but is never
        removable.
    """
    full, blocks = _finger_wrenches(patches, friction)
    if not is_force_closure(full):
        return frozenset()
    removable = set()
    for finger, block in blocks.items():
        if finger == PALM:  # the palm is never lifted
            continue
        if len(block) == 0:
            removable.add(finger)
            continue
        rest = [b for g, b in blocks.items() if g != finger and len(b)]
        if rest and is_force_closure(np.vstack(rest)):
            removable.add(finger)
    return frozenset(removable)


#: Sides of the friction-cone polygon the grip LP (`min_grip_force`) uses, whatever
#: ``Friction.edges`` the closure test uses. The polygon is inscribed in the cone, so it
#: keeps at least ``cos(pi / GRIP_CONE_SIDES)`` (0.981 at 16 sides) of the friction
#: coefficient in every tangential direction: the answer lies between the exact (circular
#: cone) answer for ``mu`` and the exact answer for ``mu cos(pi / GRIP_CONE_SIDES)``.
#: A coarse polygon of the closure's own (e.g. 5 edges, 0.81 mu in the worst direction,
#: and a different worst direction for every edge count) made the required force an
#: artefact of the discretization on thin objects.
GRIP_CONE_SIDES = 16


def min_grip_force(patches: Mapping[str, tuple], friction: Friction, load, *,
                   cone_sides: int | None = GRIP_CONE_SIDES) -> float:
    """Smallest per-finger normal force with which the contacts hold an external load.

    The contact wrenches are non-negative combinations ``sum_j lambda_j w_j`` of soft-finger
    rim wrenches (`contact_wrenches`: every row has a unit normal force), so a finger's
    total normal force is the sum of its ``lambda_j``. This solves the linear program

        min t  s.t.  sum_j lambda_j w_j = -load,  lambda >= 0,
                     sum_{j of finger i} lambda_j <= t   for every finger i

    (HiGHS). Force closure says *some* contact forces resist any load; this says how hard
    the fingers must press to resist *this* one (e.g. the object's weight), in newtons.

    Cone linearization: the rim is sampled with ``cone_sides`` directions (default
    `GRIP_CONE_SIDES` = 16), independently of ``friction.edges``, so the answer does not
    depend on the closure's discretization. The polygon is inscribed in the friction cone,
    so the result is never below the exact answer ``t(mu)`` and never above
    ``t(mu cos(pi / cone_sides))`` (exact answers of the circular cone with the friction
    coefficient shown): conservative, and within 2 % of ``mu`` at 16 sides. Example: two
    opposed contacts holding a weight ``W`` along their common tangent need exactly
    ``W / (2 mu)`` each; the polygon gives a value in ``[W / (2 mu), W / (2 mu cos(pi / sides))]``.
    The torsional part (``+/- gamma`` per unit normal force) is exact.

    Args:
        patches: finger -> (points (n, 3), normals (n, 3)), object frame, normals inward.
        friction: soft-finger friction model (``mu``, ``gamma``; ``edges`` is not used
            unless ``cone_sides`` is None).
        load: (6,) external wrench on the object ``[f ; tau]``, object frame, torque about
            the object origin (gravity: ``[m g_obj ; 0]`` when the origin is the centre of mass).
        cone_sides: sides of the inscribed cone polygon (>= 3); None uses ``friction.edges``
            (the closure's own linearization, the behaviour before ``cone_sides`` existed).

    Returns:
        t in newtons (0 for a zero load); ``inf`` when no contact forces balance the load
        (no contacts, or HiGHS proves the program infeasible): "infeasible" is the only
        meaning of ``inf``.

    Raises:
        InputError: bad patches, a load that is not 6 finite numbers, or a bad ``cone_sides``.
        PlannerError: HiGHS stopped without an answer (iteration limit, numerical trouble):
            the grip force is unknown, which is neither a value nor infeasible.
    """
    return GripContacts(patches, friction, cone_sides=cone_sides).force(load)


class GripContacts:
    """`min_grip_force` of one set of contacts under several loads: the contacts' key and
    wrenches are made once (``force(load)`` for each load; the same memo, programs and
    answers as `min_grip_force`, which is ``GripContacts(patches, friction).force(load)``).

    Raises:
        InputError: a bad ``cone_sides`` or friction (at construction); bad patches or load
            (at `force`).
    """

    def __init__(self, patches: Mapping[str, tuple], friction: Friction, *, cone_sides: int | None = GRIP_CONE_SIDES):
        if cone_sides is not None:
            if isinstance(cone_sides, bool) or not isinstance(cone_sides, (int, np.integer)) or cone_sides < 3:
                raise InputError(f"cone_sides must be an integer >= 3 or None, got {cone_sides!r}")
            if not isinstance(friction, Friction):
                raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
            friction = Friction(friction.mu, friction.gamma, int(cone_sides))
        self.patches, self.friction = patches, friction
        self._contacts = _grip_input_key(patches, friction)  # the same patches asked again: no wrenches built
        self._program = None  # (W, spans, (W.shape, W.tobytes(), spans)) once a load needs them

    def _wrenches(self) -> tuple:
        if self._program is None:
            contacts = self._contacts
            if contacts in _GRIP_MEMO:  # the same contacts under another load (another gravity direction)
                W, spans = _GRIP_MEMO[contacts]
            else:
                W, blocks = _finger_wrenches(self.patches, self.friction)
                spans, start = [], 0
                for owner, b in blocks.items():
                    if len(b) and owner != PALM:  # the rigid palm presses as hard as the fingers make it
                        spans.append((start, start + len(b)))
                    start += len(b)
                if contacts is not None and start:
                    W.setflags(write=False)
                    _GRIP_MEMO[contacts] = (W, spans)
            self._program = (W, spans, (W.shape, W.tobytes(), tuple(spans)))
        return self._program

    def force(self, load) -> float:
        """`min_grip_force` of these contacts for ``load``."""
        w_ext = checked_load(load)
        given = None if self._contacts is None else ("given", w_ext.tobytes(), self._contacts)
        if given in _GRIP_MEMO:
            return _GRIP_MEMO[given]
        W, spans, same = self._wrenches()
        if not w_ext.any():
            return 0.0
        if not len(W):
            return math.inf
        # the program is W, the spans and the load: the same program, the same answer (synthesis
        # asks it of a grasp's loads, then execution mode's test of that grasp asks it again)
        key = same + (w_ext.tobytes(),)
        hit = _GRIP_MEMO.get(key)
        if hit is not None:
            return hit
        t = _grip_lp(W, spans, w_ext, same)
        if len(_GRIP_MEMO) >= GRIP_MEMO:
            for stale in list(_GRIP_MEMO)[: GRIP_MEMO // 2]:
                del _GRIP_MEMO[stale]
        _GRIP_MEMO[key] = t
        if given is not None:
            _GRIP_MEMO[given] = t
        return t


def _grip_input_key(patches, friction):
    """A key of `min_grip_force`'s contacts (the patches' arrays, the friction), or None when
    they are not plain (then the wrenches are built and checked every time)."""
    if not isinstance(friction, Friction):
        return None
    try:
        items = tuple((f, a.dtype.str, a.shape, a.astype(float).tobytes(), b.dtype.str, b.shape, b.astype(float).tobytes())
                      for f, a, b in ((f, np.asarray(p), np.asarray(n)) for f, p, n in _patch_items(patches)))
        key = ("contacts", friction.mu, friction.gamma, friction.edges, items)
        hash(key)
    except (InputError, TypeError, ValueError):
        return None
    return key


#: Entries `min_grip_force` remembers: answers and the wrenches of contacts (per process; the
#: oldest half dropped beyond this; a synthesis candidate makes about 13).
GRIP_MEMO = 256
_GRIP_MEMO: dict = {}


def _grip_lp(W: np.ndarray, spans: list, w_ext: np.ndarray, same: tuple | None = None) -> float:
    """`min_grip_force`'s linear program for the wrenches W, finger spans and load; ``same``:
    ``(W.shape, W.tobytes(), tuple(spans))`` when the caller has it (its memo key's start)."""
    k = len(W)

    def program():
        A_ub = np.zeros((len(spans), k + 1))
        for i, (a, b) in enumerate(spans):
            A_ub[i, a:b] = 1.0
        A_ub[:, k] = -1.0
        c = np.zeros(k + 1)
        c[k] = 1.0
        return c, A_ub, np.zeros(len(spans)), np.c_[W.T, np.zeros(6)], [(0, None)] * (k + 1)

    # the program is homogeneous in the load: solve for the unit load and scale t back, so
    # HiGHS's absolute tolerances cannot decide feasibility for a tiny (or huge) load
    scale = float(np.abs(w_ext).max())
    # the same contacts under another load (the next gravity direction) differ in b_eq only:
    # HiGHS goes on from the last optimum (`solve_highs_rhs`)
    same = (W.shape, W.tobytes(), tuple(spans)) if same is None else same
    t = solve_highs_rhs(("grip",) + same, -w_ext / scale, program, "grip force LP",
                        f" for {len(spans)} finger(s) and load {np.round(w_ext, 6).tolist()}; the grip force is unknown")
    # t >= 0 is a bound of the program; an objective from a warm basis can read -4e-13 where it is 0
    # (exp9 v2's Allegro mesh 0.3 kg, palm up: a plan file refused as holding a negative grip)
    return math.inf if t is None else max(t, 0.0) * scale


def checked_load(load) -> np.ndarray:
    """A load as a (6,) float wrench ``[f ; tau]``; InputError unless 6 finite numbers."""
    try:
        w = np.asarray(load, dtype=float).reshape(6)
    except (TypeError, ValueError) as err:
        raise InputError(f"load must be 6 numbers [fx fy fz tx ty tz], got {load!r}") from err
    if not np.all(np.isfinite(w)):
        raise InputError(f"load must be finite, got {w.tolist()}")
    return w


#: Inner polytopes kept by ``batch_grasp_closure`` for warm starts (each holds ~1-3k facets).
_WARM_CACHE_SIZE = 32


def batch_grasp_closure(list_of_patches: Sequence[Mapping[str, tuple]], friction: Friction) -> list[Closure]:
    """Closure of many grasps in one call, sharing work between them.

    * Wrench blocks are built once per distinct patch (by identity, then by content).
    * Grasps with the same multiset of patches are evaluated once.
    * Grasps are evaluated by increasing number of patches, and a grasp one patch larger
      than an evaluated grasp starts from that grasp's final inner polytope (its vertices
      are wrenches of the larger grasp too), instead of a fresh simplex.

    Args:
        list_of_patches: grasps, each finger -> (points (n, 3), normals (n, 3)).
        friction: soft-finger friction model shared by all grasps.

    Returns:
        One Closure per grasp, in the input order.
    """
    cache = _WrenchCache(friction)
    grasps = []
    for patches in list_of_patches:
        keyed = [cache.block(f, p, n) for f, p, n in _patch_items(patches)]
        grasps.append(sorted(((k, b) for k, b in keyed if len(b)), key=lambda kb: kb[0]))
    done: dict[tuple, Closure] = {}
    hulls: dict[tuple, Hull] = {}  # insertion-ordered: oldest evicted first
    out: list[Closure | None] = [None] * len(grasps)
    for i in sorted(range(len(grasps)), key=lambda i: len(grasps[i])):
        items = grasps[i]
        signature = tuple(k for k, _ in items)
        if signature in done:
            out[i] = done[signature]
            continue
        blocks = [b for _, b in items]
        W = np.vstack(blocks) if blocks else np.zeros((0, 6))
        warm = None
        for pos in range(len(signature)):
            sub = hulls.get(signature[:pos] + signature[pos + 1 :])
            if sub is not None:  # rows of the sub-grasp inside W: every block but `pos`
                starts = np.cumsum([0] + [len(b) for b in blocks])
                rows = np.concatenate(
                    [np.arange(starts[q], starts[q + 1]) for q in range(len(blocks)) if q != pos]
                )
                warm = Hull(sub.c, rows[sub.V], sub.A, sub.N)
                break
        res, hull = wrench_closure(W, warm=warm, keep=True)
        if hull is not None:
            hulls[signature] = hull
            if len(hulls) > _WARM_CACHE_SIZE:
                del hulls[next(iter(hulls))]
        done[signature] = out[i] = res
    return out
