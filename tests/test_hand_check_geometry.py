"""`hand check` reports a finger without collision geometry as an error (exit 1), as `hand
init` does: it said '0 error(s)' for the hand.yaml that `hand init` had just written with
'error: fingers.finger_0: no link of the finger has collision geometry: it cannot touch'."""

from planner.cli import main

URDF = """<?xml version="1.0"?>
<robot name="bare"><link name="base"><collision><geometry><box size="0.05 0.05 0.01"/></geometry></collision></link>
<link name="a"/><link name="b"/><link name="c"/><link name="d"/>
<joint name="j1" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0.03 0.01 0"/><axis xyz="0 1 0"/>
<limit lower="0" upper="1" effort="1" velocity="1"/></joint>
<joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.02 0 0"/><axis xyz="0 1 0"/>
<limit lower="0" upper="1" effort="1" velocity="1"/></joint>
<joint name="j3" type="revolute"><parent link="base"/><child link="c"/><origin xyz="0.03 -0.01 0"/><axis xyz="0 1 0"/>
<limit lower="0" upper="1" effort="1" velocity="1"/></joint>
<joint name="j4" type="revolute"><parent link="c"/><child link="d"/><origin xyz="0.02 0 0"/><axis xyz="0 1 0"/>
<limit lower="0" upper="1" effort="1" velocity="1"/></joint>
</robot>
"""


def test_hand_check_agrees_with_hand_init_on_a_finger_without_geometry(tmp_path, capsys):
    (tmp_path / "bare.urdf").write_text(URDF)
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(tmp_path / "bare.urdf"), "-o", str(out)]) == 1
    capsys.readouterr()
    assert main(["hand", "check", str(out)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert any(l.startswith("error: fingers.finger_0: no link of the finger has collision geometry") for l in lines)
    assert lines[-1].endswith("2 error(s), 3 warning(s)")
