"""Planning time and graph size: graph search vs the greedy baseline (thesis Algorithm 2).

For the box and cylinder pairs (parallel extension -> IR2M), times the planner without
finger paths (grasp realization excluded, measured separately), repeated, and prints
medians. The greedy baseline runs on the same realized grasps in the same process.
Target from the issue: the box pair planned (without paths) in under 1 s on 2 cores.

Then the box pair in execution mode (`PlanOptions.for_execution`: mean contacts, six
gravity directions, grip ranking: per state six capacity LPs over the joints' torque limits
and six grip LPs; without the verification replays) against the default planner and the
mean-contact planner without gravity, without and with OMPL finger paths, as a ratio to the
default measured in the same run.

Then what verification costs: the box pair planned with ``--execution`` as the command line
does (OMPL paths), verified in pybullet in its six directions (two worker processes) against
``--no-verify``, medians and their ratio in the same run.

Last, the anytime planner on two pairs that need intermediate contacts (Allegro sphere: four
fingers -> a tripod where the middle finger takes the ring finger's place; the box pair in
execution mode): with the defaults (rounds of intermediate contacts, at most `max_rounds`)
and with --time-limit 0 (the pair's own contacts only: no sequence), grasp realization
excluded; the first run also computes the reachable contact pools, which later runs reuse
(cached per hand and object).

Usage: python benchmarks/bench_plan.py [--repeats N]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from planner.errors import NoSequenceError
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.realization import realize
from planner.regrasp import plan_regrasp

ROOT = Path(__file__).resolve().parent.parent
PAIRS = {
    "box": ("grasps/icub/box_parallel_extension.yaml", "grasps/icub/box_ir2m.yaml"),
    "cylinder": ("grasps/icub/cylinder_parallel_extension.yaml", "grasps/icub/cylinder_ir2m.yaml"),
}


def timed_plans(initial, final, options: PlanOptions, repeats: int):
    """Wall times (s) of ``repeats`` plans and the last result (None: no sequence)."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        try:
            result = plan_regrasp(initial, final, options)
        except NoSequenceError:
            result = None
        times.append(time.perf_counter() - t0)
    return times, result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"{'pair':<9} {'strategy':<8} {'realize s':>9} {'plan s (median)':>16} {'nodes':>6} {'edges':>6} {'steps':>5} {'bottleneck':>11}")
    for name, (a, b) in PAIRS.items():
        t0 = time.perf_counter()
        initial, final = realize(load_grasp(ROOT / a)), realize(load_grasp(ROOT / b))
        t_realize = time.perf_counter() - t0
        baseline = None
        for strategy in ("greedy", "graph"):
            times, result = timed_plans(initial, final, PlanOptions(strategy=strategy, motion=False), args.repeats)
            med = statistics.median(times)
            if strategy == "greedy":
                baseline = med
            ratio = f" ({med / baseline:.2f}x greedy)" if strategy == "graph" and baseline else ""
            if result is None:
                print(f"{name:<9} {strategy:<8} {t_realize:>9.3f} {med:>16.4f} {'-':>6} {'-':>6} {'fail':>5} {'-':>11}{ratio}")
                continue
            s = result.plan.summary
            print(
                f"{name:<9} {strategy:<8} {t_realize:>9.3f} {med:>16.4f} {s['graph_nodes']:>6} {s['graph_edges']:>6} "
                f"{s['gait_steps']:>5} {s['bottleneck_metric']:>11.4g}{ratio}"
            )
    print()
    print(f"{'box pair mode':<28} {'paths':<5} {'plan s (median)':>16} {'nodes':>6} {'blocked':>7} {'grip N':>7} {'ratio':>6}")
    initial, final = realize(load_grasp(ROOT / PAIRS["box"][0])), realize(load_grasp(ROOT / PAIRS["box"][1]))
    modes = {
        "default (patch, metric)": lambda **kw: PlanOptions(**kw),
        "mean contacts": lambda **kw: PlanOptions(contact_model="mean", **kw),
        "mean + gravity palm down": lambda **kw: PlanOptions(contact_model="mean", gravity=(0.0, 0.0, 9.81), **kw),
        "execution (set 6, grip)": lambda **kw: PlanOptions.for_execution(verify=False, **kw),
    }
    for motion in (False, True):
        baseline = None
        for name, make in modes.items():
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                result = plan_regrasp(initial, final, make(motion=motion))
                times.append(time.perf_counter() - t0)
            med = statistics.median(times)
            baseline = baseline or med
            s = result.plan.summary
            grip = s["bottleneck_grip_force_n"]
            print(f"{name:<28} {'yes' if motion else 'no':<5} {med:>16.4f} {s['graph_nodes']:>6} {s['blocked_states']:>7} "
                  f"{'-' if grip is None else f'{grip:.3f}':>7} {med / baseline:>5.2f}x")
    print()
    verification(initial, final, max(1, min(args.repeats, 3)))
    print()
    anytime(args.repeats)
    return 0


def verification(initial, final, repeats: int) -> None:
    """The box pair with --execution: verified in pybullet (six directions) vs --no-verify."""
    print(f"{'box --execution':<28} {'plan s (median)':>16} {'replays s':>9} {'sequences':>9} {'ratio':>6}")
    base = None
    for name, verify in (("--no-verify", False), ("verified (6 directions)", True)):
        times, result = timed_plans(initial, final, PlanOptions.for_execution(verify=verify), repeats)
        med = statistics.median(times)
        base = base or med
        check = result.plan.summary.get("verification") if result is not None else None
        replays = f"{result.verify_s:.2f}" if result is not None and result.verify_s is not None else "-"
        print(f"{name:<28} {med:>16.4f} {replays:>9} {check['attempts'] if check else '-':>9} {med / base:>5.2f}x")


def middle_for_ring_pair(directory: Path) -> tuple[Path, Path]:
    """The Allegro sphere pair that needs intermediate contacts (its final grasp written
    into ``directory``): the four-finger grasp -> thumb, index and the middle finger
    abducted to -0.3 rad onto the ring finger's place, ring free."""
    import yaml

    initial = ROOT / "grasps/allegro/sphere_four_finger.yaml"
    data = yaml.safe_load(initial.read_text())
    data["name"] = "allegro_sphere_middle_for_ring"
    data["fingers"]["middle"]["posture"][0] = -0.3
    data["fingers"]["ring"] = "free"
    final = directory / "middle_for_ring.yaml"
    final.write_text(yaml.safe_dump(data, sort_keys=False))
    return initial, final


def anytime(repeats: int) -> None:
    """The anytime planner on the Allegro middle-for-ring pair (it needs intermediate
    contacts) and the box pair in execution mode (within the joints' limits its own contacts
    suffice), with the defaults and with --time-limit 0 (no verification)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        a, b = middle_for_ring_pair(Path(tmp))
        allegro = realize(load_grasp(a)), realize(load_grasp(b))
    box = realize(load_grasp(ROOT / PAIRS["box"][0])), realize(load_grasp(ROOT / PAIRS["box"][1]))
    cases = {"allegro middle-for-ring": (allegro, lambda **kw: PlanOptions(motion=False, **kw)),
             "box --execution": (box, lambda **kw: PlanOptions.for_execution(motion=False, verify=False, **kw))}
    print(f"{'anytime pair':<24} {'mode':<16} {'plan s (median)':>16} {'first s':>7} {'solved':>6} {'rounds':>6} "
          f"{'added':>5} {'steps':>5} {'expanded':>8} {'grip N':>6}")
    for pair, ((initial, final), make) in cases.items():
        for name, kw in (("defaults", {}), ("--time-limit 0", {"time_limit_s": 0.0})):
            times, result = timed_plans(initial, final, make(**kw), repeats)
            med = statistics.median(times)
            if result is None:
                print(f"{pair:<24} {name:<16} {med:>16.4f} {times[0]:>7.3f} {'no':>6}")
                continue
            info, grip = result.plan.summary["search"], result.plan.summary["bottleneck_grip_force_n"]
            print(f"{pair:<24} {name:<16} {med:>16.4f} {times[0]:>7.3f} {'yes':>6} {info['rounds']:>6} "
                  f"{sum(info['intermediate_added'].values()):>5} {result.sequence.gait_steps:>5} "
                  f"{info['expanded_states']:>8} {'-' if grip is None else f'{grip:.3f}':>6}")


if __name__ == "__main__":
    raise SystemExit(main())
