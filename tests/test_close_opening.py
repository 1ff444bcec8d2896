"""The closing procedure's opening of a penetrating finger skips the steps a penetration depth
proves inside (`planner.ik.opening_reach`, `planner.collision.HandState.finger_penetration`):
the same posture, to the bit, as checking every 0.1 % step; and the reach per step bounds how
far the finger's geometry really moves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import planner.ik as ik
from planner.collision import HandState
from planner.hand import Hand
from planner.objects import GraspObject

ROOT = Path(__file__).resolve().parents[1]
HANDS = ("icub_right", "allegro_right", str(ROOT / "tests/data/coupled_hand/hand.yaml"))


def _objects(hand):
    """A sphere, a box, a cylinder and a mesh ellipsoid among the fingers (above the palm)."""
    c = np.mean([hand.kinematics(hand.q_open).frame_pose(hand.kinematics(hand.q_open).kinematic_model.frame_id(
        f.pad_link))[:3, 3] for f in hand.fingers.values()], axis=0)
    pos = [float(v) for v in c]
    mesh = ROOT / "experiments/results/exp9_pairs_v2/meshes/ellipsoid.obj"
    out = [GraspObject.from_data({"shape": "sphere", "size": [0.03], "position": pos, "quat_xyzw": [0, 0, 0, 1]}),
           GraspObject.from_data({"shape": "box", "size": [0.05, 0.04, 0.06], "position": pos,
                                  "quat_xyzw": [0.1, 0.2, 0.0, 0.974679]}),
           GraspObject.from_data({"shape": "cylinder", "size": [0.02, 0.09], "position": pos,
                                  "quat_xyzw": [0.7071, 0.0, 0.0, 0.7071]}),
           GraspObject.from_data({"shape": "mesh", "size": [1.0], "mesh": mesh.name, "position": pos,
                                  "quat_xyzw": [0, 0, 0, 1]},
                                 base_dir=mesh.parent)]
    return out


def _scan(hand, finger, q, obj, monkeypatch):
    """`close_finger` checking every opening step (no depth bound)."""
    with monkeypatch.context() as m:
        m.setattr(ik, "opening_reach", lambda *a, **k: None)
        return ik.close_finger(hand, finger, q, obj)


@pytest.mark.parametrize("hand_ref", HANDS)
def test_opening_with_the_depth_bound_ends_where_the_scan_does(hand_ref, monkeypatch):
    """Random finger postures (most penetrate the object, some deeply) closed on four object
    shapes: the posture is the scan's to the bit."""
    hand = Hand.load(hand_ref)
    rng = np.random.default_rng(7)
    n = penetrating = 0
    for obj in _objects(hand):
        sphere = ik.object_sphere(obj)
        for name, f in hand.fingers.items():
            idx = list(f.q_index)
            for _ in range(6):
                q = np.array(hand.q_open, float)
                q[idx] = rng.uniform(hand.lower[idx], hand.upper[idx])
                q = ik.couple_finger(f, q)
                penetrating += HandState(hand.collision, q).finger_penetrates(obj, name, sphere)
                a, b = _scan(hand, name, q, obj, monkeypatch), ik.close_finger(hand, name, q, obj)
                assert np.array_equal(a, b), (hand_ref, obj.shape, name)
                n += 1
    assert penetrating >= n // 5  # the opening branch is exercised


@pytest.mark.parametrize("hand_ref", HANDS)
def test_reach_per_step_bounds_the_geometry_motion(hand_ref):
    """Every point of a finger's geometry (its bounding sphere's centre and 6 points on it)
    moves no farther than `opening_reach` when the closing joints move by one step, at random
    postures."""
    hand = Hand.load(hand_ref)
    rng = np.random.default_rng(3)
    for name, f in hand.fingers.items():
        cidx = np.array(ik.closing_drivers(hand, f))
        step = 1e-3 * (hand.upper[cidx] - hand.lower[cidx])
        reach = ik.opening_reach(hand, f, cidx, step)
        assert reach is not None and set(reach) == set(hand.collision.finger_geometries(name))
        for _ in range(20):
            q = np.array(hand.q_open, float)
            q[list(f.q_index)] = rng.uniform(hand.lower[list(f.q_index)], hand.upper[list(f.q_index)])
            q = ik.couple_finger(f, q)
            q2 = q.copy()
            q2[cidx] += step * rng.choice([-1.0, 1.0], size=len(cidx))
            q2 = ik.couple_finger(f, q2)
            a, b = HandState(hand.collision, q), HandState(hand.collision, q2)
            for i, v in reach.items():
                g = hand.collision.geometries[i]
                offsets = np.vstack([np.zeros(3), g.radius_m * np.vstack([np.eye(3), -np.eye(3)])])
                pa = a.kinematics.joint_placement(g.joint_id)
                pb = b.kinematics.joint_placement(g.joint_id)
                for o in offsets:
                    x = g.center + o
                    assert np.linalg.norm(pb.act(x) - pa.act(x)) <= v * (1 + 1e-9) + 1e-12
