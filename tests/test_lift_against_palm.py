"""A finger lifts, moves and lands beside an object held against the palm.

The links next to the palm (the Allegro's abduction links, link_0.0/4.0/8.0) stay within the
2 mm clearance of such an object whatever the finger's flexion: 1.5 mm at the open posture,
the lifted finger of every grasp state. A lift, land or move asks no link to be farther from
the object than it is there (`FingerScene.required`); before, every landing of these fingers
failed ("cannot land on contact B") and every move from the open posture was "not free".
The box is exp9's allegro_right_box_m0.3 (0.2 mm from the palm).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.finger_scene import DEFAULT_CLEARANCE_M, DEFAULT_TOUCH_TOL_M, FingerScene
from planner.hand import Hand
from planner.motion import plan_gait_step
from planner.objects import make_object
from planner.retreat import retreat_blocked

FINGERS = ("index", "middle", "ring")
BASE_LINK = {"index": "link_0.0", "middle": "link_4.0", "ring": "link_8.0"}


@pytest.fixture(scope="module")
def hand():
    return Hand.load("allegro_right")


@pytest.fixture(scope="module")
def box():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([0.7056548, 0.0452918, 0.7056548, 0.0452918]).as_matrix()
    T[:3, 3] = [0.034806, -0.000439, -0.016522]
    return make_object("box", (0.05067, 0.07014, 0.04698), T)


@pytest.fixture(scope="module")
def q_open(hand):
    return np.asarray(hand.q_open, dtype=float)


def _link_distances(hand, obj, q, finger):
    out = {}
    for d, link, _, _ in hand.state(q).object_distances(obj, finger):
        out[link] = min(d, out.get(link, np.inf))
    return out


def test_the_open_posture_is_within_the_clearance(hand, box, q_open):
    """The premise: the object lies against the palm and each finger's base link is nearer
    to it than the clearance at the open posture, so no margin-only check passes there."""
    assert hand.state(q_open).palm_object_distance(box) < 0.001
    for finger in FINGERS:
        d = _link_distances(hand, box, q_open, finger)
        assert 0.0 < d[BASE_LINK[finger]] < DEFAULT_CLEARANCE_M
        assert not hand.state(q_open).clearance(box, finger, DEFAULT_CLEARANCE_M)


@pytest.mark.parametrize("finger", FINGERS)
def test_required_margin_is_capped_by_the_open_posture(hand, box, q_open, finger):
    scene = FingerScene(hand, box, q_open, finger, DEFAULT_TOUCH_TOL_M)
    d_open = _link_distances(hand, box, q_open, finger)
    assert scene.open_distances() == pytest.approx(d_open, abs=1e-12)
    base = BASE_LINK[finger]
    assert scene.base_links() == (base,)  # the abduction link: no closing joint moves it
    for link, d in d_open.items():
        for margin in (DEFAULT_CLEARANCE_M, 0.005):
            want = min(margin, max(d - 1e-6, 0.0)) if link == base else margin
            assert scene.required(link, margin) == pytest.approx(want, abs=1e-12)
        assert scene.required(link, -DEFAULT_TOUCH_TOL_M) == -DEFAULT_TOUCH_TOL_M  # a touch margin: unchanged
    assert scene.required(base, DEFAULT_CLEARANCE_M) < DEFAULT_CLEARANCE_M
    # the open posture itself is free, and a finger pushed into the object is not
    assert scene.is_valid(q_open[scene.idx], DEFAULT_CLEARANCE_M)
    q_in = hand.close_finger(finger, q_open, box)[scene.idx]
    assert not scene.is_valid(q_in, DEFAULT_CLEARANCE_M)
    words = scene.explain(q_in, DEFAULT_CLEARANCE_M)
    assert "mm from the object (needs 2.0)" in words and f"{base} is" not in words


@pytest.mark.parametrize("finger", FINGERS)
def test_land_and_lift_beside_the_palm(hand, box, q_open, finger):
    """The finger closed onto the box from its open posture can land there and lift off again;
    every configuration of the move keeps each link as far as the open posture does (or the
    clearance), the land and lift never penetrate deeper than the touch tolerance."""
    idx = list(hand.fingers[finger].q_index)
    q_contact = hand.close_finger(finger, q_open, box)
    assert min(_link_distances(hand, box, q_contact, finger).values()) < 0.001  # it touches
    d_open = _link_distances(hand, box, q_open, finger)
    land = plan_gait_step(hand, box, None, q_contact, finger, q_others=q_open)
    lift = plan_gait_step(hand, box, q_contact, None, finger)
    np.testing.assert_array_equal(land["land"][-1], q_contact[idx])
    np.testing.assert_array_equal(lift["lift"][0], q_contact[idx])
    np.testing.assert_array_equal(lift["move"][-1], q_open[idx])
    q = q_open.copy()
    for gait in (land, lift):
        for part in ("lift", "move", "land"):
            for row in gait.get(part, ()):
                q[idx] = row
                d = _link_distances(hand, box, q, finger)
                if part == "move":
                    for link, dl in d.items():
                        assert dl >= min(DEFAULT_CLEARANCE_M, d_open[link]) - 2e-6, (part, link, dl)
                else:
                    assert min(d.values()) >= -DEFAULT_TOUCH_TOL_M - 1e-9
    assert retreat_blocked(hand, box, q_contact[idx], finger) is None


def test_only_links_no_closing_joint_moves_are_relieved(hand, box, q_open):
    """The ring's proximal link is 3.2 mm from the box at the open posture, but opening the
    finger moves it: it keeps the full margins. A base link within the touch tolerance at the
    open posture is asked to stay where it is there, one inside the object to come out. The
    iCub has no such link."""
    scene = FingerScene(hand, box, q_open, "ring", DEFAULT_TOUCH_TOL_M)
    assert scene.open_distances()["link_9.0"] < 0.005
    assert scene.required("link_9.0", 0.005) == 0.005
    assert scene.required("link_9.0", DEFAULT_CLEARANCE_M) == DEFAULT_CLEARANCE_M
    scene._open = dict(scene.open_distances(), **{"link_8.0": 0.5 * DEFAULT_TOUCH_TOL_M})
    assert scene.required("link_8.0", DEFAULT_CLEARANCE_M) == pytest.approx(0.5 * DEFAULT_TOUCH_TOL_M - 1e-6, abs=1e-12)
    scene._open = dict(scene.open_distances(), **{"link_8.0": -0.3e-3})
    assert scene.required("link_8.0", DEFAULT_CLEARANCE_M) == 0.0  # inside the object at the open posture: out
    thumb = FingerScene(hand, box, q_open, "thumb", DEFAULT_TOUCH_TOL_M)
    assert thumb.base_links() == ("link_12.0", "link_13.0")
    icub = Hand.load("icub_right")
    for finger in icub.fingers:
        assert FingerScene(icub, box, np.asarray(icub.q_open, float), finger, DEFAULT_TOUCH_TOL_M).base_links() == ()


def _exp9_grasp(tmp_path, hand: str, obj: dict, fingers: dict):
    """A grasp of exp9 v2's pairs (experiments/results/exp9_pairs_v2), realized."""
    import yaml

    from planner.grasp import load_grasp
    from planner.realization import realize

    data = {"schema_version": 1, "name": "g", "hand": hand, "object": obj, "friction": {"mu": 0.9, "gamma": 0.004},
            "fingers": fingers}
    path = tmp_path / "g.yaml"
    path.write_text(yaml.safe_dump(data))
    return realize(load_grasp(path), suggest=False)


def test_a_contact_the_finger_cannot_leave_names_the_link_that_stays_on_the_object(tmp_path):
    """exp9's iCub box pair (100 g), final grasp: the thumb touches with its proximal phalanx
    at its opening limit, and that phalanx is 0.08 mm from the box with the thumb open, inside
    the 1 mm touch tolerance: the refusal says so, with the distance measured there."""
    import re

    g = _exp9_grasp(tmp_path, "icub_right",
                    {"shape": "box", "size": [0.03821, 0.06469, 0.02626], "position": [0.014671, 0.002155, 0.019018],
                     "quat_xyzw": [0.0, 0.0, -0.014998, 0.9998875], "mass_kg": 0.1},
                    {"thumb": {"contact": {"point": [0.01534, -0.03234, -0.00974]}},
                     "index": {"posture": [0.0, 0.3, 0.0, 0.0]}, "middle": {"posture": [0.3, 0.0, 0.0]},
                     "ring": {"posture": [0.0, 0.0, 0.0, 0.0]}, "little": {"posture": [0.1745, 0.0, 0.0, 0.0]}})
    f = g.hand.fingers["thumb"]
    why = retreat_blocked(g.hand, g.obj, g.q[list(f.q_index)], "thumb")
    m = re.search(r"at the finger's open posture too, thumb_proximal is ([0-9.]+) mm from the object", why or "")
    assert m is not None, why
    q = np.array(g.q, dtype=float)
    q[list(f.q_index)] = np.asarray(g.hand.q_open)[list(f.q_index)]
    d = min(d for d, link, _, _ in g.hand.state(q).object_distances(g.obj, "thumb") if link == "thumb_proximal")
    assert float(m.group(1)) == pytest.approx(d * 1e3, abs=0.01) and d < DEFAULT_TOUCH_TOL_M


def test_a_thumb_whose_base_link_lies_on_the_object_lifts_as_far_as_it_goes(tmp_path):
    """exp9's Allegro box pair (300 g): the thumb's link_12.0 (no closing joint moves it) is
    0.88 mm from the box at every thumb posture. The thumb can still back off its contact on
    link_14.0, and open it is lifted as far as it goes (what the plan's audit accepts of a
    lifted finger); at its contact it is not (link_14.0 touches)."""
    g = _exp9_grasp(tmp_path, "allegro_right",
                    {"shape": "box", "size": [0.05067, 0.07014, 0.04698], "position": [0.034806, -0.000439, -0.016522],
                     "quat_xyzw": [0.7056548, 0.0452918, 0.7056548, 0.0452918], "mass_kg": 0.3},
                    {"thumb": {"contact": {"point": [0.01183, 0.03507, 0.0052]}},
                     "index": {"posture": [-0.235, 0.0, 0.0, 0.0]}, "middle": "free",
                     "ring": {"posture": [0.0, 0.3, 0.0, 0.0]}})
    f = g.hand.fingers["thumb"]
    idx = list(f.q_index)
    assert retreat_blocked(g.hand, g.obj, g.q[idx], "thumb") is None
    scene = FingerScene(g.hand, g.obj, g.q, "thumb", DEFAULT_TOUCH_TOL_M)
    q_open = np.asarray(g.hand.q_open, dtype=float)[idx]
    d12 = scene.open_distances()["link_12.0"]
    assert 0.0 < d12 < DEFAULT_TOUCH_TOL_M and "link_12.0" in scene.base_links()
    assert scene.lifted_as_far_as_it_goes(q_open)
    assert not scene.lifted_as_far_as_it_goes(g.q[idx])
