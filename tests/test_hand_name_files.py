"""A hand.yaml's name names synth's files (DIR/<hand>_<shape>_01.yaml): a name with a path
separator ('../../escaped') wrote the grasps outside -o DIR. Such a name is refused; a hand
without a name takes its folder's, also when the hand.yaml is given as '../hand.yaml'."""

import os

import pytest

from planner.cli import main
from planner.errors import SpecError
from planner.hand import ROBOTS_DIR, Hand

URDF = ROBOTS_DIR / "icub_right" / "icub_right.urdf"


def _hand(folder, name_line):
    folder.mkdir(parents=True, exist_ok=True)
    text = (ROBOTS_DIR / "icub_right" / "hand.yaml").read_text().replace("urdf: icub_right.urdf", f"urdf: {URDF}")
    text = text.replace("name: icub_right\n", name_line)
    (folder / "hand.yaml").write_text(text)
    return folder / "hand.yaml"


@pytest.mark.parametrize("name", ["../../escaped", "sub/hand", "a\\\\b", ".."])
def test_a_name_with_a_path_separator_is_refused(tmp_path, name):
    with pytest.raises(SpecError, match="expected a name without / or") as err:
        Hand.load(_hand(tmp_path / "h", f'name: "{name}"\n'))
    assert err.value.key == "name"


def test_synth_writes_nothing_outside_its_folder(tmp_path, capsys):
    hand = _hand(tmp_path / "h", "name: ../../escaped\n")
    (tmp_path / "ball.yaml").write_text("shape: sphere\nsize: [0.015]\nmass_kg: 0.03\n")
    out = tmp_path / "a" / "b" / "out"
    out.parent.mkdir(parents=True)
    assert main(["synth", str(hand), str(tmp_path / "ball.yaml"), "-n", "1", "-q", "-o", str(out)]) == 2
    assert "name: expected a name without /" in capsys.readouterr().err
    assert not list(tmp_path.rglob("*escaped*"))


def test_the_default_name_is_the_folder_s_from_a_relative_path(tmp_path, monkeypatch):
    _hand(tmp_path / "myhand", "")
    (tmp_path / "myhand" / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "myhand" / "sub")
    assert Hand.load(os.path.join("..", "hand.yaml")).name == "myhand"
