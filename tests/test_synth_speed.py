"""Synthesis where it is needed (issue 36 item 3): at the fixed pose of a grasp it made itself,
the same grasps for any number of worker processes, ranked by what execution needs, and a
progress line only on a terminal. Seeded; the rate itself is benchmarks/bench_synth.py's."""

from __future__ import annotations

import pytest

from planner.realization import execution_verdict
from planner.synthesis import SynthGrasp, _Progress, synthesize

BALL = {"shape": "sphere", "size": [0.03], "mass_kg": 0.05}
FOUR = ["thumb", "index", "middle", "ring"]


@pytest.fixture(scope="module")
def own_pose():
    """The object pose of a four-finger Allegro grasp synth made with the pose sampled."""
    r = synthesize("allegro_right", dict(BALL), FOUR, 1, fixed=False, seed=0, max_attempts=100)
    assert r.grasps
    o = r.grasps[0].data["object"]
    return dict(BALL, position=o["position"], quat_xyzw=o["quat_xyzw"])


def test_synth_at_the_pose_of_its_own_four_finger_grasp_finds_four_finger_grasps(own_pose):
    """The fingers are drawn and closed one by one at a fixed pose (a whole-hand draw needed
    every finger near the object at once: 0 of 6 there before, "sweeps miss the object")."""
    r = synthesize("allegro_right", own_pose, FOUR, 3, fixed=True, seed=1, max_attempts=60)
    assert len(r.grasps) == 3, r.rejected
    assert r.rejected.get("sweeps miss the object", 0) == 0
    for sg in r.grasps:
        assert sg.data["object"]["position"] == own_pose["position"]
        assert sg.grasp.ok and set(sg.grasp.patches) == set(FOUR)


def test_synth_at_the_pose_where_the_whole_hand_draw_missed():
    """The pose of a four-finger grasp the synthesis before issue 36 item 3 made itself (22 mm
    ball, Allegro, seed 0): there it found 0 of 6 four-finger grasps in 60 attempts, 50 of
    them "sweeps miss the object"."""
    block = {"shape": "sphere", "size": [0.022], "mass_kg": 0.03,
             "position": [0.05658609637907282, 0.01087451709606073, -0.012267258132646487],
             "quat_xyzw": [0.0, 0.0, 0.0, 1.0]}
    r = synthesize("allegro_right", block, FOUR, 3, fixed=True, seed=1, max_attempts=60)
    assert len(r.grasps) == 3 and "sweeps miss the object" not in r.rejected, r.rejected


def test_synth_gives_the_same_grasps_for_one_and_two_workers(own_pose):
    """Attempt k draws from its own generator (seed, k): the outcome does not depend on which
    process ran it, nor on how many there are."""
    one = synthesize("allegro_right", own_pose, ["thumb", "index", "middle"], 4, fixed=True, seed=3, max_attempts=40)
    two = synthesize("allegro_right", own_pose, ["thumb", "index", "middle"], 4, fixed=True, seed=3, max_attempts=40,
                     workers=2)
    assert one.grasps and [g.data for g in one.grasps] == [g.data for g in two.grasps]
    assert (one.attempts, one.candidates_passed, one.duplicates, one.rejected) == (
        two.attempts, two.candidates_passed, two.duplicates, two.rejected)
    assert [g.metric for g in two.grasps] == pytest.approx([g.grasp.metric for g in two.grasps])  # re-realized


def test_synth_ranks_execution_accepted_grasps_first():
    """Each grasp carries plan --execution's own verdict (`execution_verdict`) and the ranking
    puts the accepted ones first, then the larger closure metric."""
    r = synthesize("icub_right", dict(BALL), ["thumb", "index", "middle"], 6, fixed=False, seed=2, max_attempts=200)
    assert r.grasps
    for sg in r.grasps:
        assert sg.execution == execution_verdict(sg.grasp).reason
    keys = [(not sg.execution_ready, -sg.metric) for sg in r.grasps]
    assert keys == sorted(keys)
    # the key itself: a refused grasp with a larger metric ranks after an accepted one
    ok = SynthGrasp({}, grip_force_n=None, attempt=5, metric=0.001, execution=None)
    refused = SynthGrasp({}, grip_force_n=None, attempt=1, metric=0.01, execution="palm_up: holds 1.1x")
    assert sorted([refused, ok], key=SynthGrasp.rank_key) == [ok, refused]


def test_progress_goes_to_the_planner_logger_at_most_once_a_period(tmp_path, caplog):
    """Progress records go to the ``planner.synth`` logger (the command line shows them on a
    terminal only, without -q, like plan's), at most one per period; -q: none."""
    import logging

    from planner.cli import main

    p = _Progress()
    with caplog.at_level(logging.INFO, logger="planner"):
        p("synth: 0/5 grasps after 10 attempts")
        p("synth: 1/5 grasps after 11 attempts")  # within the period: dropped
        p.last = -1e9
        p("synth: 2/5")
    assert [r.getMessage() for r in caplog.records] == ["0/5 grasps after 10 attempts", "2/5"]
    caplog.clear()
    obj = tmp_path / "ball.yaml"
    obj.write_text("shape: sphere\nsize: [0.03]\n")
    with caplog.at_level(logging.INFO, logger="planner"):
        assert main(["synth", "allegro_right", str(obj), "-n", "1", "-o", str(tmp_path / "a")]) == 0
        assert any(r.name == "planner.synth" and "grasps" in r.getMessage() for r in caplog.records)
        caplog.clear()
        assert main(["synth", "allegro_right", str(obj), "-n", "1", "-o", str(tmp_path / "b"), "-q"]) == 0
        assert not [r for r in caplog.records if r.name == "planner.synth"]


def test_the_shortcuts_give_what_the_long_way_gives():
    """What the rate work skips or shares is the same to the bit: the sweeps of all fingers
    from one forward kinematics per sample and each finger's own sweep; the pre-filter's
    closed hand and the one realize makes from the file (its closings answered from
    memory: a copy, equal to a fresh closing); the ranking's refusal and execution_verdict's."""
    import numpy as np

    from planner.grasp import load_hand, parse_grasp
    from planner.ik import close_finger
    from planner.realization import execution_refusal, realize
    from planner.synth_sample import _sweep, _sweeps, closes_onto, object_of
    from planner.synthesis import DEFAULT_FRICTION, _grasp_data

    hand = load_hand("icub_right")
    fingers = [hand.finger(f) for f in ("thumb", "index", "middle")]
    rng = np.random.default_rng(4)
    q = np.array(hand.q_open, dtype=float)
    for f in fingers:
        idx = list(f.q_index)
        q[idx] = rng.uniform(hand.lower[idx], hand.upper[idx])
    alphas = np.linspace(0.0, 1.0, 10)
    for f, (c, n) in zip(fingers, _sweeps(hand, fingers, q, alphas, 0.03)):
        c1, n1 = _sweep(hand, f, q, alphas, 0.03)
        assert np.array_equal(c, c1) and np.array_equal(n, n1)
    r = synthesize("icub_right", dict(BALL), ["thumb", "index", "middle"], 1, fixed=False, seed=0, max_attempts=60)
    g0 = r.grasps[0]
    obj = object_of(dict(BALL, position=g0.data["object"]["position"], quat_xyzw=g0.data["object"]["quat_xyzw"]))
    pre = {f.name: np.asarray(g0.data["fingers"][f.name]["posture"], dtype=float) for f in fingers}
    q_closed, why = closes_onto(hand, fingers, obj, pre)
    assert why == ""
    g = realize(parse_grasp(_grasp_data("icub_right", obj, DEFAULT_FRICTION, fingers, pre, "c", ""), "c.yaml"), hand)
    assert np.array_equal(np.asarray(g.q), q_closed)
    f = fingers[0]
    q_pre = np.array(hand.q_open, dtype=float)
    q_pre[list(f.q_index)] = pre[f.name]
    once, again = hand.close_finger(f, q_pre, obj), hand.close_finger(f, q_pre, obj)
    assert once is not again and np.array_equal(once, again)
    assert np.array_equal(once, close_finger(hand, f, q_pre, obj))
    assert execution_refusal(g) == execution_verdict(g).reason
