"""Published robot models as shipped (issue 37 items 1, 3, 5): a hand cut out of a humanoid's
URDF with ``hand init --root``, links without ``<inertial>`` given a stated inertia, and
``package://`` / relative mesh paths resolved the same way by pinocchio, coal, pybullet and
the viewer. The robots are example-robot-data's (a dependency), read where pip put them."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
import yaml

from planner.cli import main
from planner.hand import Hand
from planner.urdf_check import installed_share_dirs

ROOT = Path(__file__).resolve().parents[1]


def _robots() -> Path:
    for d in installed_share_dirs():
        cand = Path(d) / "example-robot-data" / "robots"
        if cand.is_dir():
            return cand
    pytest.skip("example-robot-data is not installed")


#: Unitree G1 with its three-finger hands: 43 moving joints, both hands' fingers under the wrists.
G1 = "g1_description/urdf/g1_29dof_with_hand_rev_1_0.urdf"


def _pybullet_joints(urdf_path):
    from planner.sim.scene import hand_body, p

    cid = p.connect(p.DIRECT)
    try:
        body = hand_body(cid, urdf_path, visual=False)
        return [p.getJointInfo(body, i, physicsClientId=cid)[1].decode()
                for i in range(p.getNumJoints(body, physicsClientId=cid))]
    finally:
        p.disconnect(physicsClientId=cid)


def test_a_robots_urdf_is_refused_with_its_hands_listed(tmp_path, capsys):
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(_robots() / G1), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--root" in err
    assert "'left_wrist_yaw_link' (3 fingers)" in err and "'right_wrist_yaw_link' (3 fingers)" in err
    assert "pelvis" not in err  # legs (6 joints) are no fingers
    assert not out.exists()


def test_a_hand_whose_fingers_share_one_actuator_is_refused_naming_the_robots_urdf(tmp_path, capsys):
    """Romeo's hands close all fingers with one motor (its finger joints <mimic> 'RHand'): no
    finger lifts alone, so no regrasp. hand init --root says so in one line naming the robot's
    URDF and the joint (it named the sub-tree file it had just removed, with that file's line
    numbers, and said "a coupling joins two joints of one finger" of two fingers); nothing is
    left behind."""
    urdf = _robots() / "romeo_description/urdf/romeo.urdf"
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(urdf), "--root", "r_wrist", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"regrasp hand: error: {urdf}: the hand below r_wrist: joint "), err
    assert "RHand is of finger" in err[0] and "a coupling joins joints of one finger only" in err[0], err
    assert "line " not in err[0]
    assert not list(tmp_path.iterdir())


def test_a_robot_without_fingered_hands_is_refused_too(tmp_path, capsys):
    # example-robot-data's iCub: legs, arms and head, no fingers
    assert main(["hand", "init", str(_robots() / "icub_description/robots/icub.urdf"), "-o",
                 str(tmp_path / "h.yaml")]) == 2
    assert "hands found: none" in capsys.readouterr().err


@pytest.mark.needs_pybullet("the cut-out hand loaded by pybullet's URDF loader")
def test_root_cuts_the_hand_out_of_a_humanoid(tmp_path, capsys):
    out = tmp_path / "g1r" / "hand.yaml"
    out.parent.mkdir()
    assert main(["hand", "init", str(_robots() / G1), "-o", str(out), "--root", "right_wrist_yaw_link"]) == 0
    data = yaml.safe_load(out.read_text())
    assert data["urdf"] == "hand.urdf" and data["palm_frame"] == "right_wrist_yaw_link"
    hand = Hand.load(out)
    assert len(hand.joint_names) == 7 and all(j.startswith("right_hand_") for j in hand.joint_names)
    assert list(hand.fingers) == ["thumb", "index", "middle"]
    assert all(g.link.startswith("right_hand_") or g.link == "right_wrist_yaw_link" for g in hand.collision.geometries)
    # pybullet loads the sub-tree only (package:// meshes resolved), every body of it
    names = _pybullet_joints(hand.urdf_path)
    assert set(hand.joint_names) <= set(names)
    assert all(n.startswith("right_hand_") for n in names), names
    capsys.readouterr()
    assert main(["hand", "check", str(out)]) == 0
    assert re.search(r"0 error\(s\)", capsys.readouterr().out)
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.03]\nmass_kg: 0.05\n")
    assert main(["synth", str(out), str(ball), "--fingers", "thumb,index,middle", "-n", "1", "-o",
                 str(tmp_path / "g"), "--quiet"]) == 0
    assert main(["check", str(next((tmp_path / "g").glob("*.yaml")))]) == 0


def test_root_must_be_a_link(tmp_path, capsys):
    assert main(["hand", "init", str(_robots() / G1), "-o", str(tmp_path / "h.yaml"), "--root", "no_such_link"]) == 2
    assert "no_such_link" in capsys.readouterr().err


def _massless_icub(tmp_path) -> Path:
    """The bundled iCub hand with the index's distal phalanx and tip links stripped of their
    <inertial> (a published hand's fingertip anchors have none)."""
    src = Path(Hand.load("icub_right").spec_path).parent
    out = tmp_path / "icub_massless"
    shutil.copytree(src, out)
    urdf = out / "icub_right.urdf"
    text = urdf.read_text()
    for link in ("index_distal", "index_tip"):
        text = re.sub(rf'(<link name="{link}">\s*)<inertial>.*?</inertial>', r"\1", text, count=1, flags=re.S)
    urdf.write_text(text)
    return out / "hand.yaml"


@pytest.mark.needs_pybullet("the masses pybullet's replay body gets")
def test_links_without_inertia_get_the_stated_mass_everywhere(tmp_path, capsys):
    import math

    import numpy as np

    from planner.sim.scene import hand_body, p
    from planner.urdf_check import MIN_STATED_MASS_KG, STATED_DENSITY_KG_M3

    spec = _massless_icub(tmp_path)
    hand = Hand.load(spec)
    r, length = 0.0065, 0.0103  # index_distal: a cylinder and its two end spheres
    distal = STATED_DENSITY_KG_M3 * (math.pi * r * r * length + 2 * 4.0 / 3.0 * math.pi * r ** 3)
    assert set(hand.stated_inertia) == {"index_distal", "index_tip"}
    assert hand.stated_inertia["index_distal"][0] == pytest.approx(distal, rel=1e-9)
    tip_has_geometry = "index_tip" in hand.links
    if not tip_has_geometry:
        assert hand.stated_inertia["index_tip"][0] == MIN_STATED_MASS_KG
    # pinocchio: the index's last joint carries the stated masses (the URDF's were 10 g + 1 g)
    ref = Hand.load("icub_right")
    j = hand.model.getJointId(hand.fingers["index"].joints[-1])
    assert hand.model.inertias[j].mass == pytest.approx(
        sum(m for m, _ in hand.stated_inertia.values()), rel=1e-9)
    assert ref.model.inertias[j].mass == pytest.approx(0.011, rel=1e-9)
    # pybullet (the replay's body): the same masses and moments, not pybullet's 1 kg
    cid = p.connect(p.DIRECT)
    try:
        body = hand_body(cid, hand.urdf_path, inertia_from_file=True, visual=False)
        got = {}
        for i in range(p.getNumJoints(body, physicsClientId=cid)):
            link = p.getJointInfo(body, i, physicsClientId=cid)[12].decode()
            info = p.getDynamicsInfo(body, i, physicsClientId=cid)
            got[link] = (info[0], info[2])
    finally:
        p.disconnect(physicsClientId=cid)
    for link, (mass, moments) in hand.stated_inertia.items():
        assert got[link][0] == pytest.approx(mass, rel=1e-6)
        assert np.allclose(got[link][1], moments, rtol=1e-6)
    assert got["index_intermediate"][0] != pytest.approx(1.0)
    # hand check names them and the mass given
    assert main(["hand", "check", str(spec)]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("warning: inertia:"))
    assert "index_distal" in line and "index_tip" in line and f"{distal * 1000:.3g} g" in line and "1 kg" in line


def _grasp_for(spec, tmp_path) -> Path:
    """The bundled iCub sphere grasp, held by the hand at ``spec`` (same joints)."""
    text = (ROOT / "grasps" / "icub" / "sphere_ir2m.yaml").read_text()
    path = tmp_path / "grasp.yaml"
    path.write_text(re.sub(r"(?m)^hand: .*$", f"hand: {spec}", text))
    return path


def _pybullet_mesh_links(urdf_path) -> set:
    from planner.sim.scene import hand_body, p

    cid = p.connect(p.DIRECT)
    try:
        body = hand_body(cid, urdf_path, visual=False)
        out = set()
        for i in range(p.getNumJoints(body, physicsClientId=cid)):
            if any(s[2] == p.GEOM_MESH for s in p.getCollisionShapeData(body, i, physicsClientId=cid)):
                out.add(p.getJointInfo(body, i, physicsClientId=cid)[12].decode())
        return out
    finally:
        p.disconnect(physicsClientId=cid)


@pytest.mark.needs_pybullet("pybullet's mesh loader")
def test_relative_mesh_paths_resolve_against_the_urdf_folder_in_every_command(tmp_path, capsys):
    from tests.test_mesh_hand import mesh_hand

    spec = mesh_hand(tmp_path / "hand")
    hand = Hand.load(spec)
    assert "index_distal" in _pybullet_mesh_links(hand.urdf_path)
    grasp = _grasp_for(spec, tmp_path)
    elsewhere = tmp_path / "run"
    elsewhere.mkdir()
    import os

    cwd = os.getcwd()
    os.chdir(elsewhere)  # no command may resolve meshes/... against the working directory
    try:
        assert main(["view", str(grasp), "-o", "g.html"]) == 0
        assert main(["hand", "check", str(spec)]) == 0
    finally:
        os.chdir(cwd)
    assert "ok: pybullet: loads the URDF" in capsys.readouterr().out


def _package_hand(tmp_path) -> tuple[Path, Path]:
    """The mesh iCub hand with its meshes in a ROS package ``icub_mesh_pkg`` under
    ``pkgs/``, named by ``package://`` paths, the URDF in another folder: (URDF, pkgs)."""
    from tests.test_mesh_hand import mesh_hand

    spec = mesh_hand(tmp_path / "src")
    pkgs = tmp_path / "pkgs"
    (pkgs / "icub_mesh_pkg").mkdir(parents=True)
    shutil.move(str(spec.parent / "meshes"), str(pkgs / "icub_mesh_pkg" / "meshes"))
    urdf = tmp_path / "robot" / "icub_mesh.urdf"
    urdf.parent.mkdir()
    urdf.write_text((spec.parent / "icub_mesh.urdf").read_text().replace('filename="meshes/',
                                                                          'filename="package://icub_mesh_pkg/meshes/'))
    shutil.rmtree(spec.parent)
    return urdf, pkgs


@pytest.mark.needs_pybullet("pybullet's mesh loader")
@pytest.mark.parametrize("how", ["package-dir", "ROS_PACKAGE_PATH"])
def test_package_paths_resolve_for_pinocchio_pybullet_and_the_viewer(tmp_path, capsys, monkeypatch, how):
    urdf, pkgs = _package_hand(tmp_path)
    out = tmp_path / "hands" / "hand.yaml"
    out.parent.mkdir()
    # without the package's folder the meshes are not found: said, naming the file
    assert main(["hand", "init", str(urdf), "-o", str(out)]) == 2
    assert "package://icub_mesh_pkg/meshes/" in capsys.readouterr().err
    extra = ["--package-dir", str(pkgs)] if how == "package-dir" else []
    if how == "ROS_PACKAGE_PATH":
        monkeypatch.setenv("ROS_PACKAGE_PATH", str(pkgs))
    assert main(["hand", "init", str(urdf), "-o", str(out), *extra]) == 0
    hand = Hand.load(out)  # pinocchio and coal: the hulls of the package's meshes
    assert type(next(g for g in hand.collision.geometries if g.link == "index_distal").shape).__name__ == "ConvexBase"
    assert "index_distal" in _pybullet_mesh_links(hand.urdf_path)  # pybullet: a resolved copy
    capsys.readouterr()
    assert main(["hand", "check", str(out)]) == 0
    assert "ok: pybullet: loads the URDF" in capsys.readouterr().out
    assert main(["view", str(_grasp_for(out, tmp_path)), "-o", str(tmp_path / "g.html")]) == 0
    page = (tmp_path / "g.html").read_text()
    assert len(page) > 100_000
