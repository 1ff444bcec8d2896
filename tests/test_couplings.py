"""Coupled joints (issue 37 item 2): a URDF ``<mimic>`` or a hand.yaml ``couplings:`` entry,
``q_follower = m q_driver + o``, is a constraint of every planning step: IK and closing
solve over the drivers, the grip model loads a driver's actuator with its followers'
torques, plans keep the coupling in every state and waypoint, and ``verify`` refuses a
plan that breaks one. The test hand (tests/data/coupled_hand, make_urdf.py) has two
fingers of three joints; its left distal joint mimics the middle one."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.audit import audit_plan
from planner.cli import main
from planner.errors import SpecError
from planner.grip import finger_statics
from planner.hand import Hand
from planner.ik import IK_TOL_M
from planner.objects import GraspObject
from planner.plan import read_plan
from planner.plan_data import integrity_record

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests/data/coupled_hand"
ICUB = ROOT / "robots/icub_right"
MIMIC = DATA / "hand.yaml"          # left_2 = left_1 by the URDF's <mimic>
YAML = DATA / "yaml_hand.yaml"      # the same hand without <mimic>; couplings in the hand.yaml
PLAIN_URDF = (DATA / "plain_hand.urdf").read_text()


@pytest.fixture(scope="module")
def mimic_hand():
    return Hand.load(MIMIC)


@pytest.fixture(scope="module")
def yaml_hand():
    return Hand.load(YAML)


def _ball(radius=0.015, position=(0.0, 0.0, 0.05)) -> GraspObject:
    return GraspObject.from_data({"shape": "sphere", "size": [radius], "position": list(position),
                                  "quat_xyzw": [0.0, 0.0, 0.0, 1.0]})


# ------------------------------------------------------------------ parsing


def test_couplings_are_read_from_the_urdf_and_the_hand_yaml(mimic_hand, yaml_hand):
    (c,) = mimic_hand.couplings
    assert (c.joint, c.follows, c.multiplier, c.offset) == ("left_2", "left_1", 1.0, 0.0)
    assert c.source.startswith("URDF line ")
    left = mimic_hand.fingers["left"]
    assert left.drivers == ("left_0", "left_1") and left.coupled == ((2, 1, 1.0, 0.0),)
    assert mimic_hand.fingers["right"].drivers == ("right_0", "right_1", "right_2")
    a, b = yaml_hand.couplings
    assert (b.joint, b.follows, b.multiplier, b.offset, b.source) == ("right_2", "right_1", 1.2, 0.1,
                                                                       "hand.yaml couplings[1]")
    # right_1's range narrowed to where right_2 = 1.2 right_1 + 0.1 stays in [0, 1.5708]
    i1, i2 = yaml_hand.joint_names.index("right_1"), yaml_hand.joint_names.index("right_2")
    assert yaml_hand.lower[i1] == 0.0 and yaml_hand.upper[i1] == pytest.approx((1.5708 - 0.1) / 1.2)
    assert yaml_hand.lower[i2] == pytest.approx(0.1) and yaml_hand.upper[i2] == pytest.approx(1.5708)
    assert yaml_hand.urdf_upper[i1] == pytest.approx(1.5708)
    # the open posture is coupled (right_1 at 0: right_2 at its offset)
    assert yaml_hand.q_open[i2] == pytest.approx(0.1)
    assert np.all(yaml_hand.coupling_errors(yaml_hand.q_open) == 0.0)


def _urdf_error(tmp_path, text: str, spec: str = "") -> str:
    d = tmp_path / "h"
    d.mkdir(exist_ok=True)
    (d / "coupled_hand.urdf").write_text(text)
    (d / "hand.yaml").write_text(MIMIC.read_text() + spec)
    with pytest.raises(SpecError) as err:
        Hand.load(d / "hand.yaml")
    line = str(err.value)
    assert "\n" not in line and str(d / "hand.yaml") in line
    return line


MIMIC_LINE = '<mimic joint="left_1" multiplier="1.0" offset="0.0"/>'
URDF = (DATA / "coupled_hand.urdf").read_text()


@pytest.mark.parametrize("mimic, needle", [
    ('<mimic joint="left_9"/>', "follows 'left_9', which is not a joint of the URDF"),
    ('<mimic joint="left_2"/>', "a joint cannot follow itself"),
    ('<mimic joint="left_1" multiplier="nan"/>', "multiplier must be a finite number"),
    ('<mimic joint="left_1" offset="inf"/>', "offset must be a finite number"),
    ('<mimic joint="left_1" multiplier="0"/>', "multiplier 0"),
    ('<mimic joint="left_tip_joint"/>', "is a fixed joint"),
    ('<mimic joint="right_1"/>', "of finger right"),
    ('<mimic/>', '<mimic>: has no joint="..." (the joint it follows)'),
])
def test_bad_mimic_elements_are_one_line_errors_naming_file_and_element(tmp_path, mimic, needle):
    line = _urdf_error(tmp_path, URDF.replace(MIMIC_LINE, mimic))
    assert needle in line and "joint 'left_2'" in line and "coupled_hand.urdf" in line, line


def test_a_chain_of_mimics_is_refused(tmp_path):
    # left_1 follows left_0, and left_2 follows left_1
    i = URDF.index('<joint name="left_1"')
    j = URDF.index("</joint>", i)
    chain = URDF[:j] + '<mimic joint="left_0"/>' + URDF[j:]
    line = _urdf_error(tmp_path, chain)
    assert "follows 'left_1', which follows 'left_0' itself" in line, line


@pytest.mark.parametrize("spec, needle", [
    ("couplings:\n  - {joint: left_2, follows: left_0}\n", "couplings[0].joint: left_2 already follows left_1 by the "
                                                           "URDF's <mimic>"),
    ("couplings:\n  - {joint: right_2, follows: left_1}\n", "couplings[0].follows: right_2 is of finger right, left_1 "
                                                            "of finger left: a coupling joins joints of one finger only"),
    ("couplings:\n  - {joint: right_2, follows: right_9}\n", "couplings[0].follows: unknown joint 'right_9'"),
    ("couplings:\n  - {joint: right_2, follows: right_2}\n", "a joint cannot follow itself"),
    ("couplings:\n  - {joint: right_2, follows: right_1, multiplier: 0}\n", "couplings[0].multiplier: multiplier 0"),
    ("couplings:\n  - {joint: right_2, follows: right_1, multiplier: .nan}\n", "couplings[0].multiplier: expected a "
                                                                              "non-zero number"),
    ("couplings:\n  - {joint: right_2, follows: right_1, gain: 2}\n", "couplings[0].gain: unknown key 'gain'; valid keys are joint, follows"),
    ("couplings:\n  - {joint: right_2}\n", "couplings[0].follows: missing required key 'follows'"),
    ("couplings: {joint: right_2}\n", "couplings: expected a list"),
    ("couplings:\n  - {joint: right_2, follows: right_1}\n  - {joint: right_1, follows: right_0}\n",
     "right_2 follows right_1 (hand.yaml couplings[0]), which follows right_0 itself"),
    ("couplings:\n  - {joint: right_2, follows: right_1, offset: 3.0}\n", "leaves right_1 no angle within both "
                                                                         "joints' limits"),
    ("couplings:\n  - {joint: right_2, follows: right_1}\nopen: {right_2: 0.3}\n", "open.right_2: right_2 follows "
                                                                                   "right_1"),
])
def test_bad_hand_yaml_couplings_are_one_line_errors_naming_the_key(tmp_path, spec, needle):
    line = _urdf_error(tmp_path, URDF, spec)
    assert needle in line, line


# ------------------------------------------------------------------ IK and closing


@pytest.mark.parametrize("which", ["mimic", "yaml"])
def test_ik_solves_over_the_drivers_and_the_coupling_holds_exactly(mimic_hand, yaml_hand, which):
    hand = mimic_hand if which == "mimic" else yaml_hand
    rng = np.random.default_rng(3)
    solved = 0
    for finger in ("left", "right"):
        f = hand.fingers[finger]
        for _ in range(6):
            # a target the coupled finger reaches: the pad at a random coupled posture
            q = hand.couple(np.where(np.isin(np.arange(hand.model.nq), f.free_index),
                                     rng.uniform(hand.lower, hand.upper), hand.q_open))
            target = hand.state(q).link_pose(f.pad_link)[:3, :3] @ np.array(f.pad_p_link) \
                + hand.state(q).link_pose(f.pad_link)[:3, 3]
            res = hand.ik_solve(finger, target, hand.q_open)
            assert res.position_error_m < IK_TOL_M
            assert np.all(hand.coupling_errors(res.q) == 0.0)  # followers set from drivers, exactly
            assert np.all(res.q >= hand.lower - 1e-12) and np.all(res.q <= hand.upper + 1e-12)
            solved += 1
    assert solved == 12


def test_reduced_jacobian_matches_finite_differences_over_the_drivers(yaml_hand):
    hand = yaml_hand
    for finger in ("left", "right"):
        f = hand.fingers[finger]
        q = hand.couple(np.array([0.3, 0.5, 0.0, 0.2, 0.4, 0.0]))
        J, p, _ = hand.kinematics(q).frame_jacobian(hand._fid(f.pad_link), np.array(f.pad_p_link))
        Jr = f.reduce(J[:, list(f.q_index)])
        assert Jr.shape == (6, len(f.free))
        h = 1e-6
        for k, i in enumerate(f.free_index):
            dq = np.zeros(hand.model.nq)
            dq[i] = h
            plus = hand.kinematics(hand.couple(q + dq)).frame_jacobian(hand._fid(f.pad_link), np.array(f.pad_p_link))[1]
            minus = hand.kinematics(hand.couple(q - dq)).frame_jacobian(hand._fid(f.pad_link), np.array(f.pad_p_link))[1]
            np.testing.assert_allclose(Jr[:3, k], (plus - minus) / (2 * h), atol=1e-7)
        # the driver's column is J_d + m J_f (chain rule), not J_d alone
        (fl, d, m, _), = f.coupled
        np.testing.assert_allclose(Jr[:, f.free.index(d)], J[:, f.q_index[d]] + m * J[:, f.q_index[fl]])
        assert np.linalg.norm(J[:3, f.q_index[fl]]) > 1e-3


def test_closing_moves_the_drivers_and_keeps_the_coupling(yaml_hand):
    hand, ball = yaml_hand, _ball()
    q = hand.q_open.copy()
    for finger in ("left", "right"):
        q = hand.close_finger(finger, q, ball)
        d = hand.state(q).finger_object_distance(ball, finger)
        assert -1e-4 <= d <= 1e-3, (finger, d)  # touching (the closing procedure's backoff)
    assert np.all(hand.coupling_errors(q) == 0.0)
    i = hand.joint_names.index
    assert q[i("left_1")] > 0.0 and q[i("right_2")] == 1.2 * q[i("right_1")] + 0.1


# ------------------------------------------------------------------ grip model


def test_a_followers_torque_loads_its_driver_by_m_times_tau_f(tmp_path, yaml_hand):
    """Analytic: the same hand without couplings gives per-joint torques tau; the coupled
    finger's actuator rows are its drivers, with tau_d + m tau_f (virtual work) bounded by
    the driver's effort limit."""
    d = tmp_path / "plain"
    d.mkdir()
    (d / "plain_hand.urdf").write_text(PLAIN_URDF)
    (d / "hand.yaml").write_text(YAML.read_text().split("\ncouplings:")[0] + "\n")
    plain = Hand.load(d / "hand.yaml")
    assert not plain.couplings
    ball = _ball()
    q = yaml_hand.q_open.copy()
    for finger in ("left", "right"):
        q = yaml_hand.close_finger(finger, q, ball)
    pts = np.array([[0.01, 0.0, 0.0], [0.012, 0.002, 0.004]])  # object frame
    f = yaml_hand.fingers["right"]
    coupled = finger_statics(yaml_hand, "right", q, pts, ball.T_palm_obj, links=["right_distal", "right_middle"])
    free = finger_statics(plain, "right", q, pts, ball.T_palm_obj, links=["right_distal", "right_middle"])
    assert coupled.joints == ("right_0", "right_1") and free.joints == ("right_0", "right_1", "right_2")
    m = 1.2
    np.testing.assert_allclose(coupled.jacobians[..., 1], free.jacobians[..., 1] + m * free.jacobians[..., 2])
    np.testing.assert_allclose(coupled.jacobians[..., 0], free.jacobians[..., 0])
    np.testing.assert_allclose(coupled.gravity[1], free.gravity[1] + m * free.gravity[2])
    # a force at the distal point: the follower's torque tau_f loads the driver's actuator by m tau_f
    force = np.array([0.0, 0.0, -1.0])
    tau = np.einsum("ij,i->j", free.jacobians[0, :3], force)
    tau_act = np.einsum("ij,i->j", coupled.jacobians[0, :3], force)
    assert abs(tau[2]) > 1e-4
    assert tau_act[1] == pytest.approx(tau[1] + m * tau[2]) and tau_act[0] == pytest.approx(tau[0])
    np.testing.assert_array_equal(coupled.effort, [0.5, 0.5])  # the drivers' limits; right_2 has no actuator
    assert f.drivers == coupled.joints


# ------------------------------------------------------------------ hand check


def test_hand_check_lists_the_couplings(capsys):
    assert main(["hand", "check", str(YAML)]) in (0, 1)
    out = capsys.readouterr().out
    assert "couplings: 2 coupled joint(s): left_2 = 1 left_1 + 0 (hand.yaml couplings[0]); right_2 = 1.2 right_1 + 0.1" \
        in out, out
    assert "joint right_1: range [0, 1.226] (URDF [0, 1.571])" in out, out
    assert "a plan commands the drivers" in out


# ------------------------------------------------------------------ plans


def _coupled_icub(folder: Path) -> Path:
    """The bundled iCub with its distal couplings (icub-hand-facts: each distal motor drives
    joints 2 and 3 equally): index_3 by a URDF <mimic>, the others in the hand.yaml."""
    folder.mkdir()
    urdf = (ICUB / "icub_right.urdf").read_text()
    i = urdf.index('<joint name="index_3"')
    j = urdf.index("</joint>", i)
    (folder / "icub_right.urdf").write_text(urdf[:j] + '<mimic joint="index_2"/>' + urdf[j:])
    spec = (ICUB / "hand.yaml").read_text() + (
        "couplings:\n  - {joint: thumb_3, follows: thumb_2}\n  - {joint: middle_3, follows: middle_2}\n"
        "  - {joint: ring_3, follows: ring_2}\n  - {joint: little_3, follows: little_2}\n")
    (folder / "hand.yaml").write_text(spec.replace("name: icub_right", "name: icub_coupled"))
    return folder / "hand.yaml"


@pytest.fixture(scope="module")
def coupled_plan(tmp_path_factory):
    folder = tmp_path_factory.mktemp("coupled")
    spec = _coupled_icub(folder / "hand")
    grasps = []
    for name in ("box_parallel_extension", "box_ir2m"):
        text = (ROOT / "grasps/icub" / f"{name}.yaml").read_text().replace("hand: icub_right", f"hand: {spec}")
        (folder / f"{name}.yaml").write_text(text)
        grasps.append(folder / f"{name}.yaml")
    out = folder / "plan.json"
    assert main(["plan", *map(str, grasps), "--execution", "--no-verify", "-o", str(out)]) == 0
    return Hand.load(spec), out


def test_a_plan_of_the_coupled_hand_keeps_every_coupling_in_every_state_and_waypoint(coupled_plan):
    hand, path = coupled_plan
    assert len(hand.couplings) == 5 and hand.couplings[0].source.startswith("URDF line")
    plan = read_plan(path)
    col = {j: i for i, j in enumerate(plan.joints)}
    waypoints = 0
    for st in plan.states:
        q = np.array([st.q[col[j]] for j in hand.joint_names])
        assert np.max(hand.coupling_errors(q)) <= 1e-9  # exact up to the file's 10 digits
    for s in plan.steps:
        q = np.array([plan.states[s.from_state].q[col[j]] for j in hand.joint_names])
        for row in np.asarray(s.path, float):
            q[[hand.joint_names.index(j) for j in s.joints]] = row
            assert np.max(hand.coupling_errors(q)) <= 1e-9, s.finger
            waypoints += 1
    assert waypoints > 50
    rep = audit_plan(plan)
    assert rep.ok, rep.problems


def test_verify_refuses_a_plan_edited_to_break_a_coupling(coupled_plan, tmp_path, capsys):
    hand, path = coupled_plan
    data = json.loads(path.read_text())
    # index_3 turned 0.05 rad past index_2 in every state and index path (consistent steps;
    # its tolerance: 0.5 mm at the distal link's reach)
    for st in data["states"]:
        st["q"]["index_3"] += 0.05
    for st in data["steps"]:
        if "index_3" in st["joints"]:
            for row in st["path"]:
                row[st["joints"].index("index_3")] += 0.05
    k = 0
    data["integrity"] = integrity_record(data)
    bad = path.parent / "state.json"  # beside the plan: its hand.spec is relative to it
    bad.write_text(json.dumps(data))
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"states[{k}].q: index_3 = " in out and "breaks its coupling index_3 = 1 index_2 + 0 (URDF line" in out, out
    tol = hand.coupling_tolerances()[0]
    assert 1e-3 < tol < 0.05 and f"by 0.05, tolerance {tol:.3g}" in out, out
    # a path waypoint: the thumb's distal joint off its driver
    data = json.loads(path.read_text())
    s = next(i for i, st in enumerate(data["steps"]) if "middle_3" in st["joints"] or "thumb_3" in st["joints"]
             or "ring_3" in st["joints"])
    step = data["steps"][s]
    c = next(j for j in ("middle_3", "thumb_3", "ring_3") if j in step["joints"])
    step["path"][1][step["joints"].index(c)] += 0.1
    data["integrity"] = integrity_record(data)
    bad.write_text(json.dumps(data))
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"steps[{s}]" in out and "path waypoint 1: " in out and f"{c} = " in out and "breaks its coupling" in out, out


def test_bundled_hands_have_no_couplings_and_plan_as_before():
    """No coupling, no change: the reduction is the identity on an uncoupled finger."""
    for name in ("allegro_right",):
        hand = Hand.load(name)
        assert not hand.couplings
        assert np.array_equal(hand.lower, hand.urdf_lower) and np.array_equal(hand.upper, hand.urdf_upper)
        for f in hand.fingers.values():
            J = np.arange(6.0 * len(f.joints)).reshape(6, -1)
            assert f.reduce(J) is J and f.drivers == f.joints


def test_hand_init_lists_the_urdf_couplings_and_a_follower_opens_with_its_driver(tmp_path, capsys):
    urdf = tmp_path / "coupled_hand.urdf"
    # a follower whose range does not start at 0: init writes no open: angle for it
    urdf.write_text(URDF.replace('<limit lower="0" upper="1.5708" effort="0.5" velocity="1"/>' + MIMIC_LINE,
                                 '<limit lower="-0.2" upper="1.5708" effort="0.5" velocity="1"/>' + MIMIC_LINE))
    assert main(["hand", "init", str(urdf), "-o", str(tmp_path / "hand.yaml")]) == 0
    out = capsys.readouterr().out
    assert "guess: couplings: the URDF's <mimic>: left_2 = 1 left_1 + 0: a plan commands the drivers" in out, out
    hand = Hand.load(tmp_path / "hand.yaml")
    assert [c.joint for c in hand.couplings] == ["left_2"]
    assert "left_2" not in (yaml.safe_load((tmp_path / "hand.yaml").read_text()).get("open") or {})
    assert np.all(hand.coupling_errors(hand.q_open) == 0.0)


def test_a_grasp_posture_must_keep_the_coupling(coupled_plan, tmp_path, capsys):
    hand, _ = coupled_plan
    text = (ROOT / "grasps/icub/box_ir2m.yaml").read_text().replace("hand: icub_right", f"hand: {hand.spec_path}")
    bad = tmp_path / "g.yaml"
    bad.write_text(text.replace("index:  {posture: [0.0, 0.0, 0.0, 0.0]}", "index:  {posture: [0.0, 0.1, 0.2, 0.3]}"))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fingers.index.posture[3]: joint index_3 = 0.3 rad breaks its coupling index_3 = 1 " \
        "index_2 + 0: give 0.2" in err[0], err
    bad.write_text(text.replace("index:  {posture: [0.0, 0.0, 0.0, 0.0]}", "index:  {posture: [0.0, 0.1, 0.2, 0.2]}"))
    assert main(["check", str(bad)]) in (0, 1)


def test_a_mimic_naming_no_joint_is_refused_or_adopted_by_hand_init(tmp_path, capsys):
    """A published robot's <mimic joint="index_q1"> for its joint Right_index_q1: loading the
    hand refuses it (say the coupling in the hand.yaml); hand init adopts the finger's one joint
    whose name ends so, as a hand.yaml coupling, and says so."""
    text = URDF.replace(MIMIC_LINE, '<mimic joint="ft_1" multiplier="1.0" offset="0.0"/>')
    line = _urdf_error(tmp_path, text)
    assert "follows 'ft_1', which is not a joint of the URDF: state the coupling in the hand.yaml's couplings:" in line
    urdf = tmp_path / "typo.urdf"
    urdf.write_text(text)
    assert main(["hand", "init", str(urdf), "-o", str(tmp_path / "hand.yaml")]) == 0
    out = capsys.readouterr().out
    assert "guess: couplings: left_2 = 1 left_1 + 0: the URDF's <mimic> (line " in out and "names 'ft_1'" in out, out
    hand = Hand.load(tmp_path / "hand.yaml")
    assert [(c.joint, c.follows, c.source) for c in hand.couplings] == [("left_2", "left_1", "hand.yaml couplings[0]")]


ALEX = "alex_description/urdf/alex_psyonic_hands.urdf"


def test_a_published_prosthetic_hand_plans_with_its_couplings(tmp_path, capsys):
    """example-robot-data's Alex with Psyonic hands (issue 37): its <mimic>s name joints
    without the side prefix; hand init --root adopts them, synth and plan keep q2 = 1.0585 q1 +
    0.7235 (the issue's plan had q1 0.355, q2 0.088 where the hand can only take q2 = 1.10)."""
    from planner.urdf_check import installed_share_dirs

    found = [Path(d) / "example-robot-data/robots" / ALEX for d in installed_share_dirs()]
    found = [p for p in found if p.is_file()]
    if not found:
        pytest.skip("example-robot-data is not installed")
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(found[0]), "-o", str(out), "--root", "RightGripperYawLink"]) == 0
    hand = Hand.load(out)
    assert [(c.joint, c.follows) for c in hand.couplings] == [
        (f"Right_{f}_q2", f"Right_{f}_q1") for f in ("index", "middle", "ring", "pinky")]
    assert all(c.multiplier == pytest.approx(1.05851325) and c.offset == pytest.approx(0.72349796)
               for c in hand.couplings)
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.03]\nmass_kg: 0.05\n")
    assert main(["synth", str(out), str(ball), "--fingers", "thumb,index,middle,ring", "-n", "1", "-o",
                 str(tmp_path / "g"), "--quiet"]) == 0
    grasp = next((tmp_path / "g").glob("*.yaml"))
    plan = tmp_path / "hold.json"
    assert main(["plan", str(grasp), str(grasp), "--execution", "--no-verify", "-o", str(plan)]) == 0
    capsys.readouterr()
    data = json.loads(plan.read_text())
    for st in data["states"]:
        q = np.array([st["q"][j] for j in hand.joint_names])
        assert np.max(hand.coupling_errors(q)) <= 1e-9
        i1, i2 = hand.joint_names.index("Right_index_q1"), hand.joint_names.index("Right_index_q2")
        assert q[i2] == pytest.approx(1.05851325 * q[i1] + 0.72349796, abs=1e-9)
    assert main(["verify", str(plan)]) == 0
