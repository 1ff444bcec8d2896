"""A number YAML reads as text says how to write it: PyYAML (YAML 1.1) reads 1e-9 (no dot)
as the string '1e-9', and the message said only "got str '1e-9'"; a quoted number likewise."""

import pytest
import yaml

from planner.cli import main
from planner.resources import bundled_grasp


@pytest.mark.parametrize("old, new, words", [
    ("mu: 0.9", "mu: 1e-9", "got str '1e-9' (YAML reads 1e-9 as text: write 1.0e-9)"),
    ("mu: 0.9", "mu: 4e2", "write 4.0e+2"),
    ("mass_kg: 0.04", "mass_kg: '0.04'", "(a number in quotes is text: write it without quotes)"),
])
def test_a_number_read_as_text_says_how_to_write_it(tmp_path, capsys, old, new, words):
    text = bundled_grasp("icub/box_ir2m.yaml").read_text()
    assert old in text
    path = tmp_path / "g.yaml"
    path.write_text(text.replace(old, new, 1))
    assert main(["check", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


@pytest.mark.parametrize("written", ["1.0e-9", "4.0e+2", "-2.0e+1"])
def test_the_suggested_spelling_is_a_yaml_number(written):
    assert isinstance(yaml.safe_load(f"a: {written}")["a"], float)


def test_text_that_is_no_number_gets_no_hint(tmp_path, capsys):
    text = bundled_grasp("icub/box_ir2m.yaml").read_text().replace("mass_kg: 0.04", "mass_kg: abc", 1)
    (tmp_path / "g.yaml").write_text(text)
    assert main(["check", str(tmp_path / "g.yaml"), "-q"]) == 2
    assert capsys.readouterr().err.strip().endswith("got str 'abc'")
