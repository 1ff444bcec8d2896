"""Whole-hand synthesis (`regrasp synth --palm`): the object is placed against the palm, the
palm's patch is part of the grasp (files say ``palm: hold``), every written grasp passes
``check`` with the palm touching and holds twice its weight palm up; a fixed pose away from
the palm is refused before any sampling; the rejection table names the palm's reasons."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from planner.cli import main
from planner.contacts import TOUCH_TOL_M
from planner.grasp import load_grasp
from planner.grip import HOLD_FACTOR, grasp_hold
from planner.hand import Hand
from planner.model import PALM
from planner.realization import PENETRATION_TOL_M, realize
from planner.synth_sample import (PALM_GAP_TOL_M, PALM_TOUCH_GAP_M, _palm_shapes, object_of,
                                  place_against_palm)
from planner.synthesis import SynthResult, default_fingers, rejection_table, synthesize

BALL = {"shape": "sphere", "size": [0.025], "mass_kg": 0.1}


def _synth(args) -> int:
    return main(["synth", *map(str, args), "--quiet"])


def test_the_placement_gap_is_inside_the_touch_tolerance():
    """Half the touch tolerance: the palm touches, nothing penetrates."""
    assert 0.0 < PALM_TOUCH_GAP_M - PALM_GAP_TOL_M and PALM_TOUCH_GAP_M + PALM_GAP_TOL_M < TOUCH_TOL_M


@pytest.mark.parametrize("hand_name", ["icub_right", "allegro_right"])
def test_place_against_palm_moves_the_object_onto_the_palm_either_way(hand_name):
    """From far in front of the palm and from inside it, the object ends `PALM_TOUCH_GAP_M` from
    the palm along the palm normal only; beside the palm it is not placed (None)."""
    hand = Hand.load(hand_name)
    n = np.asarray(hand.palm_normal)
    shapes = _palm_shapes(hand)
    box = object_of({"shape": "box", "size": [0.03, 0.04, 0.05]})
    # a point over the middle of the palm's grasping face (from its bounding box)
    c = np.mean([np.asarray(tf.getTranslation()) for _, tf in shapes], axis=0)
    for start in (c + 0.08 * n, c):  # far out, and inside the palm
        placed = place_against_palm(hand, shapes, box, start, [0.0, 0.0, 0.0, 1.0])
        assert placed is not None
        d = hand.state(hand.q_open).palm_object_distance(placed)
        assert abs(d - PALM_TOUCH_GAP_M) <= PALM_GAP_TOL_M
        moved = np.asarray(placed.position) - start
        np.testing.assert_allclose(moved - (moved @ n) * n, 0.0, atol=1e-12)  # along the normal only
    across = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    assert place_against_palm(hand, shapes, box, c + 0.3 * across / np.linalg.norm(across), [0, 0, 0, 1]) is None


def test_synth_palm_power_grasps_touch_the_palm_pass_check_and_hold_palm_up(tmp_path, capsys):
    """``--palm`` with the default fingers (all five: power grasps) and palm-up gravity: every
    written file says palm: hold, passes check (exit 0) with the palm among the patches and
    its gap within the touch tolerance, and holds twice the weight palm up (recomputed from
    the re-realized grasp, palm included, one contact per touching link)."""
    obj = tmp_path / "ball.yaml"
    obj.write_text(yaml.safe_dump(BALL))
    out = tmp_path / "out"
    palm_up = np.array([0.0, 0.0, -9.81])  # icub_right: palm_normal +z
    assert _synth(["icub_right", obj, "--palm", "-n", 2, "-o", out, "--gravity", *palm_up, "--max-attempts", 40]) == 0
    files = sorted(out.glob("*.yaml"))
    assert len(files) == 2
    capsys.readouterr()
    hand = Hand.load("icub_right")
    for f in files:
        data = yaml.safe_load(f.read_text())
        assert data["palm"] == "hold" and set(data["fingers"]) == set(hand.fingers)
        assert main(["check", str(f)]) == 0, capsys.readouterr().out
        g = realize(load_grasp(f))
        assert g.ok and PALM in g.patches and set(g.patches) == {PALM, *hand.fingers}
        s = g.palm_summary()
        assert s["holds"] and s["touching"] and -PENETRATION_TOL_M < s["distance_m"] <= TOUCH_TOL_M
        from planner.closure import apply_contact_model

        hold = grasp_hold(g.hand, g.q, apply_contact_model(dict(g.patches), "link"), g.obj.T_palm_obj,
                          g.obj.mass_kg, g.friction, [("palm_up", palm_up)], demand=False)
        assert hold[0].capacity.factor >= HOLD_FACTOR


def test_synth_palm_finds_grasps_within_a_bounded_number_of_attempts_on_both_hands():
    """Seeded: the iCub's power grasp of a 50 mm ball and the Allegro's palm-supported tripod
    (thumb, index, middle) are found within a few attempts, each with the palm touching."""
    for hand, fingers in (("icub_right", None), ("allegro_right", ["thumb", "index", "middle"])):
        fingers = fingers or default_fingers(Hand.load(hand), palm=True)
        r = synthesize(hand, dict(BALL), fingers, 1, fixed=False, seed=0, palm=True, max_attempts=40)
        assert r.grasps, (hand, r.rejected)
        g = r.grasps[0]
        assert g.data["palm"] == "hold" and PALM in g.grasp.patches and g.grasp.ok


def test_synth_palm_refuses_a_fixed_pose_away_from_the_palm_and_keeps_one_against_it(tmp_path, capsys):
    """A fixed position 10 mm from the palm: exit 2, one line saying how far, nothing written;
    one touching the palm is kept."""
    far = tmp_path / "far.yaml"
    # icub_right's palm face is at z = 3 mm: a 20 mm ball centred 33 mm up is 10 mm from it
    far.write_text("shape: sphere\nsize: [0.02]\nposition: [-0.03, 0.0, 0.033]\n")
    out = tmp_path / "out"
    assert _synth(["icub_right", far, "--palm", "-n", 1, "-o", out]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "10.0 mm from the palm" in err and "--palm" in err
    assert not out.exists() or not any(out.iterdir())
    # touching the palm there (0.5 mm): the pose is kept and the palm holds in every grasp
    near = tmp_path / "near.yaml"
    near.write_text("shape: sphere\nsize: [0.025]\nposition: [0.0135, -0.0026, 0.02765]\n")
    assert _synth(["icub_right", near, "--palm", "-n", 2, "-o", out, "--max-attempts", 20]) == 0
    for f in sorted(out.glob("*.yaml")):
        g = realize(load_grasp(f))
        np.testing.assert_allclose(g.obj.position, [0.0135, -0.0026, 0.02765])
        assert g.ok and PALM in g.patches


def test_rejection_table_names_the_palm_reasons():
    """The palm's reasons are rows like any other and the hint points at the palm."""
    r = SynthResult(grasps=(), attempts=7, candidates_passed=0, duplicates=0, seconds=0.0, palm=True,
                    rejected={"object not against the palm": 4, "sweeps miss the object on the palm": 2,
                              "not force closure": 1})
    table = rejection_table(r)
    assert "object not against the palm" in table and "sweeps miss the object on the palm" in table
    assert "not force closure" in table and "drop --palm" in table
    assert default_fingers(Hand.load("allegro_right"), palm=True) == list(Hand.load("allegro_right").fingers)


def test_rejection_table_says_to_sample_the_pose_only_when_it_was_fixed():
    """'let synth sample the pose' was the hint of 29 sweep runs whose pose was sampled."""
    rejected = {"sweeps miss the object": 530, "not force closure": 48}
    fixed = rejection_table(SynthResult(grasps=(), attempts=600, candidates_passed=0, duplicates=0, seconds=0.0,
                                        rejected=rejected, fixed=True))
    sampled = rejection_table(SynthResult(grasps=(), attempts=600, candidates_passed=0, duplicates=0, seconds=0.0,
                                          rejected=rejected))
    assert "let synth sample the pose" in fixed and "let synth sample the pose" not in sampled
    assert "the fingers do not reach the object at the poses sampled: other fingers (--fingers)" in sampled
