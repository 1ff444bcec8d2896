"""Grasp synthesis rate: execution-ready grasps per second, today's synth against the new one, in one run.

Issue 36 item 3. For each bundled hand, a 30 mm-radius ball (exp8's "sphere r30", 50 g) and
grasps synthesized execution-ready (exp8's `execution_ready`: execution mode's 6 gravity
directions, its force budget, contact model and friction reserve, the replay's palm gap):

- ``sampled``: the default tripod, the object pose sampled, ``-n`` grasps (seed 0);
- ``own pose``: every finger, the pose fixed to the pose of an every-finger grasp synth made
  itself (computed once, the same for both), 6 grasps, at most ``--fixed-attempts`` attempts.

A grasp counts as execution-ready when `planner.realization.execution_verdict` accepts it
(``plan --execution``'s own test). The baseline is the synthesis of commit ``--baseline``
(planner/synthesis.py and planner/synth_sample.py as they were there; every other module is
today's), run in its own process like the new one; its time includes the verdicts it does
not compute itself. ``--baseline`` may be given more than once (e.g. the synthesis before
issue 36 item 3 and the one before its rate work): a row per commit. Rows alternate baseline / new ``--repeat`` times (the machine's load
varies): the summary gives medians and ratios, by wall time and by CPU time (the worker
processes' included: what two cores can do is twice the grasps per CPU second).

The machine's load (/proc/loadavg, 1 min) is printed with every row: CPU seconds under load
are dearer than on idle cores (shared caches), so compare rows of one run only.

Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_synth.py [-n 20] [--repeat 3] [--quick] [--profile]
     [--why] [--baseline REV ...]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The synthesis of issue 36's report (before its item 3).
BASELINE_REV = "fb8d60f"
BALL = {"shape": "sphere", "size": [0.03], "mass_kg": 0.05}
HANDS = ("icub_right", "allegro_right")
TRIPOD = ["thumb", "index", "middle"]


def _load_baseline(rev: str) -> None:
    """Put commit ``rev``'s planner.synth_sample and planner.synthesis in sys.modules."""
    import planner  # noqa: F401 - the package the old modules live in

    for name in ("planner.synth_sample", "planner.synthesis"):
        path = name.replace(".", "/") + ".py"
        src = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{path}"], check=True, capture_output=True,
                             text=True).stdout
        mod = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader=None))
        mod.__file__ = f"{rev}:{path}"
        sys.modules[name] = mod
        exec(compile(src, mod.__file__, "exec"), mod.__dict__)  # noqa: S102 - the repository's own history


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _load() -> float:
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def _child(impl: str, rev: str, cases: list, workers: int) -> list:
    """Run the cases with one implementation; rows of plain data."""
    if impl == "baseline":
        _load_baseline(rev)
    from experiments.exp8_random_pairs import execution_ready
    from planner.realization import execution_verdict
    from planner.synthesis import synthesize

    rows = []
    for c in cases:
        kw = dict(execution_ready(c["hand"]))
        if impl == "new":
            kw["workers"] = workers
        t0, c0 = time.perf_counter(), _cpu()
        r = synthesize(c["hand"], dict(c["block"]), c["fingers"], c["n"], fixed=c["fixed"], seed=c["seed"],
                       max_attempts=c["max_attempts"], **kw)
        if impl == "baseline":  # the verdicts the new synthesis computes as it goes
            ready = sum(execution_verdict(g.grasp).ok for g in r.grasps)
        else:
            ready = sum(g.execution_ready for g in r.grasps)
        rows.append({**{k: c[k] for k in ("hand", "case")}, "impl": impl if impl == "new" else rev,
                     "workers": workers if impl == "new" else 1, "load": _load(),
                     "found": len(r.grasps), "ready": ready, "attempts": r.attempts,
                     "wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0, "rejected": r.rejected})
    return rows


def _run_child(impl: str, rev: str, cases: list, workers: int) -> list:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, __file__, "--child", impl, "--baseline", rev, "--workers", str(workers)],
                         input=json.dumps(cases), capture_output=True, text=True, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def own_poses(hands) -> dict:
    """Per hand: the object block at the pose of an every-finger grasp synth made itself (seed 0)."""
    from planner.grasp import load_hand
    from planner.synthesis import synthesize

    poses = {}
    for hand in hands:
        fingers = list(load_hand(hand).fingers)
        r = synthesize(hand, dict(BALL), fingers, 1, fixed=False, seed=0, max_attempts=400)
        if r.grasps:
            o = r.grasps[0].data["object"]
            poses[hand] = (fingers, dict(BALL, position=o["position"], quat_xyzw=o["quat_xyzw"]))
    return poses


def profile(case: dict) -> None:
    """Where the time of the new synthesis goes (cProfile, cumulative seconds per stage)."""
    import cProfile
    import pstats

    from experiments.exp8_random_pairs import execution_ready
    from planner.synthesis import synthesize

    pr = cProfile.Profile()
    pr.enable()
    r = synthesize(case["hand"], dict(case["block"]), case["fingers"], case["n"], fixed=case["fixed"],
                   seed=case["seed"], max_attempts=case["max_attempts"], **execution_ready(case["hand"]))
    pr.disable()
    st = pstats.Stats(pr).stats
    total = sum(v[2] for v in st.values())  # tottime sum
    stages = {"sample (pre-shapes, pose)": ("sample_candidate",), "close (closes_onto)": ("closes_onto",),
              "check (realize)": ("realize",), "load held (_hold_grip)": ("_hold_grip", "grasp_hold"),
              "back-off (retreat_blocked)": ("retreat_blocked",),
              "execution verdict": ("execution_refusal", "execution_verdict")}
    print(f"profile {case['hand']} {case['case']}: {len(r.grasps)} grasps, {r.attempts} attempts, "
          f"{total:.2f} s profiled")
    for label, fns in stages.items():
        cum = sum(v[3] for k, v in st.items() if k[2] in fns)
        print(f"  {label:<28} {cum:6.2f} s  {100 * cum / total:5.1f} %")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=20, help="grasps per sampled-pose row (default 20)")
    ap.add_argument("--repeat", type=int, default=3, help="baseline/new alternations (default 3)")
    ap.add_argument("--fixed-attempts", type=int, default=120, help="attempts at most at the own pose (default 120)")
    ap.add_argument("--baseline", action="append", help=f"commit of a synthesis to compare (default {BASELINE_REV}; "
                    "repeat for several)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes of the new synthesis's second row")
    ap.add_argument("--quick", action="store_true", help="one repeat, sampled pose only")
    ap.add_argument("--profile", action="store_true", help="also profile the new synthesis per hand")
    ap.add_argument("--why", action="store_true", help="also print each row's rejections (candidates dropped, by reason)")
    ap.add_argument("--child", choices=("baseline", "new"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    revs = args.baseline or [BASELINE_REV]
    if args.child:
        print(json.dumps(_child(args.child, revs[0], json.loads(sys.stdin.read()), args.workers)))
        return
    cases = [{"hand": h, "case": "sampled tripod", "block": BALL, "fingers": TRIPOD, "n": args.n, "fixed": False,
              "seed": 0, "max_attempts": 60 * args.n} for h in HANDS]
    if not args.quick:
        for h, (fingers, block) in own_poses(HANDS).items():
            cases.append({"hand": h, "case": f"own pose {len(fingers)}f", "block": block, "fingers": fingers, "n": 6,
                          "fixed": True, "seed": 1, "max_attempts": args.fixed_attempts})
    rows = []
    print(f"{'hand':<14} {'case':<16} {'impl':<8} {'w':>1} {'found':>5} {'ready':>5} {'att':>4} {'att/g':>5} "
          f"{'wall s':>6} {'cpu s':>6} {'ready/s':>7} {'ready/cpu-s':>11} {'load':>5}", flush=True)
    impls = [(rev, 1) for rev in revs] + [("new", 1), ("new", args.workers)]
    for _ in range(1 if args.quick else args.repeat):
        for impl, w in impls:
            for r in _run_child("new" if impl == "new" else "baseline", impl, cases, w):
                rows.append(r)
                print(f"{r['hand']:<14} {r['case']:<16} {r['impl']:<8} {r['workers']:>1} {r['found']:>5} {r['ready']:>5} "
                      f"{r['attempts']:>4} {r['attempts'] / max(r['ready'], 1):>5.1f} {r['wall_s']:>6.2f} "
                      f"{r['cpu_s']:>6.2f} {r['ready'] / r['wall_s']:>7.2f} {r['ready'] / r['cpu_s']:>11.2f} "
                      f"{r['load']:>5.2f}", flush=True)
                if args.why:
                    print("    rejected: " + ", ".join(f"{why} {k}" for why, k in sorted(
                        r["rejected"].items(), key=lambda kv: (-kv[1], kv[0]))), flush=True)
    print("\nmedians (ready grasps per second; ratio to the baseline):")
    for c in cases:
        base = None
        for impl, w in impls:
            sel = [r for r in rows if (r["hand"], r["case"], r["impl"], r["workers"]) == (c["hand"], c["case"], impl, w)]
            wall = statistics.median(r["ready"] / r["wall_s"] for r in sel)
            cpu = statistics.median(r["ready"] / r["cpu_s"] for r in sel)
            att = statistics.median(r["attempts"] / max(r["ready"], 1) for r in sel)
            base = base or (wall, cpu)
            print(f"  {c['hand']:<14} {c['case']:<16} {impl:<8} w{w}: {wall:6.2f}/s wall ({wall / max(base[0], 1e-9):4.1f}x), "
                  f"{cpu:6.2f}/cpu-s ({cpu / max(base[1], 1e-9):4.1f}x; two idle cores: {2 * cpu:6.2f}/s), "
                  f"{att:5.1f} attempts per ready grasp, load {statistics.median(r['load'] for r in sel):.1f}")
    if args.profile:
        for c in cases:
            profile(c)


if __name__ == "__main__":
    main()
