"""Named hand orientations (``--gravity palm_up``, ``thumb_up``, ...): `planner.gravity.named_gravity`
and the ``--gravity`` option of check, plan, replay and synth (issue 34 item 6)."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from planner.cli import main
from planner.errors import PlannerError
from planner.grasp import load_hand
from planner.gravity import ANATOMICAL_NAMES, G_MPS2, GRAVITY_NAMES, gravity_directions, named_gravity
from planner.resources import bundled_grasp

HANDS = ("icub_right", "allegro_right")
INITIAL = bundled_grasp("icub/cylinder_parallel_extension.yaml")
FINAL = bundled_grasp("icub/cylinder_ir2m.yaml")
OPPOSITES = [("palm_down", "palm_up"), ("thumb_up", "thumb_down"), ("fingers_up", "fingers_down")]


@pytest.fixture(scope="module", params=HANDS)
def hand(request):
    return load_hand(request.param)


def _valid_names(hand) -> list[str]:
    """The names this hand resolves: those of --gravity-set 7 (its sideways pair) and the anatomical ones."""
    return [n for n, _ in gravity_directions(hand.palm_normal, 7)] + list(ANATOMICAL_NAMES)


def _base(hand, finger: str) -> np.ndarray:
    """A finger's first joint at the open posture, palm frame (pinocchio's own placement)."""
    km = hand.collision.kinematic_model
    M = hand.kinematics(hand.q_open).joint_placement(hand.model.getJointId(hand.fingers[finger].joints[0]))
    return np.asarray((km.T_palm_world * M).translation, dtype=float)


def _run(capsys, *argv) -> tuple[int, str, list[str]]:
    """main(argv) in-process: (exit code, stdout, stderr lines)."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as stop:  # argparse
        code = stop.code
    out = capsys.readouterr()
    return code, out.out, out.err.strip().splitlines()


# ----------------------------------------------------------------------------- named_gravity


def test_every_name_is_a_vector_of_standard_gravity(hand):
    """Each name the hand has resolves to 9.81 m/s^2 (off: zero); the set's names give the set's vectors."""
    names = _valid_names(hand)
    assert set(names) <= set(GRAVITY_NAMES) and len(set(names)) == len(names)
    for name in names:
        g = np.asarray(named_gravity(name, hand), dtype=float)
        assert g.shape == (3,) and np.all(np.isfinite(g))
        assert np.linalg.norm(g) == pytest.approx(0.0 if name == "off" else G_MPS2, abs=1e-12), name
    for name, g in gravity_directions(hand.palm_normal, 7):
        assert named_gravity(name, hand) == g


def test_palm_down_is_along_the_palm_normal(hand):
    n = np.asarray(hand.palm_normal, dtype=float)
    np.testing.assert_allclose(named_gravity("palm_down", hand), G_MPS2 * n, atol=1e-12)
    np.testing.assert_allclose(named_gravity("palm_up", hand), -G_MPS2 * n, atol=1e-12)


def test_opposite_names_are_opposite(hand):
    pairs = OPPOSITES + [(f"side_+{a}", f"side_-{a}") for a in "xyzab"
                         if f"side_+{a}" in _valid_names(hand)]
    assert len(pairs) == 5  # palm, thumb, fingers, two sideways axes
    for up, down in pairs:
        np.testing.assert_allclose(named_gravity(up, hand), -np.asarray(named_gravity(down, hand)), atol=1e-12)


def test_thumb_and_finger_names_come_from_the_hand(hand):
    """thumb_up: orthogonal to the palm normal and against the palm-to-thumb-base direction;
    fingers_up against the palm-to-knuckles direction; the two orthogonal (a hand frame).
    Checked against the hand.yaml comments too: iCub fingers along +x, thumb on -y; Allegro
    fingers along +z, thumb on +y (its base in the URDF)."""
    n = np.asarray(hand.palm_normal, dtype=float)
    thumb_up = np.asarray(named_gravity("thumb_up", hand))
    fingers_up = np.asarray(named_gravity("fingers_up", hand))
    assert abs(thumb_up @ n) < 1e-9 and abs(fingers_up @ n) < 1e-9 and abs(thumb_up @ fingers_up) < 1e-9
    thumb = _base(hand, "thumb")
    knuckles = np.mean([_base(hand, f) for f in hand.fingers if f != "thumb"], axis=0)
    assert thumb_up @ (thumb - knuckles) < 0  # the thumb sits on the upper side: gravity away from it
    from planner.gravity import _palm_centre

    to_knuckles = knuckles - _palm_centre(hand.state(hand.q_open))
    to_knuckles -= n * (to_knuckles @ n)
    assert fingers_up @ to_knuckles < 0 < np.asarray(named_gravity("fingers_down", hand)) @ to_knuckles
    expected = {"icub_right": ((0, 1, 0), (-1, 0, 0)), "allegro_right": ((0, -1, 0), (0, 0, -1))}[hand.name]
    assert thumb_up / G_MPS2 @ expected[0] > 0.99 and fingers_up / G_MPS2 @ expected[1] > 0.99


def test_thumb_up_points_against_the_thumb_base_in_the_palm_plane(hand):
    """The brief's definition: against the palm-centre-to-thumb-base direction projected on the palm plane."""
    from planner.gravity import _palm_centre

    n = np.asarray(hand.palm_normal, dtype=float)
    d = _base(hand, "thumb") - _palm_centre(hand.state(hand.q_open))
    d -= n * (d @ n)
    assert np.asarray(named_gravity("thumb_up", hand)) @ d < 0
    assert np.asarray(named_gravity("thumb_down", hand)) @ d > 0


def test_unknown_names_and_names_the_hand_lacks_are_one_line_errors(hand):
    with pytest.raises(PlannerError) as err:
        named_gravity("sideways_up", hand)
    text = str(err.value)
    assert "\n" not in text and "'sideways_up'" in text and all(n in text for n in GRAVITY_NAMES)
    along = "xyz"[int(np.argmax(np.abs(hand.palm_normal)))]  # the axis of the palm normal has no side_ name
    with pytest.raises(PlannerError, match=f"side_\\+{along}: not a sideways direction of hand {hand.name}"):
        named_gravity(f"side_+{along}", hand)
    no_thumb = copy.copy(hand)
    no_thumb.fingers = {("digit" if k == "thumb" else k): f for k, f in hand.fingers.items()}
    for name in ("thumb_up", "thumb_down"):
        with pytest.raises(PlannerError, match="has no finger named thumb") as err:
            named_gravity(name, no_thumb)
        assert "\n" not in str(err.value)
    assert np.linalg.norm(named_gravity("fingers_up", no_thumb)) == pytest.approx(G_MPS2)


# ----------------------------------------------------------------------------- command line


def test_check_reports_the_load_held_under_a_named_gravity(capsys):
    code, out, err = _run(capsys, "check", FINAL, "--gravity", "palm_up")
    assert code == 0, err
    assert "gravity palm_up: [+0.000 +0.000 -9.810] m/s^2 in the palm frame of icub_right" in out
    assert " palm_up: holds " in out and " palm_down: " not in out
    code, out, err = _run(capsys, "check", "--gravity", "thumb_up", FINAL, "--json")  # a name before the grasp
    data = json.loads(out)
    assert code == 0 and list(data["hold"]) == ["thumb_up"] and data["gravity"]["name"] == "thumb_up"
    assert data["gravity"]["vector"] == list(named_gravity("thumb_up", load_hand("icub_right")))


def test_numeric_gravity_still_works(capsys):
    """3 numbers: as before in plan (before or after the grasps); in check the direction is "gravity",
    with the factor of the same vector's named direction."""
    code, out, _ = _run(capsys, "check", FINAL, "--gravity", "0", "0", "9.81", "--json")
    numeric = json.loads(out)["hold"]
    code2, out, _ = _run(capsys, "check", FINAL, "--json")
    assert code == code2 == 0 and list(numeric) == ["gravity"]
    assert numeric["gravity"]["factor"] == json.loads(out)["hold"]["palm_down"]["factor"]
    code, err = _run(capsys, "check", FINAL, "--gravity", "0", "0", "x")[::2]
    assert code == 2 and len(err) == 1 and "argument --gravity: invalid float value: 'x'" in err[0]


def test_plan_with_a_name_records_its_vector(capsys, tmp_path):
    """plan --gravity palm_up writes the same file, byte for byte, as --gravity 0 0 -9.81 (iCub:
    palm normal +z); the name may come before the grasp files, like the three numbers."""
    named, numeric = tmp_path / "named.yaml", tmp_path / "numeric.yaml"
    code, out, err = _run(capsys, "plan", "--gravity", "palm_up", INITIAL, FINAL, "--no-motion", "-o", named)
    assert code == 0, err
    assert out.splitlines()[0] == "gravity palm_up: [+0.000 +0.000 -9.810] m/s^2 in the palm frame of icub_right"
    code, out, err = _run(capsys, "plan", "--gravity", "0", "0", "-9.81", INITIAL, FINAL, "--no-motion", "-o", numeric)
    assert code == 0, err
    assert not out.startswith("gravity")  # numeric input: the output as before
    assert named.read_bytes() == numeric.read_bytes()
    from planner.plan import read_plan

    assert list(read_plan(named).parameters["gravity"]) == [0.0, 0.0, -9.81]


def test_replay_under_a_named_gravity(capsys, tmp_path):
    """replay --gravity thumb_up simulates under the hand's thumb_up vector (the report's parameters)."""
    plan, report = tmp_path / "plan.yaml", tmp_path / "report.json"
    assert _run(capsys, "plan", INITIAL, FINAL, "--no-motion", "-o", plan)[0] == 0
    code, out, err = _run(capsys, "replay", plan, "--gravity", "thumb_up", "--report", report)
    assert code in (0, 1), err
    g = named_gravity("thumb_up", load_hand("icub_right"))
    assert out.splitlines()[0].startswith(f"gravity thumb_up: [{' '.join(f'{v:+.3f}' for v in g)}] m/s^2")
    assert json.loads(report.read_text())["parameters"]["gravity"] == pytest.approx(list(g), abs=1e-12)


@pytest.mark.parametrize("command", ["check", "plan", "replay", "synth"])
def test_unknown_gravity_names_are_refused_in_one_line(capsys, tmp_path, command):
    args = {"check": [FINAL], "plan": [INITIAL, FINAL, "--no-motion"], "replay": [tmp_path / "p.yaml"],
            "synth": ["icub_right", tmp_path / "o.yaml", "-o", tmp_path / "out"]}[command]
    for gravity in (["sideways_up"], ["9.81"], ["0", "9.81"]):
        code, out, err = _run(capsys, command, *args, "--gravity", *gravity)
        assert code == 2 and len(err) == 1 and not out, (gravity, err)
        assert "--gravity: expected 3 numbers GX GY GZ or one of palm_down, palm_up, " in err[0]
        assert all(n in err[0] for n in ("side_+x", "thumb_up", "thumb_down", "fingers_up", "fingers_down", "off"))
    code, out, err = _run(capsys, command, "--gravity", "sideways_up", *args)  # before the positionals too
    assert code == 2 and len(err) == 1 and "expected 3 numbers GX GY GZ or one of" in err[0]


def test_a_name_the_hand_lacks_is_refused_in_one_line(capsys):
    code, out, err = _run(capsys, "check", FINAL, "--gravity", "side_+z")  # iCub: palm normal +z
    assert code == 2 and len(err) == 1 and "side_+z: not a sideways direction of hand icub_right" in err[0]
    assert "side_+x, side_-x, side_+y, side_-y" in err[0]
