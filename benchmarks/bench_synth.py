"""Grasp synthesis yield: grasps found per second for both hands on spheres, boxes and cylinders.

Run: nice .venv/bin/python benchmarks/bench_synth.py [-n 20] [--quick]
Each row synthesizes up to n thumb-index-middle grasps (object pose sampled, seed 0,
at most 60 n attempts) and reports how many were found, the attempts and the time.
"""

from __future__ import annotations

import argparse

from planner.synthesis import synthesize

OBJECTS = [
    ("sphere r15", {"shape": "sphere", "size": [0.015]}),
    ("sphere r25", {"shape": "sphere", "size": [0.025]}),
    ("box 30x40x50", {"shape": "box", "size": [0.03, 0.04, 0.05]}),
    ("box 50x50x50", {"shape": "box", "size": [0.05, 0.05, 0.05]}),
    ("cylinder r15 l80", {"shape": "cylinder", "size": [0.015, 0.08]}),
    ("cylinder r25 l100", {"shape": "cylinder", "size": [0.025, 0.1]}),
]
HANDS = [("icub_right", ["thumb", "index", "middle"]), ("allegro_right", ["thumb", "index", "middle"])]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="first object of each shape only")
    args = ap.parse_args(argv)
    objects = OBJECTS[::2] if args.quick else OBJECTS
    print(f"{'hand':<14} {'object':<18} {'found':>5} {'attempts':>8} {'passed':>6} {'dups':>4} {'time s':>7} {'grasps/s':>8}")
    total_found = total_time = 0.0
    for hand, fingers in HANDS:
        for label, block in objects:
            r = synthesize(hand, block, fingers, args.n, fixed=False, seed=0)
            total_found += len(r.grasps)
            total_time += r.seconds
            print(f"{hand:<14} {label:<18} {len(r.grasps):>5} {r.attempts:>8} {r.candidates_passed:>6} {r.duplicates:>4} "
                  f"{r.seconds:>7.1f} {len(r.grasps) / r.seconds:>8.2f}", flush=True)
    print(f"total: {int(total_found)} grasps in {total_time:.1f} s ({total_found / total_time:.2f} grasps/s)")


if __name__ == "__main__":
    main()
