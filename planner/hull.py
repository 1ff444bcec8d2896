"""The convex hull of a wrench set: force closure and the signed Ferrari-Canny metric.

Thesis section II-A: a wrench set is force closure iff the origin lies strictly inside its
convex hull; the metric is the distance from the origin to the nearest facet (epsilon)
when it is, minus the distance from the origin to the hull when it is not. The algorithm
(an incremental inner polytope, Wolfe's minimum-norm point, the qhull fallback) is
described in `planner.closure`'s module docstring; this module holds it, and
`planner.closure` turns contacts into wrenches for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgeqp3 as _dgeqp3

#: Relative tolerance (times the largest wrench norm) for affine/linear rank decisions.
RANK_RTOL = 1e-9
#: Relative tolerance (times the largest wrench norm) for "on the boundary" and for the
#: support-gap stopping test.  Metric values with ``|metric| <= METRIC_RTOL * max|w|``
#: are reported as exactly 0 (boundary, not force closure).
METRIC_RTOL = 1e-10

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
class Hull:
    """Simplicial facets of an inner polytope around an interior point ``c``: vertex rows
    V (F, 6) of W, planes A (F, 6) with ``A . (x - c) = 1`` on the facet, and neighbour slots
    N (F, 6): ``N[f, m] = 6 g + m'`` where g is the facet across the ridge opposite vertex
    ``V[f, m]`` and ``V[g, m']`` is g's vertex off that ridge (so ``N[g, m'] = 6 f + m``)."""

    c: np.ndarray
    V: np.ndarray
    A: np.ndarray
    N: np.ndarray


def _simplex_hull(W: np.ndarray, simplex: np.ndarray) -> Hull:
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
    return Hull(c, V, A, N)


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


def _expand(W: np.ndarray, seed: Hull, tol: float, decide_only: bool, keep: bool = False):
    """Grow an inner polytope Q = conv(S), S a subset of the rows of W, until the answer is certain.

    Q is a list of simplicial facets: vertex rows ``V[f]`` (indices into W), plane ``a_f``
    (column f of ``AT``) with ``a_f . (x - c) <= 1`` on Q, equality on facet f, ``c`` the
    centroid of the seed simplex (inside Q for ever), and neighbour slots ``N[f]`` (see
    ``Hull``).  ``D[f]`` is the signed distance from the origin to the facet plane (positive
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
        hull = Hull(c, V[:n][alive], AT[:, :n].T[alive], 6 * new_id[Na // 6] + Na % 6)
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


def is_force_closure(W: np.ndarray) -> bool:
    """``wrench_closure(W, decide_only=True)[0].is_force_closure``, the same steps without
    what only the metric needs (the rank, and the distance from the origin to conv(W) of a
    grasp that is not force closure: `_min_norm_point`)."""
    if len(W) == 0:
        return False
    peak = float(np.abs(W).max())
    if peak == 0.0:
        return False
    if not 2.0**-20 <= peak < 2.0**20:
        return is_force_closure(np.ldexp(W, -(math.frexp(peak)[1] - 1)))
    scale = float(np.sqrt(np.einsum("ij,ij->i", W, W).max()))
    tol = METRIC_RTOL * max(scale, 1e-300)
    simplex = _initial_simplex(W, RANK_RTOL * scale) if len(W) >= 7 and scale > 0 else None
    if simplex is None:
        return False  # (wrench_closure: the min-norm point, never force closure)
    try:
        with np.errstate(divide="ignore", invalid="ignore"):
            state = _expand(W, _simplex_hull(W, simplex), tol, True, False)[0]
    except _Degenerate:
        state = _qhull_fallback(W, tol)[0]
    return state == 1


def wrench_closure(W: np.ndarray, decide_only: bool = False, warm: Hull | None = None, keep: bool = False):
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
        closure, _ = wrench_closure(np.ldexp(W, -e), decide_only)
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
