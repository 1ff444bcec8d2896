"""Benchmark: finger path planning time per gait step (lift + move + land) on the iCub hand.

Cases:
  box, cylinder  the bundled demos grasps/icub/<shape>_parallel_extension.yaml ->
           <shape>_ir2m.yaml (when present): every finger whose contact changes makes one
           gait step from its initial to its final configuration (a finger free in the
           final grasp goes to its open posture), the other fingers held as in the
           initial grasp.
  cyl-sampled  a cylinder lying across the fingers (axis along the palm's y): the index,
           middle and thumb each move between two contacts found by the grasp realizer.
  detour   the index finger flexing around a small box (straight line blocked, OMPL needed).

Each case runs with several seeds; medians are printed in milliseconds.

Run:  .venv/bin/python benchmarks/bench_motion.py [--seeds N] [--planner NAME]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from planner.errors import KinematicsError, MotionError
from planner.grasp import load_grasp
from planner.hand import Hand
from planner.motion import plan_finger_move, plan_gait_step
from planner.objects import make_object
from planner.realization import realize, realize_contact

ROOT = Path(__file__).resolve().parents[1]


def _pose(position, R=None):
    T = np.eye(4)
    T[:3, 3] = position
    if R is not None:
        T[:3, :3] = R
    return T


GRASP_PAIRS = {  # initial -> final grasp files of the bundled demos
    "box": ("box_parallel_extension.yaml", "box_ir2m.yaml"),
    "cylinder": ("cylinder_parallel_extension.yaml", "cylinder_ir2m.yaml"),
}


def grasp_cases(hand, shape):
    """(label, obj, q_a, q_b or None, finger, q_others) from a bundled grasp pair, or []."""
    paths = [ROOT / "grasps/icub" / name for name in GRASP_PAIRS[shape]]
    if not all(p.is_file() for p in paths):
        return []
    initial, final = (realize(load_grasp(p), hand) for p in paths)
    out = []
    for finger, f in hand.fingers.items():
        idx = list(f.q_index)
        if finger not in initial.patches:
            continue
        q_b = final.q if finger in final.patches else None
        if q_b is not None and np.allclose(initial.q[idx], final.q[idx]):
            continue  # same contact: no gait step
        out.append((f"{shape} {finger}", initial.obj, initial.q, q_b, finger, initial.q))
    return out


def sampled_cylinder_cases(hand, n_candidates=40):
    """Two realized contacts per finger on a cylinder lying across the fingers."""
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object z -> palm -y
    obj = make_object("cylinder", (0.02, 0.08), _pose([0.05, -0.005, 0.027], Rx))
    rng = np.random.default_rng(0)
    points, _ = obj.sample_surface(n_candidates, rng)
    q_open = np.asarray(hand.q_open, dtype=float)
    out = []
    for finger in ("index", "middle", "thumb"):
        found = []
        for p in points:
            try:
                q, patch = realize_contact(hand, obj, finger, p, q_open)
            except KinematicsError:
                continue
            if patch is not None:
                found.append(q)
            if len(found) == 2:
                break
        if len(found) == 2:
            out.append((f"cyl-sampled {finger}", obj, found[0], found[1], finger, found[0]))
    return out


def _move_kind(path) -> str:
    """'line' when the move is the straight joint-space segment, else 'ompl'."""
    d = path[-1] - path[0]
    if np.linalg.norm(d) < 1e-12:
        return "line"
    off = (path - path[0]) - np.outer((path - path[0]) @ d / (d @ d), d)
    return "line" if np.max(np.abs(off)) < 1e-9 else "ompl"


def time_gait(hand, case, seed, planner):
    label, obj, q_a, q_b, finger, q_others = case
    t0 = time.perf_counter()
    gait = plan_gait_step(hand, obj, q_a, q_b, finger, q_others=q_others, seed=seed, planner=planner)
    return time.perf_counter() - t0, gait


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--planner", default="rrtconnect")
    args = parser.parse_args()

    hand = Hand.load("icub_right")
    cases = grasp_cases(hand, "box") + grasp_cases(hand, "cylinder") + sampled_cylinder_cases(hand)
    print(f"planner {args.planner}, {args.seeds} seeds; times in ms (median over seeds)")
    print(f"{'case':18s} {'gait step':>10s}  {'move by':8s} waypoints lift/move/land")
    all_times = []
    for case in cases:
        times = []
        gait = None
        for seed in range(args.seeds):
            try:
                dt, gait = time_gait(hand, case, seed, args.planner)
            except MotionError as err:
                print(f"{case[0]:18s} MotionError: {err}")
                break
            times.append(dt)
        if not times:
            continue
        all_times.extend(times)
        sizes = "/".join(str(len(gait[k])) if k in gait else "-" for k in ("lift", "move", "land"))
        print(f"{case[0]:18s} {statistics.median(times) * 1e3:10.1f}  {_move_kind(gait['move']):8s} {sizes}")

    # the OMPL-only part: a move whose straight line is blocked
    obstacle = make_object("box", (0.015, 0.03, 0.015), _pose([0.065, -0.026, 0.035]))
    q0 = np.asarray(hand.q_open, dtype=float)
    q1 = q0.copy()
    q1[list(hand.fingers["index"].q_index)] = [0.0, 1.5, 0.0, 0.0]
    detour = []
    for seed in range(args.seeds):
        t0 = time.perf_counter()
        plan_finger_move(hand, obstacle, q0, q1, "index", seed=seed, planner=args.planner)
        detour.append(time.perf_counter() - t0)
    print(f"{'detour (OMPL)':18s} {statistics.median(detour) * 1e3:10.1f}")
    if all_times:
        print(f"{'all gait steps':18s} {statistics.median(all_times) * 1e3:10.1f}  (n = {len(all_times)})")


if __name__ == "__main__":
    main()
