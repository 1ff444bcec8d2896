"""Planning time with and without whole-hand contacts, in the same run.

For every bundled pair (the seven exp7 library pairs of both hands and the two ball-in-palm
pairs), execution-mode planning (`PlanOptions.for_execution`: six gravity directions, grip
ranking, the joints' torque limits; without finger paths and without the verification
replays, which are timed by bench_plan.py and bench_replay.py) is timed in two models on the
same realized grasps:

* fingertips: the model before whole-hand grasps: one mean contact per finger, the palm left
  out (its patch removed from both grasps);
* whole hand: one contact per touching link (the "link" model) and the palm as a contact.

Medians of ``--repeats`` runs and their ratio (whole hand / fingertips) per pair; the
acceptance is that no pair that plans with fingertips takes more than 2x longer. A pair
that plans in one model and not the other says so.

``--refusals`` also times the full ``plan --execution`` (OMPL paths, verified in pybullet in
six directions, two worker processes) of the ball-in-palm pairs planned for the six
directions, which the simulator refuses (README "Whole-hand grasps", limit): the time to a
refusal, against the issue's 30 s.

Usage: python benchmarks/bench_whole_hand.py [--repeats N] [--refusals]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

from planner.errors import NoSequenceError, PlannerError
from planner.grasp import load_grasp
from planner.model import PALM
from planner.options import PlanOptions
from planner.realization import realize
from planner.regrasp import plan_regrasp

ROOT = Path(__file__).resolve().parent.parent
PAIRS = {
    "icub box": ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"),
    "icub cylinder": ("icub/cylinder_parallel_extension.yaml", "icub/cylinder_ir2m.yaml"),
    "icub sphere": ("icub/sphere_four_finger.yaml", "icub/sphere_ir2m.yaml"),
    "icub pen": ("icub/pen_palmar_pinch.yaml", "icub/pen_writing_tripod.yaml"),
    "allegro box": ("allegro/box_four_finger.yaml", "allegro/box_tripod.yaml"),
    "allegro sphere": ("allegro/sphere_four_finger.yaml", "allegro/sphere_tripod.yaml"),
    "allegro cylinder": ("allegro/cylinder_four_finger.yaml", "allegro/cylinder_tripod.yaml"),
    "icub ball in palm": ("icub/ball_palm_thumb_wrap.yaml", "icub/ball_palm_thumb_across.yaml"),
    "allegro ball in palm": ("allegro/ball_palm_thumb_tip.yaml", "allegro/ball_palm_thumb_distal.yaml"),
}
BALL_PAIRS = ("icub ball in palm", "allegro ball in palm")


def without_palm(g):
    """The realized grasp with its palm patch left out (the fingertip model's view)."""
    return replace(g, patches=MappingProxyType({k: v for k, v in g.patches.items() if k != PALM}))


def timed(initial, final, options: PlanOptions, repeats: int):
    """(median wall time s, the last result or the refusal's first clause)."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        try:
            result = plan_regrasp(initial, final, options)
        except (NoSequenceError, PlannerError) as err:
            result = str(err).split(";")[0][:70]
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--refusals", action="store_true", help="also time the verified refusals of the ball pairs")
    args = parser.parse_args()
    grasps = ROOT / "grasps"
    print(f"{'pair':<22} {'palm':<5} {'fingertips s':>12} {'whole hand s':>12} {'ratio':>6}  outcome (fingertips / whole hand)")
    ratios = []
    for name, (a, b) in PAIRS.items():
        ga, gb = realize(load_grasp(grasps / a)), realize(load_grasp(grasps / b))
        palm = PALM in ga.patches
        base = PlanOptions.for_execution(verify=False, motion=False, contact_model="mean")
        t_old, r_old = timed(without_palm(ga), without_palm(gb), base, args.repeats)
        t_new, r_new = timed(ga, gb, PlanOptions.for_execution(verify=False, motion=False), args.repeats)
        words = [f"{r.sequence.gait_steps} steps" if not isinstance(r, str) else f"refused ({r})" for r in (r_old, r_new)]
        ratio = t_new / t_old
        if not isinstance(r_old, str):
            ratios.append(ratio)
        print(f"{name:<22} {'yes' if palm else 'no':<5} {t_old:>12.3f} {t_new:>12.3f} {ratio:>5.2f}x  {words[0]} / {words[1]}")
    if ratios:
        print(f"largest ratio over the pairs the fingertip model plans: {max(ratios):.2f}x "
              f"(median {statistics.median(ratios):.2f}x, {len(ratios)} pairs; acceptance <= 2x)")
    if args.refusals:
        print("\nverified plan --execution (six directions, OMPL paths, 2 workers): time to the answer")
        for name in BALL_PAIRS:
            a, b = PAIRS[name]
            ga, gb = realize(load_grasp(grasps / a)), realize(load_grasp(grasps / b))
            t0 = time.perf_counter()
            try:
                res = plan_regrasp(ga, gb, PlanOptions.for_execution(workers=2))
                out = f"planned, {res.sequence.gait_steps} steps"
            except (NoSequenceError, PlannerError) as err:
                out = f"refused: {str(err)[:90]}"
            print(f"{name:<22} {time.perf_counter() - t0:>7.1f} s  {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
