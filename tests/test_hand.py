"""Hand assets and kinematics: specs load everywhere, the iCub model matches its facts,
Jacobians match finite differences, IK reaches what FK produced and refuses the rest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError, KinematicsError, SpecError, UnknownNameError
from planner.hand import ROBOTS_DIR, Hand

SPECS = sorted(ROBOTS_DIR.glob("*/hand.yaml"))

# fact sheet (/work/shared/reference/icub-hand-facts.md), fingertips at q = 0, metres
ICUB_TIPS = {"index": (0.081, -0.030, -0.010), "middle": (0.084, -0.008, -0.012),
             "ring": (0.080, 0.016, -0.018), "little": (0.072, 0.031, -0.016),
             "thumb": (0.0185, -0.087, 0.0)}


@pytest.fixture(scope="module")
def icub():
    return Hand.load("icub_right")


def _pad_palm(hand, finger, q):
    f = hand.fingers[finger]
    T = hand.state(q).link_pose(f.pad_link)
    return T[:3, :3] @ np.array(f.pad_p_link) + T[:3, 3]


@pytest.mark.parametrize("spec", SPECS, ids=lambda p: p.parent.name)
def test_spec_loads_in_pinocchio(spec):
    """Every robots/*/hand.yaml builds a Hand whose fingers cover distinct joints of the model."""
    hand = Hand.load(spec)
    joints = [j for f in hand.fingers.values() for j in f.joints]
    assert len(joints) == len(set(joints)) == hand.model.nq == len(hand.joint_names)
    assert np.all(hand.lower <= hand.q_open) and np.all(hand.q_open <= hand.upper)
    for f in hand.fingers.values():
        assert [hand.joint_names[i] for i in f.q_index] == list(f.joints)
        assert set(f.contact_links) <= set(f.links)
        hand.state(hand.q_open).link_pose(f.tip_frame)
    assert hand.state(hand.q_open).collision_objects()


@pytest.mark.needs_pybullet("pybullet's URDF loader")
@pytest.mark.parametrize("spec", SPECS, ids=lambda p: p.parent.name)
def test_spec_loads_in_pybullet(spec):
    """Every hand URDF loads in pybullet with one revolute joint per hand joint."""
    import pybullet as p

    hand = Hand.load(spec)
    cid = p.connect(p.DIRECT)
    try:
        for d in hand.package_dirs:
            p.setAdditionalSearchPath(d, physicsClientId=cid)
        body = p.loadURDF(hand.urdf_path, useFixedBase=True, physicsClientId=cid)
        names = {p.getJointInfo(body, j, physicsClientId=cid)[1].decode()
                 for j in range(p.getNumJoints(body, physicsClientId=cid))
                 if p.getJointInfo(body, j, physicsClientId=cid)[2] == p.JOINT_REVOLUTE}
        assert names == set(hand.joint_names)
    finally:
        p.disconnect(cid)


def test_icub_fingertips_match_fact_sheet(icub):
    """At q = 0 the iCub fingertip frames are within 2 mm of the published positions."""
    q = np.zeros(icub.model.nq)
    for finger, tip in ICUB_TIPS.items():
        p = icub.state(q).link_pose(icub.fingers[finger].tip_frame)[:3, 3]
        assert np.linalg.norm(p - np.array(tip)) < 2e-3, finger


def test_icub_structure(icub):
    """The iCub model has 19 joints: thumb 4, index 4, middle 3, ring 4, little 4."""
    assert icub.model.nq == 19
    assert {f: len(x.joints) for f, x in icub.fingers.items()} == \
        {"thumb": 4, "index": 4, "middle": 3, "ring": 4, "little": 4}


def test_positive_flexion_curls_toward_grasping_face(icub):
    """Flexing any finger's joints from q = 0 moves its tip toward +z (the grasping face)."""
    for f in icub.fingers.values():
        q = np.zeros(icub.model.nq)
        q[icub.joint_names.index("thumb_0")] = np.pi / 2   # opposed thumb
        before = icub.state(q).link_pose(f.tip_frame)[:3, 3]
        for j in f.close_joints:
            q[icub.joint_names.index(j)] += 0.3
        after = icub.state(q).link_pose(f.tip_frame)[:3, 3]
        if f.name == "thumb":   # opposed thumb curls toward the fingers (+x)
            assert after[0] > before[0] + 0.01
        else:
            assert after[2] > before[2] + 0.01


@pytest.mark.parametrize("name", ["icub_right", "allegro_right"])
def test_frame_jacobian_matches_finite_differences(name):
    """frame_jacobian of a link point equals central differences of its FK (linear and angular)."""
    hand = Hand.load(name)
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = rng.uniform(hand.lower, hand.upper)
        for f in hand.fingers.values():
            p_link = np.array(f.pad_p_link)
            J = hand.state(q).frame_jacobian(f.pad_link, p_link)
            eps = 1e-6
            Jn = np.zeros_like(J)
            for i in range(hand.model.nq):
                dq = np.zeros(hand.model.nq)
                dq[i] = eps
                Tp, Tm = hand.state(q + dq).link_pose(f.pad_link), hand.state(q - dq).link_pose(f.pad_link)
                Jn[:3, i] = ((Tp[:3, :3] - Tm[:3, :3]) @ p_link + Tp[:3, 3] - Tm[:3, 3]) / (2 * eps)
                dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * eps) @ Tp[:3, :3].T   # skew(omega)
                Jn[3:, i] = [dR[2, 1], dR[0, 2], dR[1, 0]]
            assert np.allclose(J, Jn, atol=1e-6), f.name


@pytest.mark.parametrize("name", ["icub_right", "allegro_right"])
def test_point_jacobians_of_palm_points_match_finite_differences(name):
    """point_jacobians (one pass, points given in the palm frame) equal central differences of
    the points carried by their links, for every finger's pad and distal link at once."""
    hand = Hand.load(name)
    rng = np.random.default_rng(1)
    q = rng.uniform(hand.lower, hand.upper)
    points = []
    for f in hand.fingers.values():
        T = hand.state(q).link_pose(f.pad_link)
        points.append((f.pad_link, T[:3, :3] @ (np.array(f.pad_p_link) + [0.002, -0.001, 0.003]) + T[:3, 3]))
    Js = hand.state(q).point_jacobians(points)
    eps = 1e-6
    for (link, p_palm), J in zip(points, Js):
        T = hand.state(q).link_pose(link)
        p_link = T[:3, :3].T @ (p_palm - T[:3, 3])
        Jn = np.zeros((3, hand.model.nq))
        for i in range(hand.model.nq):
            dq = np.zeros(hand.model.nq)
            dq[i] = eps
            Tp, Tm = hand.state(q + dq).link_pose(link), hand.state(q - dq).link_pose(link)
            Jn[:, i] = ((Tp[:3, :3] - Tm[:3, :3]) @ p_link + Tp[:3, 3] - Tm[:3, 3]) / (2 * eps)
        assert J.shape == (3, hand.model.nq) and np.allclose(J, Jn, atol=1e-6), link


@pytest.mark.parametrize("name", ["icub_right", "allegro_right"])
def test_ik_reaches_fk_targets(name):
    """Targets made by FK of random in-limit postures are reached within 0.5 mm, only the
    finger's joints move and the solution stays inside the limits."""
    hand = Hand.load(name)
    rng = np.random.default_rng(1)
    for f in hand.fingers.values():
        idx = list(f.q_index)
        for _ in range(5):
            q_true = hand.q_open.copy()
            q_true[idx] = rng.uniform(hand.lower[idx], hand.upper[idx])
            target = _pad_palm(hand, f.name, q_true)
            q = hand.ik(f.name, target, hand.q_open)
            assert np.linalg.norm(_pad_palm(hand, f.name, q) - target) < 5e-4
            others = np.setdiff1d(np.arange(hand.model.nq), idx)
            assert np.array_equal(q[others], hand.q_open[others])
            assert np.all(q >= hand.lower - 1e-12) and np.all(q <= hand.upper + 1e-12)


def test_ik_aligns_pad_normal_when_possible(icub):
    """With normal_palm set to the pad normal of an FK posture, IK returns a posture whose pad
    faces that direction within 5 degrees."""
    rng = np.random.default_rng(2)
    f = icub.fingers["index"]
    idx = list(f.q_index)
    for _ in range(5):
        q_true = icub.q_open.copy()
        q_true[idx] = rng.uniform(icub.lower[idx], icub.upper[idx])
        n = icub.state(q_true).link_pose(f.pad_link)[:3, :3] @ np.array(f.pad_n_link)
        q = icub.ik("index", _pad_palm(icub, "index", q_true), icub.q_open, normal_palm=n)
        n_got = icub.state(q).link_pose(f.pad_link)[:3, :3] @ np.array(f.pad_n_link)
        assert np.degrees(np.arccos(np.clip(n_got @ n, -1, 1))) < 5.0


def test_ik_refuses_unreachable_targets(icub):
    """A target far outside the finger's workspace raises KinematicsError."""
    with pytest.raises(KinematicsError, match="index"):
        icub.ik("index", [0.2, 0.0, 0.0], icub.q_open)
    with pytest.raises(KinematicsError):
        icub.ik("thumb", [-0.06, 0.03, -0.05], icub.q_open)   # under the palm, behind it


@pytest.mark.parametrize("name", ["allegro_right", "icub_right"])
def test_ik_falls_back_to_position_only_when_the_normal_task_fails(name):
    """The pad asked to face away from where it can (the reverse of its normal at an FK
    posture): the normal task drags the clamped joints off the target, so the combined task
    misses it; the IK then reaches it position-only and says so (the issue's Allegro contacts
    refused as out of reach)."""
    from planner.ik import IK_TOL_M, _ik_starts

    hand = Hand.load(name)
    rng = np.random.default_rng(3)
    dropped = 0
    for f in hand.fingers.values():
        idx = list(f.q_index)
        q_true = hand.q_open.copy()
        q_true[idx] = hand.lower[idx] + rng.uniform(0.3, 0.7, len(idx)) * (hand.upper[idx] - hand.lower[idx])
        target = _pad_palm(hand, f.name, q_true)
        n_away = -(hand.state(q_true).link_pose(f.pad_link)[:3, :3] @ np.array(f.pad_n_link))
        r = hand.ik_solve(f.name, target, hand.q_open, normal_palm=n_away)
        assert np.linalg.norm(_pad_palm(hand, f.name, r.q) - target) < IK_TOL_M
        # position-only runs only after the combined task failed; then the normal is far off
        combined = _ik_starts(hand.kinematics(hand.q_open),
                              [hand.q_open[idx], np.array(f.q_open), 0.5 * (hand.lower[idx] + hand.upper[idx])],
                              hand.q_open, f, hand.lower[idx], hand.upper[idx],
                              hand._fid(f.pad_link), np.array(f.pad_p_link), target, np.array(f.pad_n_link),
                              n_away, 150)
        if r.normal_dropped:
            dropped += 1
            assert combined[0] >= IK_TOL_M
            assert r.normal_error_rad > np.radians(30)
    assert dropped >= 1


def test_unreachable_target_reports_the_closest_point_and_direction(icub):
    """The error carries the closest point reached and the unit direction from the target to it."""
    from planner.ik import UnreachableError

    with pytest.raises(UnreachableError) as info:
        icub.ik("index", [0.2, 0.0, 0.0], icub.q_open)
    e = info.value
    assert np.isclose(np.linalg.norm(e.direction_palm), 1.0) and e.distance_m > 0.05
    np.testing.assert_allclose(e.target_palm + e.distance_m * e.direction_palm, e.closest_palm, atol=1e-9)
    assert e.direction_palm[0] < -0.5  # back toward the hand
    assert "move the target" in str(e)


def test_bad_names_and_sizes(icub):
    """Unknown fingers/links list the valid names; wrong q sizes are InputError."""
    with pytest.raises(UnknownNameError, match="index, little, middle, ring, thumb"):
        icub.ik("pinky", [0, 0, 0], icub.q_open)
    with pytest.raises(UnknownNameError, match="index_distal"):
        icub.state(icub.q_open).link_pose("index_distl")
    with pytest.raises(InputError):
        icub.state(np.zeros(3)).link_pose("palm")
    with pytest.raises(UnknownNameError, match="icub_right"):
        Hand.load("no_such_hand")


def _write_spec(tmp_path: Path, text: str) -> Path:
    urdf = (ROBOTS_DIR / "icub_right" / "icub_right.urdf").resolve()
    path = tmp_path / "hand.yaml"
    path.write_text(text.replace("URDF", str(urdf)))
    return path


GOOD = """schema_version: 1
urdf: URDF
palm_frame: palm
fingers:
  index: {joints: [index_0, index_1, index_2, index_3], tip_frame: index_tip}
  thumb: {joints: [thumb_0, thumb_1, thumb_2, thumb_3], tip_frame: thumb_tip}
"""


def test_minimal_spec_locks_unlisted_joints(tmp_path):
    """A spec naming two fingers gives an 8-joint hand; default contact links are the finger links."""
    hand = Hand.load(_write_spec(tmp_path, GOOD))
    assert hand.model.nq == 8
    assert hand.fingers["index"].contact_links == ("index_proximal", "index_intermediate", "index_distal")


@pytest.mark.parametrize("text, key, words", [
    (GOOD.replace("palm_frame: palm\n", ""), "palm_frame", "missing"),
    (GOOD.replace("index_3]", "index_9]"), "fingers.index.joints", "index_3"),
    (GOOD.replace("tip_frame: index_tip", "tip_frame: index_tp"), "fingers.index.tip_frame", "index_tip"),
    (GOOD.replace("tip_frame: thumb_tip}", "tip_frame: thumb_tip, contact_links: [index_distal]}"),
     "fingers.thumb.contact_links", "thumb_distal"),
    (GOOD.replace("palm_frame: palm", "palm_frame: palmm"), "palm_frame", "palm"),
    (GOOD.replace("schema_version: 1", "schema_version: 7"), "schema_version", "supported"),
    (GOOD + "open: {index_1: 3.0}\n", "open.index_1", "expected a number"),
    (GOOD.replace("  index: {joints: [index_0, index_1, index_2, index_3], tip_frame: index_tip}\n",
                  "  index: {tip_frame: index_tip}\n"), "fingers.index.joints", "missing"),
])
def test_spec_errors_name_the_key(tmp_path, text, key, words):
    """Invalid hand specs raise SpecError with the file, the key path and the valid choices."""
    with pytest.raises(SpecError) as err:
        Hand.load(_write_spec(tmp_path, text))
    assert err.value.key == key
    assert words in str(err.value)
    assert str(tmp_path) in str(err.value)


#: GOOD with a pad on the thumb (its distal link).
PADDED = GOOD.replace("tip_frame: thumb_tip}", """tip_frame: thumb_tip,
          pad: {link: thumb_distal, point: [0.0103, 0.0, 0.0065], normal: [0.0, 0.0, 1.0]}}""")
#: PADDED with units written out.
WITH_UNITS = PADDED.replace("urdf: URDF", "units: {length: m, angle: rad}\nurdf: URDF")
#: The index finger's line in GOOD.
INDEX = "joints: [index_0, index_1, index_2, index_3], tip_frame: index_tip"


# Unknown keys of a hand.yaml (top level, a finger, its pad) are refused, naming the file,
# the key and the valid keys, as a grasp file's are: a misspelt `close_joint:` or
# `close_towards:` was ignored, and the finger then closed every joint upward without a word.
# `units:` other than metres and radians is refused (it was ignored too).
@pytest.mark.parametrize("old, new, key, words", [
    ("palm_frame: palm", "palm_frame: palm\nopen_posture: {thumb_0: 0.3}", "open_posture",
     "valid keys are schema_version, name, units, urdf"),
    ("tip_frame: index_tip}", "tip_frame: index_tip, close_joint: [index_1]}", "fingers.index.close_joint",
     "valid keys are joints, close_joints, close_toward, contact_links, tip_frame, pad"),
    ("normal: [0.0, 0.0, 1.0]}", "normal: [0.0, 0.0, 1.0], radius: 0.006}", "fingers.thumb.pad.radius",
     "valid keys are link, point, normal"),
    ("length: m", "length: mm", "units.length", "m and angles in rad, got 'mm'"),
    ("angle: rad", "angle: deg", "units.angle", "got 'deg'"),
    ("angle: rad", "angle: rad, mass: kg", "units.mass", "valid keys are length, angle"),
])
def test_unknown_keys_and_other_units_are_refused(tmp_path, old, new, key, words):
    _refused_naming(tmp_path, WITH_UNITS.replace(old, new, 1), key, words)


def _refused_naming(tmp_path, spec: str, key: str, words: str) -> None:
    """The hand.yaml ``spec`` is refused at ``key``, naming the file and saying ``words``."""
    with pytest.raises(SpecError) as err:
        Hand.load(_write_spec(tmp_path, spec))
    assert err.value.key == key
    assert words in str(err.value) and str(tmp_path) in str(err.value)


def test_the_bundled_and_a_written_spec_load(tmp_path):
    assert Hand.load(_write_spec(tmp_path, WITH_UNITS)).fingers["thumb"].pad_link == "thumb_distal"
    for name in ("icub_right", "allegro_right"):
        Hand.load(name)


# A finger's tip_frame and pad.link must move with that finger's joints: another finger's
# frame or the palm was accepted by `hand check` (0 errors), and every contact of the finger
# was then refused in the grasp file as out of reach. Now the hand.yaml is refused, naming the
# key and the finger's own links (frames).
@pytest.mark.parametrize("old, new, key, words", [
    ("link: thumb_distal", "link: index_distal", "fingers.thumb.pad.link", "links are thumb_base, thumb_proximal"),
    ("link: thumb_distal", "link: palm", "fingers.thumb.pad.link", "'palm' is not a link of finger thumb"),
    ("tip_frame: index_tip", "tip_frame: thumb_tip", "fingers.index.tip_frame", "index_distal"),
    ("tip_frame: index_tip", "tip_frame: palm", "fingers.index.tip_frame", "does not move with finger index"),
])
def test_a_tip_or_pad_of_another_finger_is_refused(tmp_path, old, new, key, words):
    _refused_naming(tmp_path, PADDED.replace(old, new, 1), key, words)


def test_the_finger_own_tip_and_pad_load(tmp_path):
    hand = Hand.load(_write_spec(tmp_path, PADDED))
    assert hand.fingers["thumb"].pad_link == "thumb_distal" and hand.fingers["index"].tip_frame == "index_tip"


# A hand.yaml's finger lists (joints, close_joints, contact_links) are refused empty or with
# a joint named twice, naming the file, the key and the valid choices (an empty close_joints
# list was accepted and `check` ended in an IndexError in the closing procedure).
@pytest.mark.parametrize("index, key, words", [
    ("joints: [], tip_frame: index_tip", "fingers.index.joints", "empty list"),
    ("joints: [index_0, index_1, index_1, index_3], tip_frame: index_tip", "fingers.index.joints",
     "'index_1' is named twice"),
    (INDEX + ", close_joints: []", "fingers.index.close_joints", "joints are index_0, index_1, index_2, index_3"),
    (INDEX + ", close_joints: [index_1, index_1]", "fingers.index.close_joints", "'index_1' is named twice"),
    (INDEX + ", contact_links: []", "fingers.index.contact_links",
     "links are index_proximal, index_intermediate, index_distal"),
])
def test_empty_or_repeated_finger_lists_are_refused(tmp_path, index, key, words):
    with pytest.raises(SpecError) as err:
        Hand.load(_write_spec(tmp_path, GOOD.replace(INDEX, index)))
    assert err.value.key == key
    assert words in str(err.value)
    assert str(tmp_path) in str(err.value)


def test_the_lists_left_out_still_default_to_the_whole_finger(tmp_path):
    finger = Hand.load(_write_spec(tmp_path, GOOD)).fingers["index"]
    assert finger.close_joints == finger.joints
    assert finger.contact_links == ("index_proximal", "index_intermediate", "index_distal")


# `disabled_collisions:` given as one name instead of a list of pairs is refused as such
# (it was read letter by letter: "expected [link_a, link_b], got 'p'").
@pytest.mark.parametrize("value, words", [
    ("palm", "expected a list of [link_a, link_b] pairs, got 'palm'"),
    ("{palm: index_distal}", "expected a list of [link_a, link_b] pairs"),
    ("[[palm]]", "expected [link_a, link_b], got ['palm']"),
])
def test_disabled_collisions_not_a_list_of_pairs(tmp_path, value, words):
    with pytest.raises(SpecError) as err:
        Hand.load(_write_spec(tmp_path, GOOD + f"disabled_collisions: {value}\n"))
    assert err.value.key == "disabled_collisions" and words in str(err.value)
