"""Median times of the hand queries the planner makes most often (iCub right hand).

Run: .venv/bin/python benchmarks/bench_hand.py
"""

from __future__ import annotations

import time

import numpy as np

from planner.contacts import collisions, contact_patches
from planner.hand import Hand
from planner.objects import make_object


def median_time_s(fn, args_list, repeat=1):
    times = []
    for args in args_list:
        t0 = time.perf_counter()
        for _ in range(repeat):
            fn(*args)
        times.append((time.perf_counter() - t0) / repeat)
    return float(np.median(times))


def main():
    hand = Hand.load("icub_right")
    rng = np.random.default_rng(0)
    T = np.eye(4)
    T[:3, 3] = [0.04, -0.015, 0.045]
    obj = make_object("box", (0.024, 0.05, 0.05), T)
    f = hand.fingers["index"]
    idx = list(f.q_index)

    qs = []
    for _ in range(300):
        q = hand.q_open.copy()
        q[idx] = rng.uniform(hand.lower[idx], hand.upper[idx])
        qs.append(q)

    def fk_and_object_check(q):
        hand.state(q).link_pose(f.tip_frame)
        return collisions(hand, q, obj, fingers=["index"])

    t_fk_col = median_time_s(fk_and_object_check, [(q,) for q in qs])
    t_all_col = median_time_s(lambda q: collisions(hand, q, obj), [(q,) for q in qs])
    t_patch = median_time_s(lambda q: contact_patches(hand, q, obj), [(q,) for q in qs[:100]])

    targets = []
    for q in qs[:200]:
        T_pad = hand.state(q).link_pose(f.pad_link)
        targets.append((T_pad[:3, :3] @ np.array(f.pad_p_link) + T_pad[:3, 3],))
    t_ik = median_time_s(lambda p: hand.ik("index", p, hand.q_open), targets)
    errs = []
    for (p,) in targets:
        q = hand.ik("index", p, hand.q_open)
        T_pad = hand.state(q).link_pose(f.pad_link)
        errs.append(np.linalg.norm(T_pad[:3, :3] @ np.array(f.pad_p_link) + T_pad[:3, 3] - p))
    t_close = median_time_s(lambda q: hand.close_finger("index", q, obj), [(hand.q_open,)] * 20)

    print(f"FK + collision check, index finger vs object + other links: {t_fk_col * 1e6:8.1f} us (median)")
    print(f"collision check, whole hand (all pairs + object):           {t_all_col * 1e6:8.1f} us (median)")
    print(f"contact patches, whole hand:                                {t_patch * 1e6:8.1f} us (median)")
    print(f"IK solve, index pad, FK-generated targets:                  {t_ik * 1e6:8.1f} us (median)"
          f"; error median {np.median(errs) * 1e6:.2f} um, max {np.max(errs) * 1e6:.2f} um")
    print(f"close_finger (eqs. 8-9), index onto box:                    {t_close * 1e6:8.1f} us (median)")


if __name__ == "__main__":
    main()
