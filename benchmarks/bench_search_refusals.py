"""What the gait search's own costs come to on the slowest known refusals, before and now.

The refusals of exp10 v2's equal-pose tripod controls (experiments/results/exp10_pairs_v2,
``<pair>_initial.yaml`` -> ``<pair>_same.yaml``) spent their time in the gait search and its
finger paths, not in the verification replays: the iCub box medium (a search of thousands of
states, six sequences replayed), the Allegro box medium (the thumb's path to its final contact
failing in state after state), the Allegro sphere small (six sequences replayed); and exp9 v2's
iCub box 30 g (the verification's case); and the slowest reposing refusals, five of exp10 v2's
pose pairs (``<pair>_initial.yaml`` -> ``<pair>_final.yaml``, ``--pairs`` names ending in
``_pose``: their candidate poses' and intermediate grasps' gait searches). Each is planned with ``--execution``
(`PlanOptions.for_execution`), grasp realization excluded, in two ways, alternated:

* now: the planner as it runs (its default workers: the cores available);
* before, by ``--baseline``:
  - ``one-process`` (default): the gait search without its helper process (both halves of
    every batch of states evaluated in the planner's process, `planner.graph.Evaluator._helper`
    answering None; the verification replays as now);
  - ``per-candidate``: the reposing search (the pose pairs below) as before 2026-12-07, in
    process: each candidate pose's gait search with its own ``--max-rounds`` (not one shared,
    `planner.regrasp.RoundBudget` never running out) and its gaits verified alone before the
    whole plan is replayed (`planner.regrasp.plan_gaits` without ``whole``). (The intermediate
    grasps' reposing moves judged half in a forked copy, and their gaits at the final pose
    searched first, unverified, are not undone.)
  - ``2026-12-06``: three changes of that day undone in process: every grip-force program
    solved from scratch (`planner.lp.solve_highs_rhs` forgets the program it holds), grip
    forces ranked to their last digit (`planner.gait_search.GRIP_RANK_DECIMALS` 15), and no
    memo of finger moves not found even without the other fingers
    (`planner.motion.plan_gait_step` without ``failed_moves``). (The holds_by_bound lever kept
    per contact is not undone.)

One discarded warm-up plan per pair first (imports, the reachable-contact pools); the grip
memo and the program HiGHS holds are cleared before every plan. Prints per pair the median
wall time of each, their ratio and what came out (planned or refused, and whether the two
agree: the ranking may pick another sequence among ties).

Usage: python benchmarks/bench_search_refusals.py [--repeats N] [--pairs NAME,...]
       [--baseline one-process|per-candidate|2026-12-06]
"""

from __future__ import annotations

import argparse
import contextlib
import re
import statistics
import time
from pathlib import Path

import planner.closure as closure
import planner.gait_search as gait_search
import planner.graph as graph
import planner.lp as lp
import planner.motion as motion
import planner.regrasp as regrasp
from planner.errors import NoSequenceError
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.realization import realize

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "experiments" / "results"
#: name -> (initial file, final file)
PAIRS = {
    "icub_right_box_medium_same": ("exp10_pairs_v2/icub_right_box_medium_initial.yaml",
                                   "exp10_pairs_v2/icub_right_box_medium_same.yaml"),
    "allegro_right_box_medium_same": ("exp10_pairs_v2/allegro_right_box_medium_initial.yaml",
                                      "exp10_pairs_v2/allegro_right_box_medium_same.yaml"),
    "allegro_right_sphere_small_same": ("exp10_pairs_v2/allegro_right_sphere_small_initial.yaml",
                                        "exp10_pairs_v2/allegro_right_sphere_small_same.yaml"),
    "icub_right_box_m0.03": ("exp9_pairs_v2/icub_right_box_m0.03_initial.yaml",
                             "exp9_pairs_v2/icub_right_box_m0.03_final.yaml"),
    **{f"allegro_right_{n}_pose": (f"exp10_pairs_v2/allegro_right_{n}_initial.yaml",
                                   f"exp10_pairs_v2/allegro_right_{n}_final.yaml")
       for n in ("box_large", "box_medium", "box_small", "mesh_small", "sphere_small")},
}


@contextlib.contextmanager
def one_process():
    """The gait search without its helper process (see the module docstring)."""
    real = graph.Evaluator._helper
    graph.Evaluator._helper = lambda self: None
    try:
        yield
    finally:
        graph.Evaluator._helper = real


@contextlib.contextmanager
def before_dec06():
    """The planner without the three changes of 2026-12-06 (see the module docstring)."""
    real_rhs, real_gait, decimals = closure.solve_highs_rhs, motion.plan_gait_step, gait_search.GRIP_RANK_DECIMALS

    def cold(*args, **kw):
        lp.forget()
        return real_rhs(*args, **kw)

    def gait(*args, failed_moves=None, **kw):
        return real_gait(*args, **kw)

    closure.solve_highs_rhs, motion.plan_gait_step, gait_search.GRIP_RANK_DECIMALS = cold, gait, 15
    try:
        yield
    finally:
        closure.solve_highs_rhs, motion.plan_gait_step, gait_search.GRIP_RANK_DECIMALS = real_rhs, real_gait, decimals


@contextlib.contextmanager
def per_candidate():
    """The reposing search as before 2026-12-07 (see the module docstring)."""
    real_budget, real_gaits = regrasp.RoundBudget, regrasp.plan_gaits

    def gaits(*args, whole=None, **kw):
        return real_gaits(*args, **kw)

    regrasp.RoundBudget, regrasp.plan_gaits = (lambda rounds: real_budget(10**9)), gaits
    try:
        yield
    finally:
        regrasp.RoundBudget, regrasp.plan_gaits = real_budget, real_gaits


BASELINES = {"one-process": one_process, "per-candidate": per_candidate, "2026-12-06": before_dec06}


def outcome(initial, final, now: bool, baseline: str = "one-process") -> tuple[float, str]:
    """(wall time s, what came out: planned and the order, or the refusal's first clause)."""
    closure._GRIP_MEMO.clear()
    lp.forget()
    t0 = time.perf_counter()
    with contextlib.nullcontext() if now else BASELINES[baseline]():
        try:
            plan = regrasp.plan_regrasp(initial, final, PlanOptions.for_execution()).plan
            what = "planned: " + " ".join(plan.summary.get("order") or ())
        except NoSequenceError as err:
            what = "refused: " + re.split(r"[;:(]", re.sub(r"[0-9.]+ s\b", "s", str(err)))[0].strip()
    return time.perf_counter() - t0, what


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--pairs", default=",".join(PAIRS))
    parser.add_argument("--baseline", choices=sorted(BASELINES), default="one-process")
    args = parser.parse_args()
    print(f"{'pair':<32} {'before s':>9} {'now s':>7} {'ratio':>6}  outcome now (before, if it differs)")
    for name in args.pairs.split(","):
        a, b = PAIRS[name]
        initial, final = realize(load_grasp(RESULTS / a)), realize(load_grasp(RESULTS / b))
        outcome(initial, final, True)  # warm-up
        times: dict[bool, list[float]] = {False: [], True: []}
        seen: dict[bool, list[str]] = {False: [], True: []}
        for i in range(args.repeats):
            for now in ((False, True) if i % 2 == 0 else (True, False)):
                t, what = outcome(initial, final, now, args.baseline)
                times[now].append(t)
                seen[now].append(what)
        old, new = statistics.median(times[False]), statistics.median(times[True])
        differs = "" if set(seen[False]) == set(seen[True]) else f"  (before: {'; '.join(sorted(set(seen[False])))})"
        print(f"{name:<32} {old:>9.2f} {new:>7.2f} {new / old:>5.2f}x  {'; '.join(sorted(set(seen[True])))}{differs}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
