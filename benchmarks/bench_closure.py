"""Benchmark planner.closure against a scipy ConvexHull baseline, checking the answers agree.

Run: ``python benchmarks/bench_closure.py [--quick]``.  For 2-5 fingers x {1, 5, 10, 20}
points per finger x {4, 5, 8} cone edges it prints the median time of
``closure_from_wrenches`` (boolean + exact epsilon) next to the baseline (qhull facets for
force closure; an NNLS min-norm distance when not), their ratio, and it exits non-zero if a
boolean disagrees or a metric differs by more than 1e-6 relative.  It also times Algorithm 1
(``removable_fingers``) and ``batch_grasp_closure`` per grasp.
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import sys
import time

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import ConvexHull, QhullError

from planner.closure import (
    Friction,
    batch_grasp_closure,
    closure_from_wrenches,
    contact_wrenches,
    grasp_closure,
    removable_fingers,
)

RTOL = 1e-6
ATOL = 1e-9  # the NNLS baseline distance is only good to ~1e-12


def random_grasp(rng, n_fingers, n_points, radius=0.03, spread=0.004, tilt=0.1):
    """Finger patches on a sphere-like object, normals roughly inward (object frame, metres)."""
    patches = {}
    for i in range(n_fingers):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        points = radius * d + spread * rng.normal(size=(n_points, 3))
        normals = -d + tilt * rng.normal(size=(n_points, 3))
        patches[f"f{i}"] = (points, normals)
    return patches


def baseline(W):
    """(is_force_closure, metric) from qhull facets, or minus the NNLS distance outside."""
    try:
        offsets = ConvexHull(W).equations[:, -1]
        if offsets.max() < -1e-12:
            return True, float(-offsets.max())
    except QhullError:
        pass
    big = 1e4
    A = np.vstack([W.T, big * np.ones(len(W))])
    lam, _ = nnls(A, np.r_[np.zeros(6), big], maxiter=20 * len(W))
    return False, -float(np.linalg.norm(W.T @ lam))


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def agree(mine, ref):
    return mine.is_force_closure == ref[0] and abs(mine.metric - ref[1]) <= RTOL * abs(ref[1]) + ATOL


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer cases and repeats")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    fingers = (2, 3, 4, 5)
    points = (1, 5, 10) if args.quick else (1, 5, 10, 20)
    edges_list = (5,) if args.quick else (4, 5, 8)
    n_grasps = 3 if args.quick else 4
    failures = 0
    print(f"{'fingers':>7} {'points':>6} {'edges':>5} {'wrenches':>8} {'FC':>3} "
          f"{'mine ms':>9} {'qhull ms':>9} {'ratio':>7}  agree")
    for nf, npts, edges in itertools.product(fingers, points, edges_list):
        fr = Friction(0.5, 0.005, edges)
        Ws = [np.vstack([contact_wrenches(p, n, fr) for p, n in random_grasp(rng, nf, npts).values()])
              for _ in range(n_grasps)]
        k = len(Ws[0])
        big = k > 400
        mine_t, base_t, ok, n_fc = [], [], True, 0
        for i, W in enumerate(Ws):
            mine = closure_from_wrenches(W)
            mine_t.append(median_time(lambda: closure_from_wrenches(W), 5 if args.quick else 15))
            if big and i >= (1 if k > 900 else 2):
                continue  # the baseline is slow there: compare fewer grasps
            t0 = time.perf_counter()
            ref = baseline(W)
            base_t.append(time.perf_counter() - t0)
            n_fc += ref[0]
            if not agree(mine, ref):
                ok = False
                print(f"  DISAGREE grasp {i}: mine {mine} baseline {ref}")
        failures += not ok
        m, b = statistics.median(mine_t), statistics.median(base_t)
        print(f"{nf:>7} {npts:>6} {edges:>5} {k:>8} {n_fc:>1}/{len(base_t)} "
              f"{1e3 * m:>9.3f} {1e3 * b:>9.2f} {b / m:>7.0f}x  {'yes' if ok else 'NO'}")

    # Headline case and Algorithm 1: 5 fingers x 10 points x 5 edges.
    fr = Friction(0.5, 0.005, 5)
    grasps = [random_grasp(rng, 5, 10) for _ in range(10 if args.quick else 30)]
    single = [median_time(lambda g=g: grasp_closure(g, fr), 5) for g in grasps]
    stacked = [np.vstack([contact_wrenches(p, n, fr) for p, n in g.values()]) for g in grasps]
    raw = [median_time(lambda W=W: closure_from_wrenches(W), 5) for W in stacked]
    alg1 = [median_time(lambda g=g: removable_fingers(g, fr), 5) for g in grasps]
    n_fc = sum(grasp_closure(g, fr).is_force_closure for g in grasps)
    print(f"\n5x10x5 ({n_fc}/{len(grasps)} force closure): closure_from_wrenches median "
          f"{1e3 * statistics.median(raw):.3f} ms, grasp_closure median {1e3 * statistics.median(single):.3f} ms, "
          f"removable_fingers (Algorithm 1) median {1e3 * statistics.median(alg1):.3f} ms")

    # Batch: every subset of >= 2 fingers of a 5-finger grasp, as the graph planner evaluates nodes.
    batch_grasps = []
    for g in grasps[:5]:
        names = list(g)
        for r in range(2, 6):
            batch_grasps += [{f: g[f] for f in combo} for combo in itertools.combinations(names, r)]
    t0 = time.perf_counter()
    batch = batch_grasp_closure(batch_grasps, fr)
    t_batch = time.perf_counter() - t0
    t0 = time.perf_counter()
    loop = [grasp_closure(g, fr) for g in batch_grasps]
    t_loop = time.perf_counter() - t0
    if any(a.is_force_closure != b.is_force_closure or abs(a.metric - b.metric) > 1e-9 * abs(b.metric) + 1e-14
           for a, b in zip(batch, loop)):
        failures += 1
        print("  DISAGREE: batch_grasp_closure differs from grasp_closure")
    print(f"batch of {len(batch_grasps)} grasps: {1e3 * t_batch / len(batch_grasps):.3f} ms per grasp "
          f"(loop of grasp_closure: {1e3 * t_loop / len(batch_grasps):.3f} ms per grasp)")
    print("\nall answers agree" if not failures else f"\n{failures} case(s) DISAGREE")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
