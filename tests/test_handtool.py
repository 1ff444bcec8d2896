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
        assert fs["pad"]["link"] == ref.fingers[f].links[-1]
    # every guess comes with its reason, one line each
    assert all(f.level in ("guess", "warning", "ok") and "\n" not in f.line() for f in rep.findings)
    assert any(f.what == "palm_normal" for f in rep.findings)


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
