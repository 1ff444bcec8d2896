"""Plans do not depend on the machine's load: each pair planned on an idle machine and again
with busy-loop processes beside it gives the same bytes.

Every bound of the planner is a count (graph expansions, rounds of intermediate contacts,
OMPL collision checks, verification attempts), not a time, so a loaded machine is slower
but plans the same. This runs ``regrasp plan`` (default mode and ``--execution``) as a user
does, in a fresh process, on:

- the bundled pairs (both hands), and
- a sample of exp8's random pairs (grasps synthesized by `regrasp synth` at a sampled pose,
  seeded; written as grasp files),

first idle, then with ``--busy`` processes spinning (default 2, one per core). It compares the
written plan files byte for byte (or, for a refusal, the exit code and the message with its
seconds removed), and reports the wall times, their medians and the loaded/idle ratio.

Usage: python benchmarks/bench_load.py [--busy N] [--exp8-pairs K] [--exp8-objects N] [--only SUBSTRING]
"""

from __future__ import annotations

import argparse
import hashlib
import multiprocessing as mp
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
G = ROOT / "grasps"
BUNDLED = [
    ("icub box", "icub/box_parallel_extension", "icub/box_ir2m", ()),
    ("icub cylinder", "icub/cylinder_parallel_extension", "icub/cylinder_ir2m", ()),
    ("icub mesh box", "icub/mesh_rounded_box_parallel_extension", "icub/mesh_rounded_box_ir2m", ()),
    ("icub pen", "icub/pen_palmar_pinch", "icub/pen_writing_tripod", ()),
    ("icub sphere", "icub/sphere_four_finger", "icub/sphere_ir2m", ()),
    ("icub ball in palm", "icub/ball_palm_thumb_wrap", "icub/ball_palm_thumb_across", ("--gravity", "palm_up")),
    ("allegro box", "allegro/box_tripod", "allegro/box_four_finger", ()),
    ("allegro cylinder", "allegro/cylinder_tripod", "allegro/cylinder_four_finger", ()),
    ("allegro sphere", "allegro/sphere_four_finger", "allegro/sphere_tripod", ()),
    ("allegro ball in palm", "allegro/ball_palm_thumb_tip", "allegro/ball_palm_thumb_distal", ("--gravity", "palm_up")),
]


def _spin(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10_000))


def exp8_sample(folder: Path, k: int, objects: int, seed: int = 0, only: str | None = None) -> list[tuple[str, Path, Path, tuple]]:
    """``k`` random pairs for each of the first ``objects`` objects of exp8's sweep per hand
    (two grasps per finger set), written as grasp files."""
    sys.path.insert(0, str(ROOT))
    from experiments.exp8_random_pairs import draw_pairs, object_tasks, synth_task

    pairs, per_hand = [], {}
    for task in object_tasks(quick=False, seed=seed):
        per_hand[task["hand"]] = per_hand.get(task["hand"], 0) + 1
        if per_hand[task["hand"]] > objects or (only and only.removeprefix("exp8 ").split()[0] not in task["hand"]):
            continue
        out = synth_task({**task, "per_set": 2})
        for n, (i, j) in enumerate(draw_pairs(out["grasps"], k, seed)):
            paths = []
            for end, g in (("initial", out["grasps"][i]), ("final", out["grasps"][j])):
                p = folder / f"exp8_{task['hand']}_{task['object']}_{n}_{end}.yaml"
                p.write_text(yaml.safe_dump(g["data"], sort_keys=False))
                paths.append(p)
            pairs.append((f"exp8 {task['hand']} {task['object']} {n + 1}", paths[0], paths[1], ()))
    return pairs


def plan_once(a: Path, b: Path, extra: tuple, out: Path) -> tuple[float, int, str, str]:
    """(wall s, exit code, what to compare: the plan's sha256 or the message without times, the
    message)."""
    out.unlink(missing_ok=True)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "planner", "plan", str(a), str(b), *extra, "-o", str(out)],
                          capture_output=True, text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - t0
    if done.returncode == 0:
        return wall, 0, hashlib.sha256(out.read_bytes()).hexdigest()[:16], ""
    text = re.sub(r"\d+(\.\d+)? s\b", "_ s", done.stderr + done.stdout)
    return wall, done.returncode, hashlib.sha256(text.encode()).hexdigest()[:16], text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy", type=int, default=2, help="busy-loop processes during the loaded runs")
    ap.add_argument("--exp8-pairs", type=int, default=2, help="random pairs per exp8 object")
    ap.add_argument("--exp8-objects", type=int, default=2, help="exp8 objects per hand")
    ap.add_argument("--only", default=None, help="only pairs whose label contains this")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-load-") as tmp:
        tmp = Path(tmp)
        pairs = [(label, G / f"{a}.yaml", G / f"{b}.yaml", extra) for label, a, b, extra in BUNDLED]
        pairs += exp8_sample(tmp, args.exp8_pairs, args.exp8_objects, only=args.only) if args.exp8_pairs > 0 else []
        runs = [(f"{label} {mode}", a, b, (*extra, *(("--execution",) if mode == "execution" else ())))
                for label, a, b, extra in pairs for mode in ("default", "execution")
                if not args.only or args.only in label]
        idle = [plan_once(a, b, extra, tmp / f"idle{k}.json") for k, (_, a, b, extra) in enumerate(runs)]
        stop = mp.Event()
        spinners = [mp.Process(target=_spin, args=(stop,), daemon=True) for _ in range(args.busy)]
        for s in spinners:
            s.start()
        try:
            loaded = [plan_once(a, b, extra, tmp / f"load{k}.json") for k, (_, a, b, extra) in enumerate(runs)]
        finally:
            stop.set()
            for s in spinners:
                s.join()
    same = 0
    print(f"{'pair':<44} {'exit':>4} {'idle s':>7} {'loaded s':>8} {'ratio':>6}  same")
    differ = []
    for (label, *_), (ti, ci, hi, mi), (tl, cl, hl, ml) in zip(runs, idle, loaded):
        ok = (ci, hi) == (cl, hl)
        same += ok
        print(f"{label:<44} {ci:>4} {ti:>7.1f} {tl:>8.1f} {tl / ti:>6.2f}  {'yes' if ok else 'NO (' + str(cl) + ')'}")
        if not ok:
            differ.append((label, mi, ml))
    for label, mi, ml in differ:  # where the two refusals part
        k = next((i for i, (x, y) in enumerate(zip(mi, ml)) if x != y), min(len(mi), len(ml)))
        print(f"{label}: idle ...{mi[max(0, k - 120):k + 200]!r}\n{' ' * len(label)}  loaded ...{ml[max(0, k - 120):k + 200]!r}")
    ratios = [r[0] / i[0] for i, r in zip(idle, loaded)]
    print(f"identical idle vs {args.busy} busy processes: {same}/{len(runs)}; median wall idle "
          f"{statistics.median(r[0] for r in idle):.1f} s, loaded {statistics.median(r[0] for r in loaded):.1f} s, "
          f"median ratio {statistics.median(ratios):.2f}x")
    return 0 if same == len(runs) else 1


if __name__ == "__main__":
    sys.exit(main())
