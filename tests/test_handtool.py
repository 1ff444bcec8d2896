"""``regrasp hand init`` / ``hand check`` (planner.handtool): a hand.yaml inferred from a URDF
alone reproduces the bundled hands' hand-written ones (fingers, joints, closing joints, palm
normal), loads and plans; placeholder inertias and efforts are found and the replay replaces
the inertias."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.cli import main
from planner.hand import Hand
from planner.handtool import box_inertia, check_hand, init_hand, replay_inertia


@pytest.mark.parametrize("name", ["icub_right", "allegro_right"])
def test_init_reproduces_the_hand_written_spec(name):
    ref = Hand.load(name)
    spec, rep = init_hand(ref.urdf_path)
    assert spec["palm_normal"] == list(ref.palm_normal)
    assert list(spec["fingers"]) == list(ref.fingers)  # names (from words or geometry) and order
    for f, fs in spec["fingers"].items():
        assert fs["joints"] == list(ref.fingers[f].joints)
        assert fs["close_joints"] == list(ref.fingers[f].close_joints)
        assert "close_toward" not in fs  # every joint closes toward its upper limit: nothing written
        assert fs["pad"]["link"] == ref.fingers[f].links[-1]
    # every guess comes with its reason, one line each
    assert all(f.level in ("guess", "warning", "ok") and "\n" not in f.line() for f in rep.findings)
    assert any(f.what == "palm_normal" for f in rep.findings)


@pytest.mark.parametrize("side", ["right", "left"])
def test_init_puts_round_fingertips_pads_where_they_touch(tmp_path, capsys, side):
    """The Allegro's fingertips are spheres on links fixed beyond the last joint (pinocchio merges
    them into it and places their geometry in the joint's frame). hand init took those
    placements for the links' own frames and a sphere's first axis for its "longest": the pads
    landed 26.7 mm beyond the tip, on the sphere's side (normal -y), and synth found no grasp
    with the hand it wrote (0 of 240 candidates). Now each pad is the sphere's point the tip
    closes toward: the bundled hand-written one, on both the right hand and its mirror image."""
    urdf = Path(Hand.load("allegro_right").urdf_path).with_name(f"allegro_{side}_hand.urdf")
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(urdf), "-o", str(out), "--quiet"]) == 0
    data = yaml.safe_load(out.read_text())
    ref = Hand.load("allegro_right")
    for f, fs in data["fingers"].items():
        assert fs["pad"]["link"] == ref.fingers[f].pad_link
        np.testing.assert_allclose(fs["pad"]["point"], ref.fingers[f].pad_p_link, atol=1e-6)
        np.testing.assert_allclose(fs["pad"]["normal"], ref.fingers[f].pad_n_link, atol=1e-6)
        assert fs["close_joints"] == list(ref.fingers[f].close_joints)
    obj = tmp_path / "ball.yaml"
    obj.write_text("shape: sphere\nsize: [0.035]\nmass_kg: 0.05\n")
    assert main(["synth", str(out), str(obj), "-n", "2", "-o", str(tmp_path / "g"), "--quiet"]) == 0
    assert len(list((tmp_path / "g").glob("*.yaml"))) == 2


def test_init_writes_a_hand_that_loads_checks_and_grasps(tmp_path, capsys):
    urdf = tmp_path / "robot" / "icub_right.urdf"
    urdf.parent.mkdir()
    shutil.copy(Hand.load("icub_right").urdf_path, urdf)
    out = tmp_path / "hands" / "mine.yaml"
    out.parent.mkdir()
    assert main(["hand", "init", str(urdf), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "wrote" in text and "hand check" in text
    data = yaml.safe_load(out.read_text())
    assert data["urdf"] == "../robot/icub_right.urdf"  # relative: the hand.yaml moves with its URDF
    hand = Hand.load(out)
    assert set(hand.fingers) == {"thumb", "index", "middle", "ring", "little"}
    # the pad faces the palm side: a closed index finger's pad normal points back toward the palm
    q = hand.q_open.copy()
    for j in hand.fingers["index"].close_joints:
        q[hand.joint_names.index(j)] = hand.upper[hand.joint_names.index(j)] * 0.5
    R = hand.state(q).link_pose(hand.fingers["index"].pad_link)[:3, :3]
    assert float((R @ np.asarray(hand.fingers["index"].pad_n_link)) @ np.asarray(hand.palm_normal)) < 0.5
    assert main(["hand", "check", str(out)]) == 0
    assert re.search(r"0 error\(s\)", capsys.readouterr().out)
    # and synth finds a grasp with it (the whole pipeline needs nothing hand-written)
    obj = tmp_path / "ball.yaml"
    obj.write_text("shape: sphere\nsize: [0.025]\nmass_kg: 0.05\n")
    assert main(["synth", str(out), str(obj), "--fingers", "thumb,index,middle", "-n", "1", "-o",
                 str(tmp_path / "g"), "--quiet"]) == 0
    written = next((tmp_path / "g").glob("*.yaml"))
    assert yaml.safe_load(written.read_text())["hand"] == "../hands/mine.yaml"  # relative too
    assert main(["check", str(written)]) == 0


def test_init_refuses_an_output_onto_its_urdf(tmp_path, capsys):
    urdf = tmp_path / "h.urdf"
    shutil.copy(Hand.load("icub_right").urdf_path, urdf)
    before = urdf.read_bytes()
    assert main(["hand", "init", str(urdf), "-o", str(urdf)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert urdf.read_bytes() == before


def _placeholder_copy(tmp_path):
    """The bundled iCub with an exporter's placeholders: 0.01 kg m^2 on every distal phalanx
    and 50 000 N m efforts."""
    src = Hand.load("icub_right")
    text = Path(src.urdf_path).read_text()
    folder = tmp_path / "h"
    folder.mkdir()

    def fat(m):
        block = m.group(0)
        return re.sub(r'<inertia [^>]*/>', '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>', block)

    text = re.sub(r'<link name="[a-z]+_distal">.*?</link>', fat, text, flags=re.S)
    text = re.sub(r'effort="[0-9.]+"', 'effort="50000"', text)
    (folder / "h.urdf").write_text(text)
    spec = yaml.safe_load(src.spec_path.read_text())
    spec["urdf"] = "h.urdf"
    spec.pop("effort", None)
    (folder / "hand.yaml").write_text(yaml.safe_dump(spec))
    return folder / "hand.yaml"


def test_check_finds_placeholder_inertias_and_efforts(tmp_path):
    path = _placeholder_copy(tmp_path)
    hand = Hand.load(path)
    fixed = replay_inertia(hand)
    assert set(fixed) == {f"{f}_distal" for f in hand.fingers}
    for mass, moments, box in fixed.values():
        assert moments.max() == pytest.approx(0.01, rel=1e-3)  # (with the tip frame's body fixed to it)
        assert box.max() < 1e-4 and np.all(box > 0)
    lines = [f.line() for f in check_hand(path).findings]
    assert sum("placeholder; the replay uses the box's" in line for line in lines) == len(hand.fingers)
    assert any(line.startswith("warning: effort:") and "50000" in line for line in lines)
    # the bundled hands have none
    assert replay_inertia(Hand.load("icub_right")) == {} and replay_inertia(Hand.load("allegro_right")) == {}


def test_box_inertia_is_the_solid_box_formula():
    m, a, b, c = 0.3, 0.1, 0.2, 0.4
    assert box_inertia(m, (a, b, c)) == pytest.approx([m * (b * b + c * c) / 12, m * (a * a + c * c) / 12,
                                                      m * (a * a + b * b) / 12])


# ----------------------------------------------------------------- closing directions (issue 37 item 4)


def _flipped_icub(tmp_path, joints=("thumb_1", "thumb_2", "thumb_3")) -> Path:
    """The bundled iCub's URDF with these joints mirrored: axis negated, limits [-upper, -lower].
    The same hand: at q' = -q every link is where it was, so those joints now close toward
    their lower limits (a published thumb's convention)."""
    src = Path(Hand.load("icub_right").urdf_path)
    text = src.read_text()
    for j in joints:
        m = re.search(rf'<joint name="{j}".*?</joint>', text, flags=re.S)
        block = m.group(0)
        ax = [float(v) for v in re.search(r'<axis xyz="([^"]+)"', block).group(1).split()]
        lo, hi = (float(re.search(rf'{k}="([^"]+)"', block).group(1)) for k in ("lower", "upper"))
        new = re.sub(r'<axis xyz="[^"]+"', '<axis xyz="' + " ".join(f"{-v:g}" for v in ax) + '"', block)
        new = re.sub(r'lower="[^"]+"', f'lower="{-hi:g}"', new)
        new = re.sub(r'upper="[^"]+"', f'upper="{-lo:g}"', new)
        text = text.replace(block, new)
    out = tmp_path / "icub_flipped.urdf"
    out.write_text(text)
    return out


def test_init_finds_joints_that_close_toward_their_lower_limit(tmp_path, capsys):
    flipped = ("thumb_1", "thumb_2", "thumb_3")
    urdf = _flipped_icub(tmp_path, flipped)
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(urdf), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert re.search(r"guess: fingers\.thumb: .*thumb_1, thumb_2, thumb_3 close toward their lower limit", text)
    data = yaml.safe_load(out.read_text())
    ref = Hand.load("icub_right")
    # the same closing joints as the hand-written spec, the mirrored ones closing downward
    assert data["fingers"]["thumb"]["close_joints"] == list(ref.fingers["thumb"].close_joints)
    assert data["fingers"]["thumb"]["close_toward"] == {j: "lower" for j in flipped}
    assert all("close_toward" not in fs for f, fs in data["fingers"].items() if f != "thumb")
    hand = Hand.load(out)
    # the open posture is at each closing joint's opening end: a mirrored joint at its upper limit
    for j in flipped:
        i = hand.joint_names.index(j)
        assert hand.q_open[i] == pytest.approx(hand.upper[i]) and hand.fingers["thumb"].closes_toward(j) == "lower"
    # and it is the open posture init writes for the unmirrored hand, mirrored
    spec0, _ = init_hand(ref.urdf_path)
    (tmp_path / "h0").mkdir()
    (tmp_path / "h0" / "hand.yaml").write_text(yaml.safe_dump(spec0))
    plain = Hand.load(tmp_path / "h0" / "hand.yaml")
    for j in ref.joint_names:
        s = -1.0 if j in flipped else 1.0
        assert hand.q_open[hand.joint_names.index(j)] == pytest.approx(s * plain.q_open[plain.joint_names.index(j)]), j


def test_closing_a_mirrored_finger_gives_the_mirrored_posture(tmp_path):
    """The closing procedure (eqs. 8-9) on the mirrored thumb, closing toward its lower limits,
    stops where the original's stops, with the mirrored joints' values negated: the same
    fingertip position on the same ball."""
    from planner.objects import GraspObject

    flipped = ("thumb_1", "thumb_2", "thumb_3")
    ref = Hand.load("icub_right")
    spec = yaml.safe_load((Path(ref.spec_path)).read_text())
    spec["urdf"] = str(_flipped_icub(tmp_path, flipped))
    spec["fingers"]["thumb"]["close_toward"] = {j: "lower" for j in flipped}
    path = tmp_path / "hand.yaml"
    path.write_text(yaml.safe_dump(spec))
    hand = Hand.load(path)
    mirror = np.array([-1.0 if j in flipped else 1.0 for j in ref.joint_names])
    assert [hand.joint_names.index(j) for j in ref.joint_names] == list(range(len(ref.joint_names)))
    tip = ref.state(ref.q_open).link_pose("thumb_tip")[:3, 3]
    for r in (0.02, 0.03):  # a ball the closing thumb meets, in front of its open tip
        obj = GraspObject.from_data({"shape": "sphere", "size": [r], "position": list(tip + [0.01, 0.0, r + 0.02]),
                                     "quat_xyzw": [0, 0, 0, 1]})
        q_ref = ref.close_finger("thumb", ref.q_open, obj)
        q = hand.close_finger("thumb", mirror * ref.q_open, obj)
        assert np.any(np.abs(q_ref - ref.q_open) > 0.1), "the thumb closed"
        np.testing.assert_allclose(q, mirror * q_ref, atol=2e-3 * np.pi)  # within the 0.1 % back-off steps
        tip_ref = ref.state(q_ref).link_pose("thumb_tip")[:3, 3]
        np.testing.assert_allclose(hand.state(q).link_pose("thumb_tip")[:3, 3], tip_ref, atol=1e-4)
        assert ref.state(q_ref).finger_object_distance(obj, "thumb") >= 0.0
        assert hand.state(q).finger_object_distance(obj, "thumb") >= 0.0


@pytest.mark.parametrize("value, message", [
    ({"thumb_0": "lower"}, "closing joint"),             # thumb_0 is not one of the thumb's closing joints
    ({"thumb_1": "down"}, "closing ends are upper, lower"),  # the valid ends are named
    (["thumb_1"], "a mapping closing joint -> lower or upper"),
])
def test_close_toward_is_validated_with_one_line(tmp_path, value, message):
    from planner.errors import SpecError

    ref = Hand.load("icub_right")
    spec = yaml.safe_load((Path(ref.spec_path)).read_text())
    spec["urdf"] = str(ref.urdf_path)
    spec["fingers"]["thumb"]["close_toward"] = value
    path = tmp_path / "hand.yaml"
    path.write_text(yaml.safe_dump(spec))
    with pytest.raises(SpecError) as err:
        Hand.load(path)
    assert "fingers.thumb.close_toward" in str(err.value) and message in str(err.value)
    assert "\n" not in str(err.value)


def test_close_toward_names_drivers_not_followers(tmp_path):
    """The closing procedure moves a coupled finger's drivers: close_toward gives a driver's
    direction (one line naming the driver when it names a follower), and a follower among the
    closing joints moves its driver in the driver's direction."""
    from planner.errors import SpecError
    from planner.ik import closing_drivers, closing_signs

    ref = Hand.load("icub_right")
    spec = yaml.safe_load((Path(ref.spec_path)).read_text())
    spec["urdf"] = str(ref.urdf_path)
    spec["couplings"] = [{"joint": "index_3", "follows": "index_2", "multiplier": 1.0}]
    spec["fingers"]["index"]["close_toward"] = {"index_3": "lower"}
    path = tmp_path / "hand.yaml"
    path.write_text(yaml.safe_dump(spec))
    with pytest.raises(SpecError, match=r"fingers\.index\.close_toward\.index_3: index_3 follows index_2 \(a coupling\): "
                                        r"give index_2's closing direction"):
        Hand.load(path)
    spec["fingers"]["index"]["close_joints"] = ["index_1", "index_3"]  # index_2 moves as index_3's driver
    spec["fingers"]["index"]["close_toward"] = {"index_2": "lower"}
    path.write_text(yaml.safe_dump(spec))
    hand = Hand.load(path)
    f = hand.fingers["index"]
    assert f.driver_closing() == {"index_1": 1.0, "index_2": -1.0}
    assert [hand.joint_names[i] for i in closing_drivers(hand, f)] == ["index_1", "index_2"]
    assert closing_signs(hand, f).tolist() == [1.0, -1.0]


def test_check_warns_of_a_joint_set_to_close_the_wrong_way(tmp_path):
    """The mirrored thumb with the bundled hand.yaml (every joint closing upward, now away from
    the grasp): hand check says which joints and the fix; with close_toward it says nothing."""
    flipped = ("thumb_1", "thumb_2", "thumb_3")
    ref = Hand.load("icub_right")
    spec = yaml.safe_load((Path(ref.spec_path)).read_text())
    spec["urdf"] = str(_flipped_icub(tmp_path, flipped))
    spec.pop("open", None)
    path = tmp_path / "hand.yaml"
    path.write_text(yaml.safe_dump(spec))
    found = [f for f in check_hand(path).findings if f.what == "fingers.thumb.close_toward"]
    assert [f.text.split(" ")[0] for f in found] == list(flipped) and all(f.level == "warning" for f in found)
    assert "give close_toward: {thumb_1: lower}" in found[0].text
    spec["fingers"]["thumb"]["close_toward"] = {j: "lower" for j in flipped}
    path.write_text(yaml.safe_dump(spec))
    assert not [f for f in check_hand(path).findings if "close_toward" in f.what]
    assert not [f for f in check_hand("icub_right").findings if "close_toward" in f.what]
