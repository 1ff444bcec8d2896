"""Coupled joints in the replay (issue 37 item 2): the engine enforces every coupling
``q_f = m q_d + o`` (pybullet: a gear constraint; MuJoCo: a joint equality), the controller
commands the drivers only, and the replay reports each coupling's largest error against
`planner.hand.Hand.coupling_tolerances` (a replay that breaks one does not pass).

The test hand (tests/data/coupled_hand/yaml_hand.yaml): two fingers, ``left_2 = left_1`` and
``right_2 = 1.2 right_1 + 0.1`` (a multiplier and an offset: a wrong sign or a missing offset
shows), holding a 30 mm ball between its distal links."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.cli import main
from planner.hand import Hand
from planner.model import Friction
from planner.sim.controller import Controller
from planner.sim.engine import ContactPoint, HandTopology, JointStates, ObjectPose
from planner.sim.report import ReplayReport

ROOT = Path(__file__).resolve().parents[1]
HAND = ROOT / "tests/data/coupled_hand/yaml_hand.yaml"
BALL_Z = 0.05

GRASP = f"""schema_version: 1
name: coupled_pinch
hand: {HAND}
object:
  shape: sphere
  size: [0.015]
  position: [0.0, 0.0, {BALL_Z}]
  quat_xyzw: [0.0, 0.0, 0.0, 1.0]
  mass_kg: 0.02
friction: {{mu: 0.9, gamma: 0.004, edges: 5}}
fingers:
  left: {{posture: %s}}
  right: {{posture: %s}}
"""


@pytest.fixture(scope="module")
def hand():
    return Hand.load(HAND)


@pytest.fixture(scope="module")
def plan_path(tmp_path_factory, hand):
    """A one-state execution plan: both fingers closed on the ball (the closing procedure
    over the drivers: every posture coupled)."""
    from planner.objects import GraspObject

    ball = GraspObject.from_data({"shape": "sphere", "size": [0.015], "position": [0.0, 0.0, BALL_Z],
                                  "quat_xyzw": [0.0, 0.0, 0.0, 1.0]})
    q = hand.q_open.copy()
    for f in ("left", "right"):
        q = hand.close_finger(f, q, ball)
    assert np.max(hand.coupling_errors(q)) == 0.0
    postures = [[round(float(q[i]), 9) for i in hand.fingers[f].q_index] for f in ("left", "right")]
    folder = tmp_path_factory.mktemp("coupled_replay")
    grasp = folder / "grasp.yaml"
    grasp.write_text(GRASP % tuple(postures))
    out = folder / "plan.json"
    assert main(["plan", str(grasp), str(grasp), "--execution", "--no-verify", "-o", str(out)]) == 0
    return out


def _replay(plan_path, engine, **kw) -> ReplayReport:
    from planner.sim.replay import replay_plan

    return replay_plan(plan_path, engine=engine, acquire_s=0.2, ramp_s=0.3, settle_s=0.15, **kw)


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_a_plan_replays_with_every_coupling_within_its_tolerance(plan_path, hand, engine):
    pytest.importorskip(engine)
    rep = _replay(plan_path, engine)
    assert rep.passed, rep.verdict
    errs = {c.joint: c for c in rep.coupling_errors}
    assert sorted(errs) == ["left_2", "right_2"]
    tol = dict(zip((c.joint for c in hand.couplings), hand.coupling_tolerances()))
    for j, c in errs.items():
        assert c.tolerance == pytest.approx(tol[j])
        # a gear train, not a loose spring: a hundredth of what a plan may show
        assert c.max_error < 0.01 * c.tolerance, (engine, j, c.max_error)
        assert c.step == -1 and 0.0 < c.time_s <= rep.sim_time_s
    # the report's plain data carries them; a report without them (written before) reads too
    data = rep.to_dict()
    assert {d["joint"] for d in data["coupling_errors"]} == {"left_2", "right_2"}
    assert ReplayReport(**{k: v for k, v in vars(rep).items() if k != "coupling_errors"}).coupling_errors == ()


def test_a_coupling_the_engine_breaks_fails_the_replay_and_names_it(plan_path, monkeypatch):
    """The gear constraint without torque: the followers hang free, the error is measured
    and the verdict says which coupling, by how much, and when."""
    pytest.importorskip("pybullet")
    import planner.sim.engine_pybullet as eb

    monkeypatch.setattr(eb, "GEAR_MAX_TORQUE", 0.0)
    rep = _replay(plan_path, "pybullet")
    assert not rep.passed
    broken = [c for c in rep.coupling_errors if not c.within]
    assert broken and all(c.max_error > c.tolerance for c in broken)
    assert any(f"coupling {c.joint} = f({c.follows}) broken by" in r for c in broken for r in rep.reasons)
    assert rep.failed_step == -1


# ------------------------------------------------------------------ controller maths


class _Sensor:
    """Synthetic readings: the hand at ``q`` (engine order = the hand's), at rest; the ball
    touched by each finger's distal link on its inner side."""

    def __init__(self, hand, q):
        self.q = np.asarray(q, dtype=float)
        self.hand = hand

    def joint_states(self):
        return JointStates(self.q.copy(), np.zeros_like(self.q))

    def object_pose(self):
        return ObjectPose((0.0, 0.0, BALL_Z), (0.0, 0.0, 0.0, 1.0), np.eye(3))

    def closest_points(self, gap_m, link=None):
        pts = [ContactPoint("left_distal", (-0.015, 0.0, BALL_Z), (1.0, 0.0, 0.0), 0.0, 0.0),
               ContactPoint("right_distal", (0.015, 0.0, BALL_Z), (-1.0, 0.0, 0.0), 0.0, 0.0)]
        return [c for c in pts if link is None or c.link == link]


def test_the_controller_commands_drivers_only_with_the_followers_load_by_virtual_work(hand):
    """Drivers-only torques: a follower gets none and its driver ``tau_d + m tau_f`` of the
    uncoupled torques ``g(q) + J^T f`` (the same forces: one solution, both views); the
    driver's posture spring's lever is the reduced pad Jacobian's column ``J_d + m J_f``."""
    q = hand.q_open.copy()
    names = list(hand.joint_names)
    for f, vals in (("left", (0.06, 0.06, 0.06)), ("right", (0.06, 0.048, 1.2 * 0.048 + 0.1))):
        for j, v in zip(hand.fingers[f].joints, vals):
            q[names.index(j)] = v
    assert np.max(hand.coupling_errors(q)) < 1e-12
    sensor = _Sensor(hand, q)
    topo = HandTopology(tuple(names), ("palm", "left_proximal", "left_middle", "left_distal", "right_proximal",
                                       "right_middle", "right_distal"))
    owner = {link: ("left" if link.startswith("left") else "right" if link.startswith("right") else "palm")
             for link in topo.links}
    ctl = Controller(sensor, hand, topo, owner, {link: 0.01 for link in topo.links}, 0.02, Friction(0.9, 0.004, 5),
                     9.81)
    g = np.array([0.0, 0.0, -9.81])
    ctl.set_gravity(g)
    ctl.command({j: float(v) for j, v in zip(names, q)}, ("left", "right"))
    tau = ctl.step()  # at the targets, at rest: the feed-forward only
    state = hand.state(q)
    full = np.array(state.gravity_torques(g), dtype=float)
    for link, f in ctl.forces.items():
        p = next(c.point_m for c in sensor.closest_points(1.0) if c.link == link)
        (J,) = state.point_jacobians([(link, np.asarray(p))])
        full += J[:3].T @ f
    for c in hand.couplings:
        d, fo = names.index(c.follows), names.index(c.joint)
        assert tau[fo] == 0.0
        assert tau[d] == pytest.approx(full[d] + c.multiplier * full[fo], rel=1e-9, abs=1e-12)
    for j in ("left_0", "right_0"):
        assert tau[names.index(j)] == pytest.approx(full[names.index(j)], rel=1e-9, abs=1e-12)
    # the followers have no motor at all: no spring, no cap, a zero torque limit
    fol = [names.index(c.joint) for c in hand.couplings]
    assert np.all(ctl.kp[fol] == 0.0) and np.all(ctl.cap[fol] == 0.0) and np.all(ctl.tau_max[fol] == 0.0)
    # a driver's spring acts on the reduced coordinate: its lever is |J_d + m J_f| at the pad
    fg = hand.fingers["right"]
    Jp = state.frame_jacobian(fg.pad_link, fg.pad_p_link)[:3][:, list(fg.q_index)]
    lever = float(np.linalg.norm(Jp[:, 1] + 1.2 * Jp[:, 2]))
    d = names.index("right_1")
    assert ctl.cap[d] == pytest.approx(0.3 * ctl.force_n * lever, rel=1e-9)
    # a follower moves with its driver, |m| times as fast
    v = ctl.tracking_speed_rad_s(["right_1", "right_2"])
    assert v[1] == pytest.approx(1.2 * v[0]) and v[0] > 0


def test_replay_prints_each_couplings_largest_error_against_its_tolerance(plan_path, capsys):
    pytest.importorskip("pybullet")
    assert main(["replay", str(plan_path), "--gravity-set", "1", "--workers", "1"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("coupled joints"))
    assert "left_2 " in line and "right_2 " in line and line.endswith(": all within")


def test_synth_keeps_its_palm_clearance_where_the_nearest_palm_link_faces_the_object_obliquely(tmp_path):
    """example-robot-data's Alex/Psyonic hand: one push along the palm normal left a sampled 30 mm
    ball 1.09 mm from the thumb base (the synth keeps 2 mm), and palm up the replay's palm
    carried it; the push is repeated until the gap is there."""
    from planner.synth_sample import PALM_CLEARANCE_M, PALM_GAP_TOL_M
    from planner.urdf_check import installed_share_dirs

    found = [Path(d) / "example-robot-data/robots/alex_description/urdf/alex_psyonic_hands.urdf"
             for d in installed_share_dirs()]
    found = [p for p in found if p.is_file()]
    if not found:
        pytest.skip("example-robot-data is not installed")
    spec = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(found[0]), "-o", str(spec), "--root", "RightGripperYawLink"]) == 0
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.03]\nmass_kg: 0.05\n")
    assert main(["synth", str(spec), str(ball), "--fingers", "thumb,index,middle,ring", "-n", "1", "-o",
                 str(tmp_path / "g"), "--quiet"]) == 0
    from planner.grasp import load_grasp

    grasp = load_grasp(next((tmp_path / "g").glob("*.yaml")))
    hand = Hand.load(spec)
    gap = hand.state(hand.q_open).palm_object_distance(grasp.object)  # (the palm's links do not move)
    assert gap >= PALM_CLEARANCE_M - PALM_GAP_TOL_M, gap


def _four_bar_distal(L0, P1, L1, q_prox):
    """The mk3 finger linkage (gazebo-yarp-plugins' HandMk3CouplingHandler geometry, m): the
    motor angle q_prox + q_dist reached at proximal angle ``q_prox`` (rad), minus q_prox."""
    L0, P1, L1 = (np.asarray(v, dtype=float) for v in (L0, P1, L1))
    l2, k2 = np.sum((P1 - L1) ** 2), np.sum((L1 - L0) ** 2)
    off = np.arctan2(L1[1] - P1[1], L1[0] - P1[0])
    c, s = np.cos(q_prox), np.sin(q_prox)
    px, py = c * P1[0] - s * P1[1], s * P1[0] + c * P1[1]
    h2 = (px - L0[0]) ** 2 + (py - L0[1]) ** 2
    motor = np.arctan2(L0[1] - py, L0[0] - px) + np.arccos((h2 + l2 - k2) / (2 * np.sqrt(h2 * l2))) - off
    motor = np.mod(motor + 0.5 * np.pi, 2 * np.pi) - 0.5 * np.pi  # in [-90, 270) deg: the thumb's starts a hair below 0
    return motor - q_prox


MK3_COUPLINGS = """couplings:
  - {joint: l_hand_thumb_distal_joint, follows: l_hand_thumb_proximal_joint, multiplier: 0.6435, offset: 0.0396}
  - {joint: l_hand_index_distal_joint, follows: l_hand_index_proximal_joint, multiplier: 1.088, offset: 0.0419}
  - {joint: l_hand_medium_distal_joint, follows: l_hand_medium_proximal_joint, multiplier: 1.088, offset: 0.0419}
  - {joint: l_hand_pinky_distal_joint, follows: l_hand_pinky_proximal_joint, multiplier: 1.088, offset: 0.0419}
"""


def test_the_icub_mk3_hand_takes_its_four_bar_couplings_as_documented(tmp_path):
    """icub-models' mk3 hand (docs/HANDS.md): the hand.yaml lines are within 2.4 deg of the
    linkage over the URDF's proximal ranges, and the hand loads with its drivers' ranges
    narrowed to where the distal joints stay within their limits."""
    icub = pytest.importorskip("icub_models")
    import sys

    urdf = Path(sys.prefix) / "share/iCub/robots/left_hand_mk3/model.urdf"
    if not urdf.is_file():
        urdf = Path(icub.get_model_file("left_hand_mk3"))
    for geometry, q_max, m, o in (
            (((-0.00555, 0.00285), (0.020, 0.0015), (0.0115, 0.0014)), 1.4835, 0.6435, 0.0396),  # thumb
            (((-0.0050, 0.0040), (0.0300, 0.0015), (0.0240, 0.0008)), 1.6581, 1.088, 0.0419)):  # fingers
        q = np.linspace(0.0, q_max, 400)
        assert np.max(np.abs(_four_bar_distal(*geometry, q) - (m * q + o))) < np.radians(2.45)  # 2.4 deg, rounded
    spec = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(urdf), "-o", str(spec)]) == 0
    spec.write_text(spec.read_text() + MK3_COUPLINGS)
    hand = Hand.load(spec)
    assert len(hand.couplings) == 4 and not any(c.source.startswith("URDF") for c in hand.couplings)
    i = hand.joint_names.index
    assert hand.upper[i("l_hand_thumb_proximal_joint")] == pytest.approx((0.9599310885968813 - 0.0396) / 0.6435)
    assert hand.upper[i("l_hand_index_proximal_joint")] == pytest.approx((1.837831702350029 - 0.0419) / 1.088)
    assert hand.lower[i("l_hand_index_distal_joint")] == pytest.approx(0.0419)


def test_a_replay_in_a_callers_pybullet_client_leaves_no_gear_constraint_behind(plan_path):
    p = pytest.importorskip("pybullet")
    cid = p.connect(p.DIRECT)
    try:
        errors = []
        for _ in range(2):
            rep = _replay(plan_path, "pybullet", client=cid)
            assert rep.passed, rep.verdict
            assert p.getNumConstraints(physicsClientId=cid) == 0 and p.getNumBodies(physicsClientId=cid) == 0
            errors.append([c.max_error for c in rep.coupling_errors])
        assert errors[0] == errors[1]  # the same replay again: nothing left over changes it
    finally:
        p.disconnect(physicsClientId=cid)
