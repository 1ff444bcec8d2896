"""The physics seam's contract (`planner.sim.engine.PhysicsEngine`), checked on every engine
behind it: names, frames, units and the directions of what it reports.

Each test builds the bundled schema-2 cylinder plan's world (`planner.sim.inputs.replay_world`)
and checks one promise of the interface with mechanics: state read back as written, the
object's rotation matrix agreeing with its quaternion, contact normals pointing INTO the
object, a held object staying put and a released one falling as g t^2 / 2, a joint torque
accelerating its joint and a raised link inertia accelerating it less.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.sim import inputs as inp
from planner.sim.controller import TOUCH_TOL_M
from planner.sim.engine import engine_for

PLAN = Path(__file__).parent / "data" / "plans" / "schema2_cylinder_execution.json"
ENGINES = ["pybullet", "mujoco"]  # each skips where its package is not installed
DT = 1.0 / 240.0


@pytest.fixture(scope="module")
def plan():
    rd = inp.typed_plan(PLAN)
    info = inp.load_hand_info(rd, list(rd.joints))
    mass, _ = inp.object_mass(rd.object, 500)
    return rd, info, inp.replay_world(info, rd.object, mass, rd.friction, DT, 150)


@pytest.fixture(params=ENGINES)
def engine(request, plan):
    pytest.importorskip(request.param)
    eng = engine_for(request.param, plan[2])
    yield eng
    eng.close()


def test_topology_names_the_hands_joints_and_links(engine, plan):
    """The movable joints are the hand's; every link but the root hangs from a joint of a
    parent link; the pad of every finger belongs to that finger."""
    rd, info, _ = plan
    topo = engine.topology
    assert set(topo.joints) == set(info.hand.joint_names)
    assert topo.root == topo.links[0] and topo.root not in topo.parent
    assert set(topo.parent) == set(topo.links[1:])
    assert all(parent in topo.links for _, parent in topo.parent.values())
    owner = topo.link_owner({j: f for f, js in info.fingers.items() for j in js}, "palm")
    for f, fg in info.hand.fingers.items():
        assert owner[fg.pad_link] == f
    assert owner[topo.root] == "palm"
    masses = engine.link_masses()
    assert set(masses) == set(topo.links)
    assert all(masses[fg.pad_link] > 0 for fg in info.hand.fingers.values())


def test_state_reads_back_as_written(engine, plan):
    """Joints reset by name read back in the engine's order, at rest; the object's pose reads
    back, and its rotation matrix is its quaternion's."""
    rd, _, _ = plan
    q = dict(zip(rd.joints, rd.states[0].q))
    engine.reset_joints(q)
    js = engine.joint_states()
    got = dict(zip(engine.topology.joints, js.position))
    assert all(got[j] == pytest.approx(v, abs=1e-12) for j, v in q.items())
    np.testing.assert_array_equal(js.velocity, 0.0)
    pos = np.asarray(rd.object.position) + [0.001, -0.002, 0.003]
    quat = Rotation.from_euler("xyz", [0.1, -0.2, 0.3]).as_quat()
    engine.set_object_pose(pos, quat)
    pose = engine.object_pose()
    np.testing.assert_allclose(pose.position_m, pos, atol=1e-12)
    assert abs(abs(float(np.dot(pose.quat_xyzw, quat))) - 1.0) < 1e-12
    np.testing.assert_allclose(pose.R, Rotation.from_quat(pose.quat_xyzw).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(pose.T[:3, 3], pos, atol=1e-12)


def test_contacts_point_into_the_object_from_its_surface(engine, plan):
    """With the hand at the plan's first state around the held cylinder, the touching links
    report points on the cylinder's surface (radius within 1 mm) with unit normals pointing
    INTO it (towards its axis), and non-negative normal forces; closest points stay within
    the gap asked for and, asked per link, belong to that link; every finger the plan holds
    the object with at that state is within the replay's touch tolerance of it."""
    rd, info, _ = plan
    obj = rd.object
    engine.reset_joints(dict(zip(rd.joints, rd.states[0].q)))
    engine.set_object_pose(obj.position, obj.quat_xyzw)
    engine.hold_object(obj.position, obj.quat_xyzw)
    engine.step()
    contacts = [c for c in engine.contacts() if c.distance_m <= 0.0]
    assert contacts  # how many points a touch gives is the engine's (pybullet: manifolds; MuJoCo: penetrating ones)
    # every finger the plan holds with touches within the replay's tolerance, in any engine
    tol = TOUCH_TOL_M
    touching = engine.closest_points(tol)
    owner = engine.topology.link_owner({j: f for f, js in info.fingers.items() for j in js}, "palm")
    held = {f for f in rd.states[0].touching if f != "palm"}
    assert held and held <= {owner[c.link] for c in touching}
    R = Rotation.from_quat(obj.quat_xyzw).as_matrix()
    axis, centre, radius = R[:, 2], np.asarray(obj.position), obj.size[0]
    for c in contacts + [c for c in touching if c.distance_m <= 0.0]:
        p, n = np.asarray(c.point_m), np.asarray(c.normal)
        on_axis = centre + ((p - centre) @ axis) * axis
        assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-9)
        assert np.linalg.norm(p - on_axis) == pytest.approx(radius, abs=1e-3)
        assert n @ (on_axis - p) > 0.9 * np.linalg.norm(on_axis - p)  # into the object
        assert c.normal_force_n >= 0.0
    gap = 0.002
    near = engine.closest_points(gap)
    assert near and all(c.distance_m <= gap + 1e-9 for c in near)
    link = contacts[0].link
    assert {c.link for c in engine.closest_points(gap, link)} == {link}


def test_a_held_object_stays_and_a_released_one_falls(engine, plan):
    """Away from the hand, with gravity on and the object held, it does not move; released,
    it falls along gravity by g t^2 / 2 (to the time step's first-order error), straight."""
    rd, _, _ = plan
    obj = rd.object
    away = np.asarray(obj.position) + [0.5, 0.5, 0.5]  # out of the hand's reach
    engine.set_object_pose(away, obj.quat_xyzw)
    g = np.array([0.0, 9.81, 0.0])
    engine.set_gravity(g)
    engine.hold_object(away, obj.quat_xyzw)
    for _ in range(24):
        engine.step()
    held = np.asarray(engine.object_pose().position_m) - away
    assert np.linalg.norm(held) < 1e-4
    engine.release_object()
    start = np.asarray(engine.object_pose().position_m)
    n = 24
    for _ in range(n):
        engine.step()
    assert not engine.contacts()
    moved = np.asarray(engine.object_pose().position_m) - start
    t = n * DT
    assert moved @ g / 9.81 == pytest.approx(0.5 * 9.81 * t * t, rel=0.1)
    assert np.linalg.norm(moved - (moved @ g / 9.81) * g / 9.81) < 1e-4


def test_a_torque_turns_its_joint_and_a_raised_inertia_turns_it_less(engine, plan):
    """Gravity off, object out of reach: a positive torque on one joint gives it a positive
    velocity after a step, in the engine's joint order; after its link's inertia is raised
    tenfold above its largest moment the same torque gives a smaller one."""
    rd, info, _ = plan
    engine.set_object_pose([1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0])
    finger = next(iter(info.hand.fingers.values()))
    joint, link = finger.joints[-1], finger.pad_link
    k = engine.topology.joints.index(joint)

    def velocity_after_push() -> float:
        engine.reset_joints(dict(zip(info.hand.joint_names, np.asarray(info.hand.q_open, float))))
        tau = np.zeros(len(engine.topology.joints))
        tau[k] = 1e-3
        engine.set_joint_torques(tau)
        engine.step()
        return float(engine.joint_states().velocity[k])

    v0 = velocity_after_push()
    assert v0 > 0
    engine.raise_link_inertia(link, 1e-3)  # far above a fingertip's ~1e-7 kg m^2
    v1 = velocity_after_push()
    assert 0 < v1 < 0.5 * v0
