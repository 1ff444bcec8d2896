"""Replay speed in MuJoCo against pybullet on the same plans, in the same run.

The plans: bundled pairs planned for execution (`PlanOptions.for_execution`, finger paths
planned, verification off: the benchmark replays them itself): the demo's iCub cylinder, the
iCub sphere and the Allegro sphere pairs. Each plan is replayed palm down in each engine,
``--repeats`` times, the engines alternating (a load change on the shared machine hits both
alike); reported per plan and engine: the median wall time, simulated seconds per wall
second, the verdict, and the ratio MuJoCo / pybullet of the medians.

Where the time goes: one more replay per plan and engine with the engine's methods timed
(``step``, ``contacts``, ``closest_points``, everything else: the controller, its grip LP and
the measurements, which are the same code for both engines), so the slower engine's extra
time is seen where it is spent.

Run: ``.venv/bin/python benchmarks/bench_engines.py [--repeats N] [--plans DIR]``
(``--plans``: replay the .json/.yaml plans in DIR instead of planning the three pairs).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict
from pathlib import Path

from planner.sim.engine import engine_installed
from planner.sim.replay import replay_plan

#: (initial, final) bundled grasps planned for the benchmark.
PAIRS = (("icub/cylinder_parallel_extension.yaml", "icub/cylinder_ir2m.yaml"),
         ("icub/sphere_four_finger.yaml", "icub/sphere_ir2m.yaml"),
         ("allegro/sphere_four_finger.yaml", "allegro/sphere_tripod.yaml"))
#: The engine methods timed in the breakdown.
TIMED = ("step", "contacts", "closest_points")


def bundled_plans() -> list[tuple[str, object]]:
    """(name, plan) of each pair of `PAIRS`, planned for execution without verification."""
    from planner.api import plan
    from planner.resources import bundled_grasp

    out = []
    for a, b in PAIRS:
        res = plan(str(bundled_grasp(a)), str(bundled_grasp(b)), execution=True, verify=False, workers=1)
        out.append((Path(a).parent.name + "/" + Path(a).stem.split("_")[0], res.plan))
    return out


def folder_plans(folder: Path) -> list[tuple[str, object]]:
    from planner.plan import read_plan

    return [(p.stem, read_plan(p)) for p in sorted(folder.iterdir()) if p.suffix in (".json", ".yaml", ".yml")]


def timed_replay(plan, engine: str) -> tuple[object, dict[str, float]]:
    """A replay with the engine's `TIMED` methods timed: (report, method -> wall s)."""
    import planner.sim.replay as rp

    spent: dict[str, float] = defaultdict(float)
    real = rp.engine_for

    def wrapped(name, world, **options):
        eng = real(name, world, **options)
        for m in TIMED:
            f = getattr(eng, m)

            def timer(*a, _f=f, _m=m, **k):
                t0 = time.perf_counter()
                try:
                    return _f(*a, **k)
                finally:
                    spent[_m] += time.perf_counter() - t0

            setattr(eng, m, timer)
        return eng

    rp.engine_for = wrapped
    try:
        report = replay_plan(plan, engine=engine)
    finally:
        rp.engine_for = real
    spent["other"] = report.wall_time_s - sum(spent[m] for m in TIMED)
    return report, dict(spent)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--plans", type=Path, default=None, help="replay these plans instead of planning PAIRS")
    args = ap.parse_args(argv)
    engines = [e for e in ("pybullet", "mujoco") if engine_installed(e)]
    if len(engines) < 2:
        raise SystemExit(f"both engines are needed; installed: {', '.join(engines) or 'none'}")
    plans = folder_plans(args.plans) if args.plans else bundled_plans()
    print(f"{'plan':<18} {'engine':<9} {'wall s (median)':>15} {'sim s/wall s':>12} {'sim s':>6}  verdict")
    ratios = []
    for name, plan in plans:
        walls: dict[str, list[float]] = {e: [] for e in engines}
        reports = {}
        for _ in range(args.repeats):
            for e in engines:  # alternating: a change of the machine's load hits both
                r = replay_plan(plan, engine=e)
                walls[e].append(r.wall_time_s)
                reports[e] = r
        med = {e: statistics.median(w) for e, w in walls.items()}
        for e in engines:
            r = reports[e]
            print(f"{name:<18} {e:<9} {med[e]:>15.2f} {r.sim_time_s / med[e]:>12.2f} {r.sim_time_s:>6.2f}  "
                  f"{r.verdict[:70]}")
        ratios.append(med["mujoco"] / med["pybullet"])
        print(f"{name:<18} mujoco / pybullet wall time: {ratios[-1]:.2f}x")
    print(f"median ratio mujoco / pybullet over {len(ratios)} plans: {statistics.median(ratios):.2f}x "
          f"(< 1: MuJoCo faster)")
    print("\nwhere the time goes (one replay each, s; 'other': controller, grip LP, measurements)")
    print(f"{'plan':<18} {'engine':<9} " + " ".join(f"{m:>14}" for m in (*TIMED, "other")) + "  steps  us/step")
    for name, plan in plans:
        for e in engines:
            r, spent = timed_replay(plan, e)
            print(f"{name:<18} {e:<9} " + " ".join(f"{spent[m]:>14.3f}" for m in (*TIMED, "other"))
                  + f"  {r.sim_steps:>5}  {1e6 * spent['step'] / max(1, r.sim_steps):>7.1f}")


if __name__ == "__main__":
    main()
