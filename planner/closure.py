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

Tolerances: ``RANK_RTOL`` (rank / affine independence) and ``METRIC_RTOL`` (boundary and
stopping test), both relative to the largest wrench norm.  Algorithm 1 only needs booleans
and stops as soon as the origin is strictly inside ``Q``; ``batch_grasp_closure`` shares
wrench blocks and starts each grasp from the polytope of a grasp with one patch less.

Units: forces in newtons per unit normal force, torques in N m about the object origin; the
metric mixes both (no characteristic length is applied).
"""

from __future__ import annotations

import hashlib
import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgeqp3 as _dgeqp3

from planner.errors import InputError, PlannerError
from planner.model import Friction, cross, tangent_basis

__all__ = [
    "CONTACT_MODELS",
    "GRIP_CONE_SIDES",
    "Closure",
    "Friction",
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
#: it are the ones that hold in the replay.
CONTACT_MODELS = ("patch", "mean")

#: Relative tolerance (times the largest wrench norm) for affine/linear rank decisions.
RANK_RTOL = 1e-9
#: Relative tolerance (times the largest wrench norm) for "on the boundary" and for the
#: support-gap stopping test.  Metric values with ``|metric| <= METRIC_RTOL * max|w|``
#: are reported as exactly 0 (boundary, not force closure).
METRIC_RTOL = 1e-10

#: Largest contact point coordinate, m (object frames are centred on the object).
MAX_COORD_M = 1e3

_SIMPLEX_FACETS = np.array([[j for j in range(7) if j != i] for i in range(7)])  # (7, 6)


@dataclass(frozen=True)
class Closure:
    """Result of a force-closure test.

    Attributes:
        is_force_closure: the origin is strictly inside the convex hull of the wrenches.
        metric: signed metric (module docstring): Ferrari-Canny epsilon when force closure,
            else minus the distance from the origin to the hull (0 on the boundary).
        rank: numerical rank of the wrench matrix (k, 6), tolerance ``RANK_RTOL * max|w|``.
    """

    is_force_closure: bool
    metric: float
    rank: int


# --------------------------------------------------------------------------- wrenches


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


def _numerical_rank(W: np.ndarray, scale: float) -> int:
    if len(W) == 0 or scale == 0.0:
        return 0
    # Singular values of W from its 6x6 Gram matrix would square the conditioning; a thin
    # QR first keeps it: W = Q R, same singular values as R.
    r = np.linalg.qr(W, mode="r") if len(W) > 6 else W
    s = np.linalg.svd(r, compute_uv=False)
    return int((s > RANK_RTOL * scale).sum())


def _initial_simplex(W: np.ndarray, tol: float) -> np.ndarray | None:
    """Indices of 7 affinely independent rows spread far apart, or None (affine dim < 6).

    Greedy farthest-point choice on ``W - W[i0]``: each step takes the row farthest from the
    affine hull of the rows chosen so far.  That is Householder QR with column pivoting of
    ``(W - W[i0]).T`` (one LAPACK ``dgeqp3`` call instead of a Python Gram-Schmidt loop); the
    pivot's distance ``|R[k, k]|`` must exceed ``tol``.
    """
    i0 = int(np.argmax(W[:, 0] + 1e-3 * W[:, 3]))
    qr, jpvt, _, _, info = _dgeqp3((W - W[i0]).T, overwrite_a=1)  # (6, k), Fortran order: no copy
    if info != 0 or not (np.abs(qr.diagonal()) > tol).all():
        return None
    return np.concatenate([[i0], jpvt[:6] - 1]).astype(np.intp)


#: Ridge matching keys: one random integer below 2**43 per wrench row.  A ridge's key is the
#: sum of the keys of its vertices; sums of 5 keys are exact in float64 (so one matmul gives
#: the keys of all ridges of all new facets) and stay below 2**46, which leaves 17 low bits of
#: an int64 sort key for the entry's index (a single in-place ``sort``, no ``argsort``).
_RIDGE_KEYS = np.zeros(0)
_KEY_SENTINEL = float(2**46 - 1)  # above every sum of 5 keys: sorts last
_IDX_BITS = 17
_IDX_MASK = (1 << _IDX_BITS) - 1
_OFF_DIAG = np.ones((6, 6)) - np.eye(6)  # key of the ridge opposite m = sum of the others
_ONES6 = np.ones(6)
_ARANGE = np.arange(1 << 16)


def _ridge_keys(k: int) -> np.ndarray:
    global _RIDGE_KEYS
    if len(_RIDGE_KEYS) < k:
        size = max(k, 2 * len(_RIDGE_KEYS), 4096)
        _RIDGE_KEYS = np.random.default_rng(20240607).integers(1, 2**43, size=size).astype(float)
    return _RIDGE_KEYS


def _arange(size: int) -> np.ndarray:
    global _ARANGE
    if len(_ARANGE) < size:
        _ARANGE = np.arange(max(size, 2 * len(_ARANGE)))
    return _ARANGE


@dataclass
class _Hull:
    """Simplicial facets of an inner polytope around an interior point ``c``: vertex rows
    V (F, 6) of W, planes A (F, 6) with ``A . (x - c) = 1`` on the facet, and neighbour slots
    N (F, 6): ``N[f, m] = 6 g + m'`` where g is the facet across the ridge opposite vertex
    ``V[f, m]`` and ``V[g, m']`` is g's vertex off that ridge (so ``N[g, m'] = 6 f + m``)."""

    c: np.ndarray
    V: np.ndarray
    A: np.ndarray
    N: np.ndarray


def _simplex_hull(W: np.ndarray, simplex: np.ndarray) -> _Hull:
    X = W[simplex]
    c = X.mean(axis=0)
    V = simplex[_SIMPLEX_FACETS]
    # Barycentric coordinates: lambda_{1..6}(x) = (x - x_0) @ G, G = inv(rows x_i - x_0), and
    # lambda_0 = 1 - sum; each is 1/7 at c, so facet i (lambda_i = 0) is -7 g_i . (x - c) = 1.
    G = np.linalg.inv(X[1:] - X[0])
    A = np.empty((7, 6))
    A[0] = 7.0 * G.sum(axis=1)
    A[1:] = -7.0 * G.T
    # Facet i omits simplex vertex i; across its ridge opposite vertex v lies facet v, whose
    # vertex off that ridge is i (at position i - 1 if v < i, else i).
    i = np.arange(7)[:, None]
    N = 6 * _SIMPLEX_FACETS + np.where(_SIMPLEX_FACETS < i, i - 1, i)
    return _Hull(c, V, A, N)


class _Degenerate(Exception):
    """The incremental polytope met a numerically degenerate update."""


def _qhull_fallback(W: np.ndarray, tol: float) -> tuple[int, float]:
    """Slow exact path (qhull facets, never joggled) if the fast expansion degenerates."""
    from scipy.spatial import ConvexHull, QhullError  # imported lazily: rarely needed

    try:
        offsets = ConvexHull(W).equations[:, -1]  # unit normals: distance = -offset
    except QhullError:
        return -1, 0.0
    d = float(-offsets.max())
    if d > tol:
        return 1, d
    return (0, 0.0) if d >= -tol else (-1, d)


def _connected(visible: np.ndarray, N: np.ndarray, f: int) -> np.ndarray:
    """The facets of ``visible`` reachable from facet f through visible neighbours."""
    comp = np.zeros_like(visible)
    comp[f] = True
    front = np.array([f])
    while len(front):
        nb = N.take(front, axis=0).ravel() // 6
        nb = np.unique(nb[visible.take(nb) & ~comp.take(nb)])
        comp[nb] = True
        front = nb
    return comp


def _expand(W: np.ndarray, seed: _Hull, tol: float, decide_only: bool, keep: bool = False):
    """Grow an inner polytope Q = conv(S), S a subset of the rows of W, until the answer is certain.

    Q is a list of simplicial facets: vertex rows ``V[f]`` (indices into W), plane ``a_f``
    (column f of ``AT``) with ``a_f . (x - c) <= 1`` on Q, equality on facet f, ``c`` the
    centroid of the seed simplex (inside Q for ever), and neighbour slots ``N[f]`` (see
    ``_Hull``).  ``D[f]`` is the signed distance from the origin to the facet plane (positive
    on the inner side); dead facet slots have ``a = 0, D = inf``.

    One step (a few dozen numpy calls on arrays of a few hundred facets; the step count, ~25
    for 500 grasp wrenches, is what EPA needs and is not reduced by richer seeds):

    * nearest facet f (most violated while the origin is outside Q), support row j along its
      normal: stop if the support gap ``h(u) - D[f] <= tol``;
    * visible facets: ``a_f . (y_j - c) > 1``; the horizon is read off the neighbour slots of
      the visible facets (a visible facet next to a hidden one);
    * a new facet cones each horizon ridge to ``y_j``.  Its plane lies in the pencil of the
      two planes through the ridge (visible parent p, hidden neighbour q):
      ``a = (1 - lam) a_p + lam a_q`` with ``lam = (a_p.y - 1) / (a_p.y - a_q.y)`` in (0, 1],
      a convex combination, so rounding errors never grow from one generation to the next
      (no 6x6 inverses are stored or updated);
    * neighbours: a new facet's ridge opposite ``j`` is its horizon ridge (the hidden
      neighbour's slot is rewired to it); its other 5 ridges contain ``j`` and are paired
      among the new facets by sorting exact integer ridge keys.  A key seen other than
      exactly twice (inconsistent horizon or key collision) triggers one retry with the
      visible set cut down to the facets connected to f (coplanar inputs can make an isolated
      facet "visible" by rounding), then ``_Degenerate`` (exact qhull fallback).

    Because Q is inside conv(W), the stop is exact: ``epsilon(Q) = d <= epsilon(W) <= h(u)
    <= d + tol``; the reported plane is then solved afresh from its 6 vertices.

    Args:
        W: (k, 6) wrenches.
        seed: a starting inner polytope (vertices are rows of W, ``seed.c`` strictly inside).
        tol: distance tolerance of the stopping tests.
        decide_only: stop as soon as force closure is certain (no exact epsilon).
        keep: also return the final polytope (to warm-start a superset of W).

    Returns:
        (state, value, hull): state 1 = force closure with epsilon ``value`` (with
        ``decide_only`` only a lower bound > tol); 0 = origin on the boundary; -1 = origin
        strictly outside.  ``hull`` is the final polytope if ``keep`` else None.
    """
    keys = _ridge_keys(len(W))
    c = seed.c
    Y = W - c
    YT = Y.T.copy()
    n = len(seed.V)
    cu = max(2048, 2 * n)
    AT = np.zeros((6, cu))  # planes as columns: y @ AT[:, :n] is a fast matvec
    V = np.empty((cu, 6), dtype=np.intp)
    N = np.empty((cu, 6), dtype=np.intp)
    D = np.full(cu, np.inf)
    V[:n] = seed.V
    N[:n] = seed.N
    AT[:, :n] = seed.A.T
    D[:n] = (1.0 + seed.A @ c) / np.sqrt(np.einsum("ij,ij->i", seed.A, seed.A))
    Vf = V.reshape(-1)  # flat views: flat index 6 f + m addresses vertex / neighbour slot m of f
    Nf = N.reshape(-1)
    ar6 = _arange(6 * cu)
    vis_thr = 1.0 + 1e-12
    for _ in range(len(W) + 1):
        f = int(D.argmin())
        d = float(D[f])
        if not d < math.inf:  # NaN from a degenerate update (argmin returns NaN first)
            raise _Degenerate
        if decide_only and d > tol:
            state = 1
            break
        a = AT[:, f]
        s = a @ YT
        j = int(s.argmax())
        gap = (float(s[j]) - 1.0) / math.sqrt(a @ a)  # h(u) - d, u = a / |a|
        if d + gap < -tol:
            state = -1  # a plane strictly separates the origin from every wrench
            break
        if gap <= tol:
            # The facet plane supports conv(W): epsilon(Q) = d <= epsilon(W) <= h <= d + tol.
            state = 1 if d > tol else (0 if d >= -tol else -1)
            if state == 1:
                # Solve the plane afresh from its vertices and keep that distance if the
                # refined plane still supports W.
                a = np.linalg.solve(Y[V[f]], np.ones(6))
                norm = math.sqrt(a @ a)
                d_refined = (1.0 + a @ c) / norm
                if ((Y @ a).max() - 1.0) / norm <= tol and d_refined > tol:
                    d = d_refined
            break
        # Beneath-beyond insertion of row j: drop the facets it sees, cone the horizon to it.
        pa = Y[j] @ AT[:, :n]
        visible = pa > vis_thr
        visible[f] = True
        for attempt in range(2):
            vis = visible.nonzero()[0]
            ns = N.take(vis, axis=0)  # ndarray.take: faster than fancy indexing for gathers
            fi, ci = (~visible.take(ns // 6)).nonzero()  # horizon: visible facet, hidden neighbour
            parent = vis.take(fi)
            nh = len(fi)
            m = n + nh
            if m > cu:
                cu = 2 * m
                AT = np.concatenate([AT, np.zeros((6, cu - AT.shape[1]))], axis=1)
                V = np.concatenate([V, np.empty((cu - len(V), 6), dtype=np.intp)])
                N = np.concatenate([N, np.empty((cu - len(N), 6), dtype=np.intp)])
                D = np.concatenate([D, np.full(cu - len(D), np.inf)])
                Vf = V.reshape(-1)
                Nf = N.reshape(-1)
                ar6 = _arange(6 * cu)
            if 6 * nh > _IDX_MASK:
                raise _Degenerate  # pragma: no cover (over 21845 new facets in one step)
            local = ar6[: 6 * nh : 6] + ci  # flat slot of each new facet's horizon ridge ...
            slot = local + 6 * n  # ... in the new block, and in V / N
            Vn = V[n:m]
            V.take(parent, axis=0, out=Vn)
            Vf[slot] = j  # ridge + new vertex
            # New facets meet pairwise across their ridges through j: same ridge key.
            rk = (keys.take(Vn) @ _OFF_DIAG).ravel()
            rk[local] = _KEY_SENTINEL
            pk = (rk.astype(np.int64) << _IDX_BITS) | ar6[: 6 * nh]
            pk.sort()
            pk = pk[: 5 * nh]
            sk = pk >> _IDX_BITS
            step = sk[1:] - sk[:-1]
            if not (nh & 1 or step[0::2].any() or np.count_nonzero(step) != len(step) // 2):
                break
            # A ridge key not seen exactly twice: the horizon is not a closed manifold.  Seen
            # on coplanar inputs, where a facet far from f is "visible" by rounding only
            # (a . y - 1 ~ 1e-12): keep the visible facets connected to f and retry once.
            if attempt:
                raise _Degenerate
            visible = _connected(visible, N, f)
        hs = ns[fi, ci]  # the hidden neighbour's slot of the horizon ridge
        nbr = hs // 6
        # Planes of the new facets: the pencil through each horizon ridge.
        pp = pa.take(parent)
        lam = (pp - 1.0) / (pp - pa.take(nbr))
        Ap = AT.take(parent, axis=1)
        An = AT.take(nbr, axis=1)
        An -= Ap
        An *= lam
        An += Ap
        AT[:, n:m] = An
        D[n:m] = (c @ An + 1.0) / np.sqrt(_ONES6 @ (An * An))
        # Neighbour links: across the horizon ridge, the hidden facet (both ways) ...
        Nf[slot] = hs
        Nf[hs] = slot
        # ... across the other ridges, the new facet with the same key (sorted next to it).
        e = (pk & _IDX_MASK) + 6 * n
        Nf[e[0::2]] = e[1::2]
        Nf[e[1::2]] = e[0::2]
        # Visible facets die (a = 0 is never visible, D = inf never nearest).
        AT[:, vis] = 0.0
        D[vis] = np.inf
        n = m
    else:
        raise _Degenerate  # pragma: no cover (every step adds a new vertex: cannot happen)
    hull = None
    if keep:
        alive = D[:n] < math.inf
        new_id = np.cumsum(alive) - 1
        Na = N[:n][alive]
        hull = _Hull(c, V[:n][alive], AT[:, :n].T[alive], 6 * new_id[Na // 6] + Na % 6)
    return state, (d if state == 1 else 0.0), hull


def _min_norm_point(W: np.ndarray, tol: float) -> float:
    """Euclidean distance from the origin to conv(W) (Wolfe's min-norm-point algorithm)."""
    sq = np.einsum("ij,ij->i", W, W)
    S = [int(np.argmin(sq))]
    lam = np.array([1.0])
    x = W[S[0]].copy()
    # Optimality gap tolerance relative to the largest row (Wolfe's Z1 * max|p|^2): relative
    # to |x|^2 alone, round-off on a face shared by many rows (e.g. several cone edges at the
    # same distance) keeps the gap above it and the loop cycles, adding and dropping them.
    gap_tol = 1e-12 * float(sq.max())
    for _ in range(50 * len(W) + 100):
        xx = x @ x
        if xx <= tol * tol:
            break  # within tolerance of the origin: the metric is 0 anyway
        s = W @ x
        j = int(np.argmin(s))
        # Wolfe's optimality test: no row is closer to the origin along -x than x itself.
        if xx - s[j] <= gap_tol or j in S:
            break
        S.append(j)
        lam = np.append(lam, 0.0)
        while True:  # minor cycle: affine minimizer of the corral, clipped into the simplex
            P = W[S]
            m = len(S)
            K = np.zeros((m + 1, m + 1))
            K[:m, :m] = P @ P.T
            K[:m, m] = K[m, :m] = 1.0
            rhs = np.zeros(m + 1)
            rhs[m] = 1.0
            alpha = np.linalg.lstsq(K, rhs, rcond=None)[0][:m]
            if (alpha > 1e-12).all():
                lam = alpha
                break
            neg = alpha <= 1e-12
            theta = np.min(lam[neg] / (lam[neg] - alpha[neg]))
            lam = lam + theta * (alpha - lam)
            keep = lam > 1e-12
            keep[np.argmax(lam)] = True
            S = [i for i, k in zip(S, keep) if k]
            lam = lam[keep]
            lam /= lam.sum()
        x_new = lam @ W[S]
        if x_new @ x_new >= xx:
            break  # no progress (round-off): x is the minimum-norm point to working precision
        x = x_new
    return float(math.sqrt(x @ x))


def _closure(W: np.ndarray, decide_only: bool = False, warm: _Hull | None = None, keep: bool = False):
    """Closure of W (k, 6); ``warm``: an inner polytope of a subset of W to start from.

    Returns (Closure, final inner polytope or None).
    """
    k = len(W)
    if k == 0:
        return Closure(False, 0.0, 0), None
    # Force closure is scale invariant and the metric scales with W. Far from unit scale
    # (squares overflow or underflow), solve for W / 2^e, 2^e near the largest |w_i| (exact
    # in floating point), and scale the metric back; contact wrenches (unit normal force)
    # never need it, so their numbers and warm-start polytopes are untouched.
    peak = float(np.abs(W).max())
    if peak == 0.0:
        return Closure(False, 0.0, 0), None
    if not 2.0**-20 <= peak < 2.0**20:
        e = math.frexp(peak)[1] - 1
        closure, _ = _closure(np.ldexp(W, -e), decide_only)
        return Closure(closure.is_force_closure, math.ldexp(closure.metric, e), closure.rank), None
    scale = float(np.sqrt(np.einsum("ij,ij->i", W, W).max()))
    tol = METRIC_RTOL * max(scale, 1e-300)
    if warm is None:
        simplex = _initial_simplex(W, RANK_RTOL * scale) if k >= 7 and scale > 0 else None
        if simplex is not None:
            warm = _simplex_hull(W, simplex)
    # 7 affinely independent rows span R^6; only rank-deficient candidates need the SVD.
    rank = 6 if warm is not None else _numerical_rank(W, scale)
    hull = None
    if warm is not None:
        try:
            with np.errstate(divide="ignore", invalid="ignore"):
                state, value, hull = _expand(W, warm, tol, decide_only, keep)
        except _Degenerate:
            state, value = _qhull_fallback(W, tol)
        if state == 1:
            return Closure(True, float(value), rank), hull
        if state == 0:
            return Closure(False, 0.0, rank), hull
    dist = _min_norm_point(W, tol)
    return Closure(False, 0.0 if dist <= tol else -dist, rank), hull


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
    return _closure(_check_wrenches(W))[0]


def apply_contact_model(patches: Mapping[str, tuple], model: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Patches as the closure test sees them under a contact model (`CONTACT_MODELS`).

    "patch" returns the patches unchanged; "mean" replaces each by one point, the mean of
    its points, with the normalized mean of its normals.

    Raises:
        UnknownNameError: model is not one of `CONTACT_MODELS`.
        InputError: a patch is not a pair of (n, 3) arrays, or its normals cancel out.
    """
    if model not in CONTACT_MODELS:
        from planner.errors import UnknownNameError

        raise UnknownNameError("contact model", model, CONTACT_MODELS)
    out = {}
    for finger, points, normals in _patch_items(patches):
        p, n = _as_arrays(points, normals)
        if model == "mean" and len(p):
            p, n = _unit_normals(p, n)
            m = n.mean(axis=0)
            norm = float(np.linalg.norm(m))
            if not norm > 1e-9:
                raise InputError(f"the normals of finger {finger!r} cancel out: no mean contact normal")
            p, n = p.mean(axis=0, keepdims=True), (m / norm)[None, :]
        out[finger] = (p, n)
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
    return _closure(_finger_wrenches(patches, friction)[0])[0]


def removable_fingers(patches: Mapping[str, tuple], friction: Friction) -> frozenset:
    """Fingers whose whole patch can be lifted with the rest still force closure (Algorithm 1).

    Args:
        patches: finger -> (points (n, 3), normals (n, 3)), object frame, normals inward.
        friction: soft-finger friction model.

    Returns:
        frozenset of finger names; fingers with an empty patch are removable; empty when the
        grasp itself is not force closure.
    """
    full, blocks = _finger_wrenches(patches, friction)
    if not _closure(full, decide_only=True)[0].is_force_closure:
        return frozenset()
    removable = set()
    for finger, block in blocks.items():
        if len(block) == 0:
            removable.add(finger)
            continue
        rest = [b for g, b in blocks.items() if g != finger and len(b)]
        if rest and _closure(np.vstack(rest), decide_only=True)[0].is_force_closure:
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
    w_ext = checked_load(load)
    if cone_sides is not None:
        if isinstance(cone_sides, bool) or not isinstance(cone_sides, (int, np.integer)) or cone_sides < 3:
            raise InputError(f"cone_sides must be an integer >= 3 or None, got {cone_sides!r}")
        if not isinstance(friction, Friction):
            raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
        friction = Friction(friction.mu, friction.gamma, int(cone_sides))
    W, blocks = _finger_wrenches(patches, friction)
    if not w_ext.any():
        return 0.0
    sizes = [len(b) for b in blocks.values() if len(b)]
    if not sizes:
        return math.inf
    k = len(W)
    A_ub = np.zeros((len(sizes), k + 1))
    for i, (a, b) in enumerate(zip(np.cumsum([0] + sizes[:-1]), np.cumsum(sizes))):
        A_ub[i, a:b] = 1.0
    A_ub[:, k] = -1.0
    c = np.zeros(k + 1)
    c[k] = 1.0
    # the program is homogeneous in the load: solve for the unit load and scale t back, so
    # HiGHS's absolute tolerances cannot decide feasibility for a tiny (or huge) load
    scale = float(np.abs(w_ext).max())
    res = solve_highs(c, A_ub, np.zeros(len(sizes)), np.c_[W.T, np.zeros(6)], -w_ext / scale, [(0, None)] * (k + 1),
                      "grip force LP", f" for {len(sizes)} finger(s) and load {np.round(w_ext, 6).tolist()}; "
                                       "the grip force is unknown")
    return math.inf if res is None else float(res.x[k]) * scale


def checked_load(load) -> np.ndarray:
    """A load as a (6,) float wrench ``[f ; tau]``; InputError unless 6 finite numbers."""
    try:
        w = np.asarray(load, dtype=float).reshape(6)
    except (TypeError, ValueError) as err:
        raise InputError(f"load must be 6 numbers [fx fy fz tx ty tz], got {load!r}") from err
    if not np.all(np.isfinite(w)):
        raise InputError(f"load must be finite, got {w.tolist()}")
    return w


def solve_highs(c, A_ub, b_ub, A_eq, b_eq, bounds, what: str, detail: str = "; the answer is unknown"):
    """Solve ``min c x`` s.t. ``A_ub x <= b_ub``, ``A_eq x = b_eq``, ``bounds`` with HiGHS, for
    a program that cannot be unbounded: the result (``.x``) at an optimum, None when it is
    infeasible.

    HiGHS's "unbounded or infeasible" (e.g. from presolve) means infeasible here. When the
    default method ends unsure (e.g. "model_status is Unknown; primal_status is Infeasible",
    seen on a synthesized Allegro grasp) the interior-point method decides.

    Raises:
        PlannerError: any other status (iteration limit, numerical trouble): the answer is
            unknown, which is neither a value nor infeasible.
    """
    res = None
    for method in ("highs", "highs-ipm"):
        res = highs_lp(c, A_ub, b_ub, A_eq, b_eq, bounds, method)
        if res.status == 0:
            return res
        if res.status == 2 or (res.status == 4 and "unbounded or infeasible" in res.message):
            return None
    raise PlannerError(f"{what} failed (HiGHS status {res.status}: {res.message}){detail}")


class _LPResult:
    """What `highs_lp` answers, in ``scipy.optimize.linprog``'s terms: ``status`` (0 optimal,
    1 iteration or time limit, 2 infeasible, 3 unbounded, 4 other), ``message``, ``x``."""

    __slots__ = ("status", "message", "x")

    def __init__(self, status: int, message: str, x):
        self.status, self.message, self.x = status, message, x


_HIGHS = None  # one highspy.Highs per process, reused (a model is passed per solve)


def _highs():
    global _HIGHS
    if _HIGHS is None:
        import highspy

        # its constructor prints a banner on the C stdout: keep a command's output clean
        sys.stdout.flush()
        saved = os.dup(1)
        try:
            with open(os.devnull, "w") as null:
                os.dup2(null.fileno(), 1)
                h = highspy.Highs()
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        h.setOptionValue("output_flag", False)
        # the programs are small and dense: presolve costs more than it saves (0.54 vs
        # 0.91 ms per grip LP, the same optimum)
        h.setOptionValue("presolve", "off")
        # no worker threads: the verification replays fork this process (a fork of a process
        # with live threads can deadlock), and the programs are too small to share
        h.setOptionValue("threads", 1)
        _HIGHS = (highspy, h)
    return _HIGHS


def highs_lp(c, A_ub, b_ub, A_eq, b_eq, bounds, method: str) -> _LPResult:
    """One HiGHS solve through highspy, the HiGHS project's own Python interface (a model
    passed as arrays: scipy's linprog spends 2-3x HiGHS's own time in checking and
    converting its input on the planner's small programs)."""
    highspy, h = _highs()
    inf = highspy.kHighsInf
    c = np.asarray(c, dtype=float)
    n = len(c)
    A_ub = np.zeros((0, n)) if A_ub is None or not len(A_ub) else np.asarray(A_ub, dtype=float)
    b_ub = np.zeros(0) if not len(A_ub) else np.asarray(b_ub, dtype=float)
    A_eq, b_eq = np.asarray(A_eq, dtype=float), np.asarray(b_eq, dtype=float)
    A = np.vstack([A_eq, A_ub])
    cols, rows = np.nonzero(A.T)  # column-major order of the non-zeros
    start = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(np.bincount(cols, minlength=n), out=start[1:])
    lo = np.array([-inf if b[0] is None else b[0] for b in bounds], dtype=float)
    hi = np.array([inf if b[1] is None else b[1] for b in bounds], dtype=float)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, len(A)
    lp.col_cost_, lp.col_lower_, lp.col_upper_ = c, lo, hi
    lp.row_lower_ = np.r_[b_eq, np.full(len(b_ub), -inf)]
    lp.row_upper_ = np.r_[b_eq, b_ub]
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_, lp.a_matrix_.index_, lp.a_matrix_.value_ = start, rows.astype(np.int32), A[rows, cols]
    h.setOptionValue("solver", "ipm" if method == "highs-ipm" else "choose")
    h.passModel(lp)
    h.run()
    st = h.getModelStatus()
    S = highspy.HighsModelStatus
    if st == S.kOptimal:
        return _LPResult(0, "Optimal", np.array(h.getSolution().col_value, dtype=float))
    if st == S.kInfeasible:
        return _LPResult(2, "The problem is infeasible.", None)
    if st == S.kUnboundedOrInfeasible:
        return _LPResult(4, "The problem is unbounded or infeasible.", None)
    if st == S.kUnbounded:
        return _LPResult(3, "The problem is unbounded.", None)
    if st in (S.kIterationLimit, S.kTimeLimit):
        return _LPResult(1, f"model_status is {h.modelStatusToString(st)}", None)
    return _LPResult(4, f"model_status is {h.modelStatusToString(st)}", None)


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
    hulls: dict[tuple, _Hull] = {}  # insertion-ordered: oldest evicted first
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
                warm = _Hull(sub.c, rows[sub.V], sub.A, sub.N)
                break
        res, hull = _closure(W, warm=warm, keep=True)
        if hull is not None:
            hulls[signature] = hull
            if len(hulls) > _WARM_CACHE_SIZE:
                del hulls[next(iter(hulls))]
        done[signature] = out[i] = res
    return out
