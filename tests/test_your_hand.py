"""docs/YOUR_HAND.md, run: two published hands from their registry package (example-robot-data,
a dependency) as shipped, through the page's first four steps with its own commands: ``hand
init --root``, ``hand check``, ``synth`` (seeded, 2 grasps), ``plan --execution`` (without the
simulator's verification, which the page runs, as ``replay --gravity-set 6``).

- the Unitree G1's right hand (a whole-robot URDF; a thumb closing toward its lower limits);
- Alex's right Psyonic hand (a whole-robot URDF with 4 ``<mimic>`` joints naming no joint).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from planner.cli import main
from planner.hand import Hand
from tests.test_published_hands import G1, _robots

ALEX = "alex_description/urdf/alex_psyonic_hands.urdf"

#: The page's object files (docs/YOUR_HAND.md): a pose against each hand's palm.
G1_BALL = "shape: sphere\nsize: [0.03]\nposition: [0.1092, 0.046, 0.0086]\nmass_kg: 0.05\n"
ALEX_BOX = ("shape: box\nsize: [0.04, 0.04, 0.04]\nposition: [-0.003, 0.0251, -0.1349]\n"
            "quat_xyzw: [-0.6199, 0.0, 0.7847, 0.0]\nmass_kg: 0.05\n")


def _walk(tmp_path, capsys, urdf: str, root: str, obj_text: str, fingers: list[str]) -> tuple[Path, dict]:
    """hand init, hand check, synth and plan --execution --no-verify as the page gives them:
    (the hand.yaml, the plan)."""
    hand_yaml = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(_robots() / urdf), "--root", root, "-o", str(hand_yaml), "-q"]) == 0
    capsys.readouterr()
    assert main(["hand", "check", str(hand_yaml)]) == 0
    assert re.search(r": 0 error\(s\)", capsys.readouterr().out)
    obj = tmp_path / "object.yaml"
    obj.write_text(obj_text)
    grasps = tmp_path / "grasps"
    cmd = ["synth", str(hand_yaml), str(obj), "--palm", "-n", "2", "--seed", "0", "-o", str(grasps), "-q"]
    if fingers:
        cmd += ["--fingers", ",".join(fingers)]
    assert main(cmd) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()[:2]
    # each grasp held in the simulator as plan --execution replays an initial grasp, or refused by it
    assert all(" execution-ready, held in " in line or " not for --execution as an initial grasp: does not hold in the simulator (" in line
               for line in lines), out
    assert " execution-ready, held in " in lines[0], out  # the first ranked one held
    first, second = sorted(grasps.glob("*.yaml"))
    plan = tmp_path / "plan.yaml"
    assert main(["plan", str(first), str(second), "--execution", "--no-verify", "-o", str(plan), "-q"]) == 0
    data = yaml.safe_load(plan.read_text())
    assert data["steps"] and data["summary"]["gait_steps"] >= 1
    return hand_yaml, data


def test_unitree_g1_hand_from_its_robot_urdf_to_a_regrasp_plan(tmp_path, capsys):
    hand_yaml, plan = _walk(tmp_path, capsys, G1, "right_wrist_yaw_link", G1_BALL, ["thumb", "index", "middle"])
    # the thumb closes toward its lower limits (item 4): hand init wrote it, and its open
    # posture is at the other end (thumb_1 at its upper limit 0.61 rad; thumb_2's is 0)
    spec = yaml.safe_load(hand_yaml.read_text())
    thumb = spec["fingers"]["thumb"]
    assert thumb["close_joints"] == ["right_hand_thumb_1_joint", "right_hand_thumb_2_joint"]
    assert thumb["close_toward"] == {"right_hand_thumb_1_joint": "lower", "right_hand_thumb_2_joint": "lower"}
    hand = Hand.load(hand_yaml)
    i1 = hand.joint_names.index("right_hand_thumb_1_joint")
    assert hand.q_open[i1] == pytest.approx(hand.upper[i1]) == pytest.approx(0.61086523)
    # the plan moves the thumb (a palm-supported regrasp) and every state is in the limits
    assert any(s.startswith("thumb:") for s in plan["summary"]["order"])
    for s in plan["states"]:
        for j, v in s["q"].items():
            i = hand.joint_names.index(j)
            assert hand.lower[i] - 1e-9 <= v <= hand.upper[i] + 1e-9, (j, v)


def test_alex_psyonic_hand_with_its_mimic_joints_to_a_regrasp_plan(tmp_path, capsys):
    hand_yaml, plan = _walk(tmp_path, capsys, ALEX, "RightGripperYawLink", ALEX_BOX, [])
    hand = Hand.load(hand_yaml)
    assert len(hand.couplings) == 4  # adopted from the URDF's <mimic> naming no joint
    assert set(plan["states"][0]["fingers"]) == set(hand.fingers)  # --palm: every finger by default
    # every state keeps each follower on its driver: q2 = 1.0585 q1 + 0.7235
    for s in plan["states"]:
        q = s["q"]
        for c in hand.couplings:
            assert q[c.joint] == pytest.approx(c.multiplier * q[c.follows] + c.offset, abs=1e-8)


def test_synth_names_the_finger_that_fails(tmp_path, capsys):
    """The G1 hand set up as before closing directions (every thumb joint closing toward its
    upper limit, the thumb open fully flexed): synth's drops are the thumb's, and it says so;
    with hand init's closing directions the thumb drops none of them."""
    from planner.synthesis import finger_table, load_object_file, synthesize

    new = tmp_path / "g1" / "hand.yaml"
    new.parent.mkdir()
    assert main(["hand", "init", str(_robots() / G1), "--root", "right_wrist_yaw_link", "-o", str(new), "-q"]) == 0
    spec = yaml.safe_load(new.read_text())
    thumb = spec["fingers"]["thumb"]
    del thumb["close_toward"]
    thumb["close_joints"] = list(thumb["joints"])
    hand = Hand.load(new)
    spec["open"] = {j: float(hand.lower[hand.joint_names.index(j)]) for j in thumb["joints"]}
    old = tmp_path / "g1" / "upward.yaml"
    old.write_text(yaml.safe_dump(spec, sort_keys=False))
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.03]\nposition: [0.14, 0.062, 0.011]\nmass_kg: 0.05\n")
    obj, _, fixed = load_object_file(ball)
    results = {}
    for name, path in (("upward", old), ("init", new)):
        results[name] = synthesize(str(path), obj, ["thumb", "index", "middle"], 10, fixed=fixed, seed=0,
                                   max_attempts=8, base_dir=tmp_path)
    up = results["upward"]
    # every candidate dropped was dropped for the thumb (the reasons counted overall, by finger)
    assert sum(up.by_finger["thumb"].values()) == sum(up.rejected.values()) >= 2
    assert not up.by_finger["index"] and not up.by_finger["middle"]
    table = finger_table(up)
    assert re.search(r"thumb\s+\d+\s+\d+ a finger misses the object", table)
    assert "try: fingers.thumb: its closing motion misses the object" in table
    assert not any(results["init"].by_finger.values()) and len(results["init"].grasps) > len(up.grasps)


def test_the_g1_left_hand_mirrored_flexes_toward_its_lower_limits(tmp_path, capsys):
    """The G1's left hand is the right one mirrored: its fingers flex toward their lower limits
    (index_0 in [-1.571, 0]) and its thumb toward its upper ones. hand init takes flexion as
    the larger part of each range, so the palm normal is the right hand's negated and every
    closing direction the right hand's reversed; synth then finds its grasps (1 of 10 in
    600 attempts when every joint closed upward)."""
    specs = {}
    for side in ("left", "right"):
        out = tmp_path / side / "hand.yaml"
        out.parent.mkdir()
        assert main(["hand", "init", str(_robots() / G1), "--root", f"{side}_wrist_yaw_link", "-o", str(out), "-q"]) == 0
        specs[side] = yaml.safe_load(out.read_text())
    left, right = specs["left"], specs["right"]
    assert left["palm_normal"] == [-v + 0.0 for v in right["palm_normal"]] == [0.0, -1.0, 0.0]
    for f in ("thumb", "index", "middle"):
        mirror = [j.replace("right_", "left_") for j in right["fingers"][f]["close_joints"]]
        assert left["fingers"][f]["close_joints"] == mirror
        down_r = set(right["fingers"][f].get("close_toward", {}))
        down_l = set(left["fingers"][f].get("close_toward", {}))
        assert down_l == {j.replace("right_", "left_") for j in right["fingers"][f]["close_joints"]} - {
            j.replace("right_", "left_") for j in down_r}, f
    hand = Hand.load(tmp_path / "left" / "hand.yaml")
    for j in hand.fingers["index"].close_joints:  # open at 0, the upper end, away from flexion
        i = hand.joint_names.index(j)
        assert hand.q_open[i] == hand.upper[i] == 0.0 and hand.lower[i] < -1.5
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.03]\nmass_kg: 0.05\n")
    capsys.readouterr()
    assert main(["synth", str(tmp_path / "left" / "hand.yaml"), str(ball), "-n", "2", "--seed", "0", "-o",
                 str(tmp_path / "g"), "-q"]) == 0
    assert "2/2 grasps" in capsys.readouterr().out


#: A 30 mm ball at a pose against the Psyonic palm (docs/YOUR_HAND.md, section 2: the pair that passes).
ALEX_BALL = "shape: sphere\nsize: [0.03]\nposition: [0.0004, 0.0313, -0.1284]\nmass_kg: 0.05\n"


@pytest.fixture(scope="module")
def psyonic_hold(tmp_path_factory):
    """(hand.yaml, a one-state plan file) of a synthesized Psyonic power grasp of the ball."""
    import contextlib
    import io

    d = tmp_path_factory.mktemp("psyonic")
    hand_yaml = d / "hand.yaml"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["hand", "init", str(_robots() / ALEX), "--root", "RightGripperYawLink", "-o", str(hand_yaml),
                     "-q"]) == 0
        (d / "ball.yaml").write_text(ALEX_BALL)
        assert main(["synth", str(hand_yaml), str(d / "ball.yaml"), "--palm", "-n", "1", "--seed", "0", "-o",
                     str(d / "g"), "-q"]) == 0
        grasp = next((d / "g").glob("*.yaml"))
        plan = d / "hold.yaml"
        assert main(["plan", str(grasp), str(grasp), "--execution", "--no-verify", "-o", str(plan), "-q"]) == 0
    return hand_yaml, plan


def test_a_psyonic_grasp_without_its_thumb_has_no_release_equilibrium(psyonic_hold):
    """The four one-actuator fingers close onto their slides, all pushing the ball the same
    way: with the thumb the closed grasp balances at its release, without it nothing does
    (`planner.grip.release_equilibrium`; the simulator drops such states, docs/YOUR_HAND.md)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from planner.closure import apply_contact_model
    from planner.grip import grasp_statics, release_equilibrium
    from planner.sim.inputs import typed_plan

    hand_yaml, plan_path = psyonic_hold
    rd = typed_plan(str(plan_path))
    hand = Hand.load(hand_yaml)
    st = rd.states[0]
    q = np.zeros(len(hand.joint_names))
    for j, v in zip(rd.joints, st.q):
        q[hand.joint_names.index(j)] = v
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rotation.from_quat(rd.object.quat_xyzw).as_matrix(), rd.object.position
    patches = apply_contact_model(st.patches, rd.parameters["contact_model"])
    statics = grasp_statics(hand, q, patches, T)
    assert release_equilibrium(patches, statics, rd.friction)
    for drop in ("thumb", "index"):
        p = {f: v for f, v in patches.items() if f != drop}
        assert release_equilibrium(p, {f: v for f, v in statics.items() if f != drop}, rd.friction) == (drop != "thumb")


def test_the_replay_starts_outside_the_object_and_holds_the_psyonic_ball(psyonic_hold, monkeypatch):
    """The planned posture overlaps pybullet's geometry; the replay backs the holding coupled
    (one-actuator) fingers out along their normals and moves the ball out of the palm before
    closing them under their torques: none of their links overlaps the ball at the start, the
    couplings kept."""
    pytest.importorskip("pybullet")
    from planner.sim import replay as R

    _, plan_path = psyonic_hold
    seen = {}
    place, clear = R._Sim.start_place, R._Sim.start_clear

    def start_place(self, pos, quat):
        seen["before"] = min(cp.distance_m for cp in self.engine.closest_points(0.002))
        return place(self, pos, quat)

    def start_clear(self, fingers):
        moved = clear(self, fingers)
        seen["cleared"] = set(fingers)  # the coupled fingers (`_Sim.friction_locked`), not the thumb
        seen["after"] = min(cp.distance_m for cp in self.engine.closest_points(0.002)
                            if self.ctl.link_finger.get(cp.link) in fingers)
        seen["moved"] = moved
        q = self.ctl.q()
        seen["coupling"] = max(self.ctl.hand.coupling_errors(q))
        return moved

    monkeypatch.setattr(R._Sim, "start_place", start_place)
    monkeypatch.setattr(R._Sim, "start_clear", start_clear)
    import os

    cwd = os.getcwd()
    os.chdir(plan_path.parent)
    try:
        report = R.replay_plan(str(plan_path), engine="pybullet")
    finally:
        os.chdir(cwd)
    assert seen["before"] < -2e-4  # the planned posture overlaps the engine's hulls
    assert seen["cleared"] and "thumb" not in seen["cleared"]  # two actuators: not friction-locked
    assert seen["after"] >= -1e-5
    # the coupled fingers (closing toward their upper limits) opened, their followers with them
    coupled = {j: v for j, v in seen["moved"].items() if not j.startswith("Right_thumb")}
    assert len(coupled) == 8 and all(v < 0 for v in coupled.values())
    assert seen["coupling"] <= 1e-9
    assert report.passed, report.verdict
