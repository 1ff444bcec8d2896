"""Planning time with and without reposing, in the same run.

1. Pairs that need no reposing (the bundled library pairs of both hands, which share the
   object's pose and plan by finger gaits): execution-mode planning (six gravity directions,
   grip ranking, torque limits; no finger paths, no verification replays) timed with reposing
   allowed (the default) and with ``repose=False`` (the planner before reposing). The issue's
   bound: no more than 1.5x. Medians of ``--repeats`` runs and their ratio per pair.
2. Pairs that do need it: the Allegro pairs with the final grasp's object moved (2 mm / 3 deg
   about the palm normal, a turn the fingers drive): planned with reposing (without it they
   are refused at once, object poses differ), the time and the plan's reposing moves.

Usage: python benchmarks/bench_reposing.py [--repeats N]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from planner.errors import PlannerError
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.realization import realize
from planner.regrasp import plan_regrasp
from planner.resources import bundled_grasp

from bench_whole_hand import BALL_PAIRS, PAIRS  # noqa: E402 - the bundled library pairs, one list

SAME_POSE = {k: v for k, v in PAIRS.items() if k not in BALL_PAIRS}
MOVED = {k: v for k, v in SAME_POSE.items() if k.startswith("allegro")}
MOVE_M, TURN_DEG = 0.002, 3.0


def _grasp(name, T=None):
    spec = load_grasp(bundled_grasp(name))
    if T is not None:
        spec = replace(spec, object=spec.object.with_pose(T))
    return realize(spec).require_placed()


def _time(a, b, opts, repeats):
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        try:
            result = plan_regrasp(a, b, opts)
        except PlannerError as err:
            result = err
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    opts = PlanOptions.for_execution(motion=False, verify=False)
    print(f"1. pairs at one pose, execution mode without paths or replays, median of {args.repeats}")
    print(f"{'pair':<18} {'gaits only s':>12} {'with reposing s':>15} {'ratio':>6}  result")
    ratios = []
    for name, (ia, fb) in SAME_POSE.items():
        a, b = _grasp(ia), _grasp(fb)
        t_off, r_off = _time(a, b, replace(opts, repose=False), args.repeats)
        t_on, r_on = _time(a, b, opts, args.repeats)
        same = (isinstance(r_off, PlannerError) == isinstance(r_on, PlannerError))
        ratios.append(t_on / t_off)
        words = ("refused both" if isinstance(r_on, PlannerError) and isinstance(r_off, PlannerError) else
                 "planned both" if same else "DIFFERENT")
        print(f"{name:<18} {t_off:>12.3f} {t_on:>15.3f} {t_on / t_off:>6.2f}  {words}")
    print(f"ratio median {statistics.median(ratios):.2f}, max {max(ratios):.2f} (bound 1.5)")
    print(f"2. the final grasp's object moved {MOVE_M * 1e3:g} mm and turned {TURN_DEG:g} deg about the palm normal")
    for name, (ia, fb) in MOVED.items():
        a = _grasp(ia)
        T = np.array(load_grasp(bundled_grasp(fb)).object.T_palm_obj, dtype=float)
        T[:3, 3] += MOVE_M * np.array([1.0, 0.0, 0.0])
        T[:3, :3] = Rotation.from_rotvec(math.radians(TURN_DEG) * np.array([0.0, 0.0, 1.0])).as_matrix() @ T[:3, :3]
        try:
            b = _grasp(fb, T)
        except PlannerError as err:
            print(f"{name:<18} final grasp not realized at the moved pose: {str(err)[:100]}")
            continue
        t_on, r_on = _time(a, b, opts, args.repeats)
        if isinstance(r_on, PlannerError):
            print(f"{name:<18} {t_on:>8.3f} s refused: {str(r_on)[:160]}")
        else:
            rep = r_on.plan.summary.get("reposing", {})
            print(f"{name:<18} {t_on:>8.3f} s planned: {rep.get('moves')} reposing move(s), "
                  f"{rep.get('object_path_mm')} mm / {rep.get('object_path_deg')} deg, {len(r_on.plan.steps)} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
