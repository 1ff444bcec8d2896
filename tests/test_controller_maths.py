"""The replay's grasp controller as plain maths: synthetic readings, no physics engine.

The controller (`planner.sim.controller`) reads joint states, the object's pose and closest
points through `planner.sim.engine.Sensor`; here a fake sensor gives it the contacts of a
bundled plan's state, and the tests check the mechanics of what it commands: the balanced
contact forces hold the object's weight, the joint torques are ``g(q) + J^T f`` within the
hand's limits, the torques come out in the engine's joint order, an approaching finger
presses along its normal, and the armature floor keeps the stiffest posture spring at
``ARMATURE_OMEGA_DT``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.sim import controller as C
from planner.sim.engine import ContactPoint, HandTopology, JointStates, ObjectPose
from planner.sim.inputs import plan_hand, typed_plan

PLAN = Path(__file__).parent / "data" / "plans" / "schema2_cylinder_execution.json"
ROOT = "root_link"


class FakeSensor:
    """Readings of a hand at rest at ``q`` (engine order), the object at ``T``, and these
    closest points (``points``: within the contact gap; ``far``: only within the approach
    distance)."""

    def __init__(self, q, T, points, far=()):
        self.q, self.T, self.points, self.far = np.asarray(q, float), T, list(points), list(far)

    def joint_states(self) -> JointStates:
        return JointStates(self.q.copy(), np.zeros_like(self.q))

    def object_pose(self) -> ObjectPose:
        quat = tuple(Rotation.from_matrix(self.T[:3, :3]).as_quat())
        return ObjectPose(tuple(self.T[:3, 3]), quat, self.T[:3, :3].copy())

    def closest_points(self, gap_m: float, link: str | None = None) -> list[ContactPoint]:
        pts = [c for c in self.points + self.far if c.distance_m <= gap_m]
        return [c for c in pts if link is None or c.link == link]


@pytest.fixture(scope="module")
def setup():
    rd = typed_plan(PLAN)
    hand = plan_hand(rd)
    return rd, hand


def _controller(rd, hand, state_index=0, engine_order=None, drop=(), far=()):
    """A controller on the plan's state with one contact per touching finger at its pad
    (the plan's point and normal, palm frame); fingers in ``drop`` get no contact, those in
    ``far`` a closest point 5 mm off the surface."""
    st = rd.states[state_index]
    q_hand = np.array(hand.q_open, float)
    names = list(hand.joint_names)
    for j, v in zip(rd.joints, st.q):
        q_hand[names.index(j)] = v
    joints = tuple(engine_order or names)
    q_engine = np.array([q_hand[names.index(j)] for j in joints])
    obj = rd.object
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(obj.quat_xyzw).as_matrix()
    T[:3, 3] = obj.position
    points, approach = [], []
    for f, (P, N) in st.patches.items():
        if f not in hand.fingers or f in drop:
            continue
        p_w = T[:3, :3] @ np.asarray(P[0], float) + T[:3, 3]
        n_w = T[:3, :3] @ np.asarray(N[0], float)
        link = hand.fingers[f].pad_link
        if f in far:
            approach.append(ContactPoint(link, tuple(p_w), tuple(n_w), 0.005, 0.0))
        else:
            points.append(ContactPoint(link, tuple(p_w), tuple(n_w), 0.0, 0.0))
    links = (ROOT,) + tuple(link for fg in hand.fingers.values() for link in fg.links)
    link_finger = {link: f for f, fg in hand.fingers.items() for link in fg.links}
    topo = HandTopology(joints, links, {})
    sensor = FakeSensor(q_engine, T, points, approach)
    ctl = C.Controller(sensor, hand, topo, link_finger, {link: 0.005 for link in links}, obj.mass_kg, rd.friction,
                       9.81, dt_s=1.0 / 240.0, object_radius_m=float(np.min(obj.extents)) / 2)
    return ctl, st, q_hand, q_engine, T, points


@pytest.mark.parametrize("g_dir", [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)])
def test_balanced_forces_hold_the_weight_and_torques_are_gravity_plus_jacobian_transpose(setup, g_dir):
    """At the plan's contacts under full gravity the commanded forces sum to -m g, each lies
    inside the friction cone with at least the minimum normal force, and the feed-forward
    torques are g(q) + sum J_c^T f_c (pinocchio, computed here independently) within the
    joints' effort limits, in the engine's joint order."""
    rd, hand = setup
    ctl, st, q_hand, _, T, points = _controller(rd, hand)
    g = 9.81 * np.asarray(g_dir)
    ctl.set_gravity(g)
    ctl.command(dict(zip(rd.joints, st.q)), st.touching)
    assert ctl.balanced
    m = rd.object.mass_kg
    total = sum(ctl.forces.values())
    np.testing.assert_allclose(total + m * g, 0.0, atol=1e-6 * max(1.0, m * 9.81))
    by_link = {c.link: c for c in points}
    for link, f in ctl.forces.items():
        n = np.asarray(by_link[link].normal)
        fn = float(f @ n)
        ft = float(np.linalg.norm(f - fn * n))
        assert fn >= C.MIN_NORMAL_RATIO * ctl.force_n - 1e-9
        assert ft <= rd.friction.mu * fn + 1e-9
    # tau = g(q) + sum J^T f, independently
    state = hand.state(q_hand)
    expected = state.gravity_torques(g).astype(float)
    names = list(hand.joint_names)
    for c in points:
        J = state.point_jacobians([(c.link, np.asarray(c.point_m))])[0][:3]
        f = ctl.forces[c.link]
        finger = next(k for k, fg in hand.fingers.items() if c.link in fg.links)
        cols = [names.index(j) for j in hand.fingers[finger].joints]
        expected[cols] += J[:, cols].T @ f
    tau_hand = ctl.tau[[ctl.hand_pos[j] for j in names]]
    np.testing.assert_allclose(tau_hand, expected, atol=1e-9)
    assert np.all(np.abs(ctl.tau) <= ctl.tau_max + 1e-9)


def test_torques_follow_the_engine_joint_order(setup):
    """An engine that orders its joints otherwise gets the same torques, permuted: the
    controller speaks joint names, not indices."""
    rd, hand = setup
    names = list(hand.joint_names)
    order = names[::-1]
    out = []
    for eng in (names, order):
        ctl, st, _, q_engine, _, _ = _controller(rd, hand, engine_order=eng)
        ctl.set_gravity((0.0, 0.0, 9.81))
        ctl.command(dict(zip(rd.joints, st.q)), st.touching)
        tau = ctl.torques(JointStates(q_engine, np.zeros_like(q_engine)))
        out.append(dict(zip(eng, tau)))
    assert out[0].keys() == out[1].keys()
    for j in names:
        assert out[0][j] == pytest.approx(out[1][j], abs=1e-12)


def test_at_the_target_and_at_rest_the_motors_give_the_feed_forward(setup):
    """With the joints at their posture targets and still, the spring and damper add
    nothing: the torques are the feed-forward ``g(q) + J^T f`` (clipped at the limits); a
    joint velocity adds ``-Kd qdot``."""
    rd, hand = setup
    ctl, st, _, q_engine, _, _ = _controller(rd, hand)
    ctl.set_gravity((0.0, 0.0, 9.81))
    ctl.command(dict(zip(rd.joints, st.q)), st.touching)
    ctl.latch(st.touching)
    js = JointStates(ctl.q_target.copy(), np.zeros_like(q_engine))
    np.testing.assert_allclose(ctl.torques(js), np.clip(ctl.tau, -ctl.tau_max, ctl.tau_max), atol=1e-15)
    qd = np.full_like(q_engine, 0.01)
    moved = ctl.torques(JointStates(ctl.q_target.copy(), qd))
    free = np.abs(ctl.tau - ctl.kd * qd) < ctl.tau_max
    np.testing.assert_allclose(moved[free], (ctl.tau - ctl.kd * qd)[free], atol=1e-15)


def test_no_gravity_gives_a_pure_squeeze_of_internal_forces(setup):
    """Gravity off (acquisition): the forces balance nothing, so they sum to zero, and the
    torques carry no gravity compensation."""
    rd, hand = setup
    ctl, st, q_hand, _, _, points = _controller(rd, hand)
    ctl.set_gravity(np.zeros(3))
    ctl.command(dict(zip(rd.joints, st.q)), st.touching)
    assert ctl.balanced
    np.testing.assert_allclose(sum(ctl.forces.values()), 0.0, atol=1e-7)
    assert all(float(np.linalg.norm(f)) > 0 for f in ctl.forces.values())


def test_a_holding_finger_off_the_object_approaches_along_its_normal(setup):
    """A holding finger whose pad is 5 mm away (beyond the contact gap, within the approach
    distance) is commanded the squeeze along its closest point's normal, and takes no share
    of the balanced load."""
    rd, hand = setup
    ctl, st, _, _, _, _ = _controller(rd, hand, far=("little",))
    ctl.set_gravity((0.0, 0.0, 9.81))
    ctl.command(dict(zip(rd.joints, st.q)), st.touching)
    contacts = ctl.contacts()
    little = [c for c in contacts if c.finger == "little"]
    assert len(little) == 1 and not little[0].touching
    f = ctl.forces[hand.fingers["little"].pad_link]
    np.testing.assert_allclose(f, ctl.force_n * little[0].normal, atol=1e-12)
    others = sum(v for k, v in ctl.forces.items() if k != hand.fingers["little"].pad_link)
    np.testing.assert_allclose(others + rd.object.mass_kg * np.array([0, 0, 9.81]), 0.0, atol=1e-6)


def test_armature_floor_puts_the_stiffest_spring_at_the_design_omega_dt(setup):
    """Every finger link gets its finger's inertia floor, and with every finger free at the
    open posture (where the floor is sized: the pad's longest lever) the stiffest posture
    spring of a one-finger squeeze sits at omega dt = ARMATURE_OMEGA_DT, the others below."""
    rd, hand = setup
    ctl, st, _, _, _, _ = _controller(rd, hand)
    for f, fg in hand.fingers.items():
        floors = {ctl.armature_floor[link] for link in fg.links}
        assert len(floors) == 1
        assert floors == {ctl.armature[ctl.hand_pos[fg.joints[0]]]}
    names = list(hand.joint_names)
    ctl.sensor.q = np.array([hand.q_open[names.index(j)] for j in ctl.movable], float)
    ctl.command(dict(zip(names, np.asarray(hand.q_open, float))), ())  # every finger free
    F1 = C.squeeze_force_n(ctl.mass, ctl.g_max, 1, ctl.friction.mu, ctl.floor_n)
    scale = max(C.FREE_SHARE, C.POSTURE_SHARE) / C.FREE_SHARE * F1 / ctl.force_n
    idx = [ctl.hand_pos[j] for fg in hand.fingers.values() for j in fg.joints]
    w = np.sqrt(scale * ctl.kp[idx] / ctl.armature[idx]) * (1.0 / 240.0)
    assert np.all(w <= C.ARMATURE_OMEGA_DT * (1 + 1e-9))
    assert np.max(w) == pytest.approx(C.ARMATURE_OMEGA_DT, rel=0.02)


def test_the_palm_hands_its_load_over_to_the_fingers_for_a_reposing_move(setup):
    """The object against the palm (a contact of the palm's link on the side the fingers squeeze
    it toward, gravity pressing it there): in the balance the palm carries part of the weight
    and the fingers' squeeze, so the fingers' forces do not sum to the weight; with the palm's
    share faded to 0 (a reposing move: the planner holds the object with the fingers alone
    while it moves relative to the palm) the fingers carry all of it, and a share between
    blends the two solutions linearly (a handover, as a finger's). The palm is passive: it is
    never commanded a force."""
    rd, hand = setup
    ctl, st, _, _, T, points = _controller(rd, hand)
    n = np.asarray(hand.palm_normal, float)
    finger_push = sum(np.asarray(c.normal, float) for c in points)
    assert float(finger_push @ n) > 0.0  # the fingers squeeze the object toward +n: the palm there
    r = float(np.min(rd.object.extents)) / 2
    ctl.sensor.points.append(ContactPoint(ROOT, tuple(T[:3, 3] + r * n), tuple(-n), 0.0, 0.0))
    m = rd.object.mass_kg
    g = 9.81 * n  # pressing the object onto the palm
    ctl.set_gravity(g)
    totals = {}
    for share in (1.0, 0.25, 0.0):
        ctl.fade_palm(share)
        ctl.command(dict(zip(rd.joints, st.q)), st.touching)
        assert ctl.balanced
        assert set(ctl.forces) == {c.link for c in points}
        totals[share] = sum(ctl.forces.values())
    np.testing.assert_allclose(totals[0.0] + m * g, 0.0, atol=1e-6)  # the fingers alone hold the weight
    assert float(np.linalg.norm(totals[1.0] + m * g)) > 0.1 * m * 9.81  # the palm carries part of it
    np.testing.assert_allclose(totals[0.25], 0.25 * totals[1.0] + 0.75 * totals[0.0], atol=1e-9)
