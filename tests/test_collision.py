"""The collision layer (planner/collision.py): analytic distances on a one-joint toy hand,
and the bundled hands' allowed pairs, open postures and `HandState.with_finger`."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import pytest

from planner.collision import CollisionModel, Geometry
from planner.errors import InputError
from planner.grasp import load_hand
from planner.objects import make_object

BASE_X = 0.05      # the finger joint (z axis) sits at (BASE_X, 0, 0) in the palm frame
ARM_M = 0.03       # the tip sphere's centre is ARM_M along the joint's x axis
TIP_R = 0.005
PALM_R = 0.03


def _sphere(index, link, finger, radius, joint_id, offset):
    shape = coal.Sphere(radius)
    shape.computeLocalAABB()
    plc = pin.SE3(np.eye(3), np.asarray(offset, dtype=float))
    return Geometry(index, link, finger, shape, joint_id, plc, plc.act(np.array(shape.aabb_center)),
                    float(shape.aabb_radius))


@pytest.fixture(scope="module")
def toy():
    """A palm sphere (radius PALM_R at the origin) and a one-joint finger "f" ending in a sphere."""
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([BASE_X, 0.0, 0.0])), "j1")
    model.addBodyFrame("palm", 0, pin.SE3.Identity(), 0)
    model.addBodyFrame("tip", j, pin.SE3.Identity(), 0)
    geoms = [_sphere(0, "palm", None, PALM_R, 0, [0.0, 0.0, 0.0]),
             _sphere(1, "tip", "f", TIP_R, j, [ARM_M, 0.0, 0.0])]
    return CollisionModel(model, pin.SE3.Identity(), geoms, {"f": (0,)}, allowed=())


def _tip(theta):
    return np.array([BASE_X + ARM_M * np.cos(theta), ARM_M * np.sin(theta), 0.0])


def _pose(position):
    T = np.eye(4)
    T[:3, 3] = position
    return T


@pytest.mark.parametrize("theta", [0.0, 0.7, 2.0, np.pi])
def test_sphere_sphere_distance_is_centre_distance_minus_radii(toy, theta):
    """The palm-tip signed distance is |c_tip - c_palm| - r_tip - r_palm at every joint angle,
    negative (penetration) when the finger folds back onto the palm."""
    state = toy.state([theta])
    (a, b, d), = state.link_pair_distances(margin_m=1.0)
    assert (a, b) == ("palm", "tip")
    expect = np.linalg.norm(_tip(theta)) - TIP_R - PALM_R
    assert d == pytest.approx(expect, abs=1e-9)
    depths = state.self_collisions()
    assert depths == ([] if expect > 0 else [("palm", "tip", pytest.approx(-expect, abs=1e-9))])


def test_box_at_known_offset(toy):
    """A box face 25 mm from the tip sphere reads 25 mm with witness points on the sphere and the
    face; moved 27 mm closer it reads 2 mm of penetration; the finger's clearance follows."""
    half = 0.01
    for face_x, expect in ((0.11, 0.025), (0.083, -0.002)):
        obj = make_object("box", (2 * half, 2 * half, 2 * half), _pose([face_x + half, 0.0, 0.0]))
        state = toy.state([0.0])
        ld = state.link_object(obj, ["tip", "no_such_link"])
        assert list(ld) == ["tip"]
        assert ld["tip"].distance_m == pytest.approx(expect, abs=1e-7)
        assert state.finger_object_distance(obj, "f") == ld["tip"].distance_m
        if expect > 0:
            np.testing.assert_allclose(ld["tip"].p_link_palm, [BASE_X + ARM_M + TIP_R, 0, 0], atol=1e-9)
            np.testing.assert_allclose(ld["tip"].p_obj_palm, [face_x, 0, 0], atol=1e-9)
        for margin in (-0.003, -0.001, 0.0, 0.02, 0.03):
            assert state.clearance(obj, "f", margin) == (expect >= margin), (face_x, margin)
        (d, link, _, _), = state.object_distances(obj, "f")
        assert link == "tip" and d == pytest.approx(expect, abs=1e-7)


def test_state_is_immutable_and_independent_of_query_order(toy):
    """q is copied and read-only, and a state answers the same after another state's queries
    (its lazy FK is not a stale pinocchio.Data)."""
    q = np.array([0.3])
    a, b = toy.state(q), toy.state([2.5])
    q[0] = 1.0
    assert a.q[0] == 0.3 and not a.q.flags.writeable
    d_a = a.link_pair_distances(margin_m=1.0)
    b.link_pair_distances(margin_m=1.0)
    fresh = toy.state([0.3])
    assert a.link_pair_distances(margin_m=1.0) == d_a == fresh.link_pair_distances(margin_m=1.0)
    assert toy.state([0.3]).center(1) == pytest.approx(_tip(0.3))
    with pytest.raises(InputError):
        toy.state([0.0, 1.0])


@pytest.mark.parametrize("hand_name", ["icub_right", "allegro_right"])
def test_allowed_pairs_are_symmetric_and_never_checked(hand_name):
    """Allowed pairs are symmetric, include every parent-child link pair, and no checked geometry
    pair is an allowed pair, a pair on one link or a palm-palm pair."""
    hand = load_hand(hand_name)
    cm = hand.collision
    for a in cm.links:
        for b in cm.links:
            assert cm.is_allowed(a, b) == cm.is_allowed(b, a)
    joint = {g.link: g.joint_id for g in cm.geometries}
    for a in cm.links:
        for b in cm.links:
            if a != b and hand.model.parents[joint[a]] == joint[b]:
                assert cm.is_allowed(a, b)
    assert cm.pairs
    for i, j in cm.pairs:
        gi, gj = cm.geometries[i], cm.geometries[j]
        assert i < j and gi.link != gj.link and not cm.is_allowed(gi.link, gj.link)
        assert gi.finger is not None or gj.finger is not None
        assert cm.is_checked(i, j) and cm.is_checked(j, i)


@pytest.mark.parametrize("hand_name", ["icub_right", "allegro_right"])
def test_self_collisions_empty_at_the_open_posture(hand_name):
    """The open posture is free of self-collisions (its overlaps are allowed by design)."""
    hand = load_hand(hand_name)
    assert hand.state(hand.q_open).self_collisions() == []


def test_self_collision_found_when_two_fingers_cross():
    """iCub: the little finger abducted onto the flexed ring finger is a self-collision
    involving both (so the empty answer above can fail)."""
    hand = load_hand("icub_right")
    q = np.array(hand.q_open)
    for joint, value in (("ring_1", 1.2), ("little_1", 0.4), ("little_0", hand.lower[hand.joint_names.index("little_0")])):
        q[hand.joint_names.index(joint)] = value
    q[hand.joint_names.index("ring_0")] = hand.upper[hand.joint_names.index("ring_0")]
    hits = hand.state(q).self_collisions()
    assert any({"ring", "little"} <= {a.split("_")[0], b.split("_")[0]} for a, b, _ in hits), hits
    assert all(depth > 0 for _, _, depth in hits)


@pytest.mark.parametrize("hand_name", ["icub_right", "allegro_right"])
def test_with_finger_equals_a_fresh_state(hand_name):
    """Moving one finger with `with_finger` gives the same geometry poses, link-object distances,
    clearance answers and self-collisions as a fresh state at the same q (to 1e-12)."""
    hand = load_hand(hand_name)
    obj = make_object("sphere", (0.02,), _pose([0.05, 0.0, 0.06]))
    rng = np.random.default_rng(11)
    base = hand.state(hand.q_open)
    for finger, f in hand.fingers.items():
        idx = list(f.q_index)
        for _ in range(3):
            q_f = rng.uniform(hand.lower[idx], hand.upper[idx])
            moved = base.with_finger(finger, q_f)
            q = np.array(hand.q_open)
            q[idx] = q_f
            fresh = hand.state(q)
            np.testing.assert_array_equal(moved.q, fresh.q)
            for g in hand.collision.geometries:
                a, b = moved.transform(g.index), fresh.transform(g.index)
                np.testing.assert_allclose(a.getTranslation(), b.getTranslation(), atol=1e-12)
                np.testing.assert_allclose(a.getRotation(), b.getRotation(), atol=1e-12)
            d_m = {k: v.distance_m for k, v in moved.link_object(obj, hand.links).items()}
            d_f = {k: v.distance_m for k, v in fresh.link_object(obj, hand.links).items()}
            assert d_m.keys() == d_f.keys()
            np.testing.assert_allclose(list(d_m.values()), list(d_f.values()), atol=1e-12)
            for margin in (-0.001, 0.0, 0.002):
                assert moved.clearance(obj, finger, margin) == fresh.clearance(obj, finger, margin)
            assert [c[:2] for c in moved.self_collisions()] == [c[:2] for c in fresh.self_collisions()]
            again = moved.with_finger(finger, hand.q_open[idx])
            np.testing.assert_allclose(again.finger_link_poses(finger), base.finger_link_poses(finger), atol=1e-12)


def test_a_finger_path_may_overlap_the_hand_as_much_as_a_grasp_may():
    """The Allegro thumb's link_14.0 goes 0.06 mm into palm_link at a posture of a realized
    grasp (exp9's mesh pair): a finger state that deep is clear (`check` accepts a grasp
    with 0.5 mm, the audit a plan: `HAND_OVERLAP_TOL_M`), one 7 mm deep is not, and the
    reasons name only the deep one; the object is far away in both."""
    from planner.collision import HAND_OVERLAP_TOL_M
    from planner.objects import make_object
    from planner.realization import PENETRATION_TOL_M

    assert HAND_OVERLAP_TOL_M == PENETRATION_TOL_M
    hand = load_hand("allegro_right")
    idx = list(hand.fingers["thumb"].q_index)
    T = np.eye(4)
    T[:3, 3] = (0.3, 0.3, 0.3)
    far = make_object("sphere", (0.02,), T)
    for posture, depth_mm, clear in (((0.356, 0.723, 1.478, 0.636), 0.065, True), ((0.8, -0.1, 1.478, 0.636), 7.2, False)):
        q = np.array(hand.q_open, dtype=float)
        q[idx] = posture
        state = hand.state(q)
        overlap = -min(d for a, b, d in state.link_pair_distances(fingers={"thumb"}) if "palm_link" in (a, b))
        assert overlap * 1e3 == pytest.approx(depth_mm, abs=0.05)
        assert state.clearance(far, "thumb", 0.002) is clear
        assert bool(state.clearance_violations(far, "thumb", 0.002)) is not clear


@pytest.mark.parametrize("hand_name", ["icub_right", "allegro_right"])
def test_clearance_without_the_other_fingers_is_never_stricter(hand_name):
    """`clearance(..., others=False)`: the hand as if it had only the moving finger and the palm.
    Random postures of every finger among the others at random postures: clear with the other
    fingers means clear without them; the postures that differ (some must, the fingers cross)
    are exactly those whose only violations are with another finger's links."""
    hand = load_hand(hand_name)
    obj = make_object("sphere", (0.02,), _pose([0.05, 0.0, 0.06]))
    rng = np.random.default_rng(3)
    lower, upper = np.asarray(hand.lower), np.asarray(hand.upper)
    differ = 0
    for _ in range(40):
        base = hand.state(rng.uniform(lower, upper))
        for finger, f in hand.fingers.items():
            idx = list(f.q_index)
            st = base.with_finger(finger, rng.uniform(lower[idx], upper[idx]))
            with_others, alone = st.clearance(obj, finger, 0.002), st.clearance(obj, finger, 0.002, others=False)
            assert alone or not with_others
            if alone != with_others:
                differ += 1
                own = set(hand.collision.finger_links(finger))
                others = {g.link for g in hand.collision.geometries if g.finger not in (None, finger)}
                for line in st.clearance_violations(obj, finger, 0.002):
                    assert any(f" {link} " in f" {line} " for link in others), line
                    assert not any(f"penetrates {link} " in f"{line} " for link in own), line
                assert st.clearance_violations(obj, finger, 0.002, others=False) == []
    assert differ > 0
