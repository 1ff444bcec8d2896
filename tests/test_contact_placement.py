"""Contacts where asked (issue 36 item 1): a ``contact:`` point is realized by the asked link
within `CONTACT_TOL_M` with its pad facing the surface within 45 deg (IK over the pad's
position and orientation, then along the normal); when it is not, the reason names the
failing constraint and the proposed point is realized by the same code."""

from __future__ import annotations

import importlib.util
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.contacts import collisions, link_contacts
from planner.hand import Hand
from planner.ik import UnreachableError
from planner.objects import GraspObject, make_object
from planner.realization import (CONTACT_TOL_M, CONTACT_WARN_M, PAD_FACING_RAD, PENETRATION_TOL_M, _place_verified,
                                  _verify, place_contact)

_BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_contact_placement.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_contact_placement", _BENCH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def bench():
    return _bench()


@pytest.fixture(scope="module", params=["icub_right", "allegro_right"])
def hand(request):
    return Hand.load(request.param)


def _realized(hand, f, obj, point, q):
    """(landing error m of the pad link, pad-normal error rad, deepest finger penetration m)."""
    mine = [c for c in link_contacts(hand, q, obj, fingers=[f.name]) if c.link == f.pad_link]
    land = min((float(np.linalg.norm(c.point - point)) for c in mine), default=math.inf)
    T = np.asarray(obj.T_palm_obj)
    _, n_out, _ = obj.closest_surface(point)
    kin = hand.kinematics(q)
    R = kin.frame_pose(hand.collision.kinematic_model.frame_id(f.pad_link))[:3, :3]
    nerr = math.acos(float(np.clip((R @ np.array(f.pad_n_link)) @ -(T[:3, :3] @ n_out), -1.0, 1.0)))
    deep = max((d for _, _, d in collisions(hand, q, obj, fingers=[f.name], touch_tol_m=PENETRATION_TOL_M)), default=0.0)
    return land, nerr, deep


def _point_in(msg):
    m = re.search(r"a surface point it does reach \(checked\): \[([-0-9., ]+)\]", msg)
    return None if m is None else np.array([float(v) for v in m.group(1).split(",")])


def test_reachable_points_are_realized_by_the_asked_link(hand, bench):
    """Points reachable by construction (a random posture touching a sphere, box or cylinder
    with the pad within 30 deg) are touched by the pad link within 2 mm, the pad within 45 deg,
    nothing of the finger deeper than the penetration tolerance; only that finger moves."""
    rng = np.random.default_rng(7)
    done = 0
    while done < 4:
        case = bench.sample_case(hand, rng)
        if case is None:
            continue
        f, obj, point = case
        q, patch, notes = place_contact(hand, obj, f, point, hand.q_open)
        land, nerr, deep = _realized(hand, f, obj, point, q)
        failed = [n for n in notes if "not realized as asked" in n]
        if failed:  # a few are not (the benchmark's 2-4 %): the reason and a realized point, or none
            assert re.search(r"(orientation|collision|landing):", failed[0]), failed
            hint = _point_in(failed[0])
            if hint is not None:
                q, _, _ = place_contact(hand, obj, f, hint, hand.q_open)
                land, nerr, deep = _realized(hand, f, obj, hint, q)
                assert land <= CONTACT_TOL_M and nerr <= PAD_FACING_RAD and deep <= PENETRATION_TOL_M
            continue
        assert land <= CONTACT_TOL_M
        assert nerr <= PAD_FACING_RAD + 1e-9
        assert deep <= PENETRATION_TOL_M
        assert patch is not None
        others = [i for i in range(len(q)) if i not in f.q_index]
        np.testing.assert_array_equal(q[others], np.asarray(hand.q_open)[others])
        done += 1


def test_sphere_pad_lands_on_the_point_exactly():
    """The Allegro tip is a 12 mm sphere: its centre placed at point + r n touches the
    tangent plane at the point, whatever the tilt, so a tilted request lands within a tenth of
    a millimetre."""
    hand = Hand.load("allegro_right")
    f = hand.fingers["index"]
    q = np.array(hand.q_open, dtype=float)
    q[list(f.q_index)] = [0.1, 0.6, 0.5, 0.4]
    kin = hand.kinematics(q)
    _, c, _ = kin.frame_jacobian(hand.collision.kinematic_model.frame_id(f.pad_link), np.zeros(3))
    _, p_pad, R = kin.frame_jacobian(hand.collision.kinematic_model.frame_id(f.pad_link), np.array(f.pad_p_link))
    n_pad = R @ np.array(f.pad_n_link)
    tilt = np.cross(n_pad, [0.0, 1.0, 0.0])
    n_in = n_pad * math.cos(0.3) + tilt / np.linalg.norm(tilt) * math.sin(0.3)
    p = c + 0.012 * n_in + 1e-4 * n_in  # where the tip sphere meets a plane of normal -n_in
    T = np.eye(4)
    T[:3, 3] = p + 0.03 * n_in
    obj = make_object("sphere", [0.03], T)
    point = np.asarray(obj.closest_surface(p - T[:3, 3])[0])
    placed = _place_verified(hand, obj, f, point, hand.q_open, None)
    assert placed.why is None
    land, nerr, deep = _realized(hand, f, obj, point, placed.q)
    assert land < 2e-4, land
    assert nerr <= PAD_FACING_RAD
    assert deep <= PENETRATION_TOL_M
    # place_contact takes it, or the closing procedure's placement when that lands within the
    # check's warning distance with as many links touching
    q2, _, notes = place_contact(hand, obj, f, point, hand.q_open)
    assert _realized(hand, f, obj, point, q2)[0] <= CONTACT_WARN_M and not notes


#: Points a few millimetres beyond a finger's reach (found by pushing reachable points of the
#: benchmark along the face): (hand, finger, object block, point in the object frame).
BEYOND_REACH = [
    ("icub_right", "thumb", {"shape": "box", "size": [0.04470981381587795, 0.048556348776725156, 0.04326698874436879],
                             "position": [0.03910122624268878, 0.012006087691897274, 0.02800810207481111],
                             "quat_xyzw": [-0.3892077814205476, -0.09384206641632269, 0.8728344224828913,
                                           -0.2790538306158281]},
     [-0.00701, -0.00088, 0.02163]),
    ("allegro_right", "middle", {"shape": "box", "size": [0.04949274369901098, 0.06533262055501923, 0.03440664219051929],
                                 "position": [0.07063325626178266, -0.0018108909306283596, 0.053687737577598454],
                                 "quat_xyzw": [-0.10472565335752389, -0.07641290835834057, 0.9457303176595597,
                                               0.29797276926693783]},
     [-0.0146, 0.02634, 0.0172]),
]


@pytest.mark.parametrize("hand_name,finger,block,point", BEYOND_REACH)
def test_out_of_reach_names_reach_and_proposes_a_realized_point(hand_name, finger, block, point):
    """A point just beyond the finger's reach raises with the constraint (reach) and a point
    that `place_contact` does realize as asked (the same code, from the same seed)."""
    hand = Hand.load(hand_name)
    obj = GraspObject.from_data(block)
    with pytest.raises(UnreachableError) as e:
        place_contact(hand, obj, finger, np.array(point), hand.q_open)
    msg = str(e.value)
    assert msg.startswith("reach:"), msg
    hint = _point_in(msg)
    assert hint is not None, msg
    f = hand.fingers[finger]
    q, _, notes = place_contact(hand, obj, f, hint, hand.q_open)
    land, nerr, deep = _realized(hand, f, obj, hint, q)
    assert land <= CONTACT_TOL_M and nerr <= PAD_FACING_RAD and deep <= PENETRATION_TOL_M, notes
    assert not any("not realized" in n for n in notes)


def test_far_out_of_reach_says_move_the_object():
    """Nothing near the point is realized: the error says so and which way to move the object."""
    hand = Hand.load("icub_right")
    T = np.eye(4)
    T[:3, 3] = [0.03, 0.0, 0.06]
    obj = make_object("box", [0.03, 0.09, 0.04], T)
    with pytest.raises(UnreachableError) as e:
        place_contact(hand, obj, "index", np.array([0.0, 0.044, -0.02]), hand.q_open)
    assert str(e.value).startswith("reach:")
    assert "no surface point near it is realized: move the object toward the finger" in str(e.value)


def test_a_point_the_pad_cannot_face_names_orientation():
    """A point the Allegro thumb's tip reaches only facing away (position-only IK gets there,
    the pad within 45 deg does not): placed as before, with the failing constraint
    (orientation) and a proposed point realized as asked by the same code, or none."""
    hand = Hand.load("allegro_right")
    obj = GraspObject.from_data({"shape": "box", "size": [0.07470109283036071, 0.05005626999443798, 0.04351804070730557],
                                 "position": [0.06811880825147802, 0.05590375172194079, -0.04601871091238745],
                                 "quat_xyzw": [-0.5872289861384696, 0.49781654176414447, 0.04923078045012557,
                                               0.6363309978627826]})
    f = hand.fingers["thumb"]
    q, _, notes = place_contact(hand, obj, f, np.array([-0.00762, 0.02503, 0.02176]), hand.q_open)
    failed = [n for n in notes if "not realized as asked" in n]
    assert failed and "orientation: link_15.0_tip reaches the point only with its pad facing away" in failed[0], notes
    hint = _point_in(failed[0])
    if hint is None:
        assert "no surface point within 20 mm is realized" in failed[0]
    else:
        q, _, notes = place_contact(hand, obj, f, hint, hand.q_open)
        land, nerr, deep = _realized(hand, f, obj, hint, q)
        assert land <= CONTACT_TOL_M and nerr <= PAD_FACING_RAD and deep <= PENETRATION_TOL_M, notes


def test_verify_names_the_colliding_link():
    """A finger pushed into the object: the check names the penetrating link first."""
    hand = Hand.load("allegro_right")
    f = hand.fingers["index"]
    q = np.array(hand.q_open, dtype=float)
    g = next(g for g in hand.collision.geometries if g.link == "link_2.0")
    kin = hand.kinematics(q)
    T_link = kin.frame_pose(hand.collision.kinematic_model.frame_id("link_2.0"))
    T = np.eye(4)
    T[:3, 3] = T_link[:3, :3] @ np.asarray(g.center) + T_link[:3, 3]  # a ball around the middle phalanx
    obj = make_object("sphere", [0.01], T)
    point = obj.closest_surface(np.array([0.0, 0.0, 0.01]))[0]
    n_out_palm = np.array([0.0, 0.0, 1.0])
    check = _verify(hand, obj, f, f.pad_link, q, point, n_out_palm)
    assert check.why is not None and check.why.startswith("collision: link_")
    assert "inside the object" in check.why
