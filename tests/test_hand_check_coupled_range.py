"""`hand check` reports a driver whose coupling leaves it a single angle (a follower within
its own limits there only) as an error, as it does a URDF joint with equal limits: it said
'ok: joint index_2: range [0, -0]' and '0 error(s)', and the finger could not close."""

from planner.cli import main
from planner.hand import ROBOTS_DIR


def test_a_coupling_that_pins_its_driver_is_an_error(tmp_path, capsys):
    text = (ROBOTS_DIR / "icub_right" / "hand.yaml").read_text().replace(
        "urdf: icub_right.urdf", f"urdf: {ROBOTS_DIR / 'icub_right' / 'icub_right.urdf'}")
    (tmp_path / "hand.yaml").write_text(text + "couplings:\n  - {joint: index_3, follows: index_2, multiplier: -1.0}\n")
    assert main(["hand", "check", str(tmp_path / "hand.yaml")]) == 1
    out = capsys.readouterr().out.splitlines()
    assert any(l.startswith("error: joint index_2: range [0, 0]: index_3 = -1 index_2 + 0") for l in out), out
    assert out[-1].endswith("1 error(s), 0 warning(s)")


def test_a_coupling_that_narrows_its_driver_is_still_ok(tmp_path, capsys):
    text = (ROBOTS_DIR / "icub_right" / "hand.yaml").read_text().replace(
        "urdf: icub_right.urdf", f"urdf: {ROBOTS_DIR / 'icub_right' / 'icub_right.urdf'}")
    (tmp_path / "hand.yaml").write_text(text + "couplings:\n  - {joint: index_3, follows: index_2, multiplier: 2.0}\n")
    assert main(["hand", "check", str(tmp_path / "hand.yaml")]) == 0
    assert "ok: joint index_2: range [0, 0.7854]" in capsys.readouterr().out
