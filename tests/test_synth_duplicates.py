"""Near-duplicates dropped as soon as their contacts are known (issue 36 item 3's rate): a
candidate that could not replace its kept twin even if it passed every remaining test skips
them, and the kept grasps are the same as with every test run. Seeded; no timing."""

from __future__ import annotations

import numpy as np

import planner.synthesis as S
from experiments.exp8_random_pairs import execution_ready

BALL = {"shape": "sphere", "size": [0.03], "mass_kg": 0.05}


def test_outranked_only_by_a_twin_the_candidate_cannot_beat():
    f = np.zeros((7, 3))
    near, far = f + 0.004 / np.sqrt(3), f + 0.006
    ready_hi, ready_lo, refused_hi = (False, -0.02, 3), (False, -0.01, 3), (True, -0.05, 3)
    assert S._outranked([(f, ready_hi)], near, 0.015, 9)  # better ranked twin: nothing to gain
    assert S._outranked([(f, ready_hi)], near, 0.02, 9)  # equal metric: the earlier attempt stays
    assert not S._outranked([(f, ready_lo)], near, 0.015, 9)  # it may replace its twin
    assert not S._outranked([(f, refused_hi)], near, 0.001, 9)  # an accepted candidate replaces a refused twin
    assert not S._outranked([(f, ready_hi)], far, 0.001, 9)  # not a near-duplicate
    assert not S._outranked([], near, 0.001, 9)
    # the first twin decides, as synthesize's own loop finds it
    assert not S._outranked([(f, ready_lo), (near, ready_hi)], near, 0.015, 9)


def test_skipping_outranked_duplicates_keeps_the_same_grasps(monkeypatch):
    kw = execution_ready("icub_right")
    calls = {"hold": 0}
    hold = S._hold_grip

    def counted(*a, **k):
        calls["hold"] += 1
        return hold(*a, **k)

    monkeypatch.setattr(S, "_hold_grip", counted)
    fast = S.synthesize("icub_right", dict(BALL), ["thumb", "index", "middle"], 20, fixed=False, seed=1,
                        max_attempts=200, **kw)
    fast_calls, calls["hold"] = calls["hold"], 0
    attempt = S._attempt
    monkeypatch.setattr(S, "_attempt", lambda ctx, k, kept=None: attempt(ctx, k))  # every test, always
    full = S.synthesize("icub_right", dict(BALL), ["thumb", "index", "middle"], 20, fixed=False, seed=1,
                        max_attempts=200, **kw)
    assert fast.grasps and [(g.data, g.metric, g.grip_force_n, g.attempt, g.execution) for g in fast.grasps] == [
        (g.data, g.metric, g.grip_force_n, g.attempt, g.execution) for g in full.grasps]
    assert (fast.attempts, fast.candidates_passed, fast.duplicates, fast.rejected) == (
        full.attempts, full.candidates_passed, full.duplicates, full.rejected)
    assert fast.duplicates > 0 and fast_calls < calls["hold"]
