"""Contacts and collisions of hand configurations, and a hand-made iCub box grasp whose
patches are force closure with the thumb and not without it."""

from __future__ import annotations

import numpy as np
import pytest

from planner.contacts import TOUCH_TOL_M, collisions, contact_patches, touching_links
from planner.hand import Hand
from planner.model import Friction
from planner.objects import make_object


@pytest.fixture(scope="module")
def icub():
    return Hand.load("icub_right")


def _tilted_box(center, pitch_deg, size):
    """Box whose x axis e = (cos b, 0, -sin b): the thumb pushes along +e, the fingers along -e."""
    b = np.radians(pitch_deg)
    e, t = np.array([np.cos(b), 0.0, -np.sin(b)]), np.array([0.0, 1.0, 0.0])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([e, t, np.cross(e, t)])
    T[:3, 3] = center
    return make_object("box", size, T)


@pytest.fixture(scope="module")
def box_grasp(icub):
    """Thumb opposed to index and middle on a pitched box, each finger closed onto it (eqs. 8-9)."""
    obj = _tilted_box([0.04, -0.015, 0.045], 45.0, (0.024, 0.05, 0.05))
    q = icub.q_open.copy()
    q[icub.joint_names.index("thumb_0")] = 1.3
    assert collisions(icub, q, obj) == []
    for f in ("thumb", "index", "middle"):
        q = icub.close_finger(f, q, obj)
    return q, obj


def test_closing_stops_at_touch(icub, box_grasp):
    """After closing, each closed finger touches the object within tolerance and nothing
    penetrates it or another link."""
    q, obj = box_grasp
    touching = touching_links(icub, q, obj)
    assert set(touching) == {"thumb", "index", "middle"}
    assert collisions(icub, q, obj) == []
    for f in ("thumb", "index", "middle"):
        d = icub.state(q).finger_object_distance(obj, f)
        assert 0.0 <= d <= TOUCH_TOL_M


def test_patches_have_several_points_on_surface_with_inward_normals(icub, box_grasp):
    """Each touching finger has several patch points on the object surface, near the link, with
    unit normals equal to minus the outward surface normal."""
    q, obj = box_grasp
    patches = contact_patches(icub, q, obj)
    assert set(patches) == {"thumb", "index", "middle"}
    for p, n in patches.values():
        assert len(p) >= 3 and p.shape == n.shape
        for x, m in zip(p, n):
            ps, n_out, d = obj.closest_surface(x)
            assert abs(d) < 1e-9
            assert np.allclose(m, -n_out)
    # the thumb pushes along +x of the object, the fingers along -x
    assert np.allclose(patches["thumb"][1], [1.0, 0.0, 0.0])
    assert np.allclose(patches["index"][1], [-1.0, 0.0, 0.0])


def test_box_grasp_force_closure_with_thumb_and_not_without(icub, box_grasp):
    """The thumb-index-middle box grasp is force closure; lifting the thumb breaks it."""
    closure = pytest.importorskip("planner.closure")
    q, obj = box_grasp
    friction = Friction(mu=0.5, gamma=0.005)
    assert closure.grasp_closure(contact_patches(icub, q, obj), friction).is_force_closure
    lifted = q.copy()
    idx = list(icub.fingers["thumb"].q_index)
    lifted[idx] = icub.q_open[idx]
    patches = contact_patches(icub, lifted, obj)
    assert "thumb" not in patches
    result = closure.grasp_closure(patches, friction)
    assert not result.is_force_closure and result.metric <= 0


def test_patches_follow_the_object(icub, box_grasp):
    """Patches are in the object frame: moving the object 0.1 m away removes them all, and a
    box rotated about its own x axis by 180 degrees (same surface) gives the mirrored points."""
    q, obj = box_grasp
    T = obj.T_palm_obj.copy()
    T[2, 3] += 0.1
    assert contact_patches(icub, q, obj.with_pose(T)) == {}
    flip = obj.with_pose(obj.T_palm_obj @ np.diag([1.0, -1.0, -1.0, 1.0]))
    a, b = contact_patches(icub, q, obj), contact_patches(icub, q, flip)
    assert a.keys() == b.keys()
    for k in a:
        assert np.allclose(np.sort(a[k][0] * [1, -1, -1], axis=0), np.sort(b[k][0], axis=0), atol=1e-9)


def test_collisions_detect_penetration(icub):
    """A box through the index finger is an object collision; ring abducted into little at full
    flexion are link collisions; the open hand alone has none."""
    assert collisions(icub, icub.q_open) == []
    q = icub.q_open.copy()
    T = np.eye(4)
    T[:3, 3] = icub.state(q).link_pose("index_intermediate")[:3, 3]
    hits = collisions(icub, q, make_object("box", (0.02, 0.02, 0.02), T))
    assert any(b == "object" and a.startswith("index") and depth > TOUCH_TOL_M for a, b, depth in hits)
    q = icub.q_open.copy()
    q[icub.joint_names.index("ring_0")] = np.radians(20)
    q[icub.joint_names.index("little_0")] = 0.0
    hits = collisions(icub, q)
    assert any({a.split("_")[0], b.split("_")[0]} == {"ring", "little"} for a, b, _ in hits)
    assert collisions(icub, q, fingers=["index"]) == []


def test_close_finger_without_object_in_the_way_closes_fully(icub):
    """A finger that never meets the object closes to (almost) its upper limits."""
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 0.3]
    q = icub.close_finger("middle", icub.q_open, make_object("sphere", (0.01,), T))
    idx = [icub.joint_names.index(j) for j in icub.fingers["middle"].close_joints]
    assert np.allclose(q[idx], icub.upper[idx], atol=1e-4)


def test_allegro_closing_touches_a_sphere():
    """On the Allegro hand, closing the index onto a sphere in front of the palm ends touching it."""
    hand = Hand.load("allegro_right")
    f = hand.fingers["index"]
    q_mid = hand.q_open.copy()
    for j in f.close_joints:
        q_mid[hand.joint_names.index(j)] = 0.6
    T_pad = hand.state(q_mid).link_pose(f.pad_link)
    p = T_pad[:3, :3] @ np.array(f.pad_p_link) + T_pad[:3, 3]
    n = T_pad[:3, :3] @ np.array(f.pad_n_link)
    T = np.eye(4)
    T[:3, 3] = p + 0.02 * n          # a 20 mm sphere just in front of the half-closed pad
    obj = make_object("sphere", (0.02,), T)
    q = hand.close_finger("index", hand.q_open, obj)
    assert "index" in touching_links(hand, q, obj)
    assert collisions(hand, q, obj, fingers=["index"]) == []
    assert "index" in contact_patches(hand, q, obj)


def test_ik_placement_then_closing_touches_without_penetration(icub, box_grasp):
    """Placing the middle pad on the box by IK (pad normal toward the face) and then running the
    closing procedure leaves it touching within tolerance and not penetrating."""
    q, obj = box_grasp
    idx = list(icub.fingers["middle"].q_index)
    q0 = q.copy()
    q0[idx] = icub.q_open[idx]
    R, t = obj.T_palm_obj[:3, :3], obj.T_palm_obj[:3, 3]   # object y axis = palm y axis
    # on the +x face, in the middle finger's flexion plane (the finger has no abduction)
    f = icub.fingers["middle"]
    T_pad = icub.state(q0).link_pose(f.pad_link)
    y_plane = (T_pad[:3, :3] @ np.array(f.pad_p_link) + T_pad[:3, 3])[1]
    p_obj = np.array([0.012, y_plane - t[1], 0.0])
    q1 = icub.ik("middle", R @ p_obj + t, q0, normal_palm=R @ [-1.0, 0.0, 0.0])
    q2 = icub.close_finger("middle", q1, obj)
    d = icub.state(q2).finger_object_distance(obj, "middle")
    assert 0.0 <= d <= TOUCH_TOL_M
    assert "middle" in contact_patches(icub, q2, obj)
