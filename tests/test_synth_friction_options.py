"""synth's --mu and --gamma are held to a grasp file's friction ranges (mu in (0, 100], gamma
in [0, 1] m), before any work: --mu 0 was accepted, ran every attempt and said "no candidate
was rejected: raise --max-attempts" (exit 1); a file written with mu 0 would fail check."""

import pytest

from planner.cli import main


@pytest.mark.parametrize("option, words", [
    (["--mu", "0"], "--mu must be in (0, 100]"),
    (["--mu", "-0.5"], "--mu must be in (0, 100]"),
    (["--mu", "nan"], "got nan"),
    (["--gamma", "-0.001"], "--gamma must be in [0, 1] m"),
    (["--gamma", "inf"], "got inf"),
])
def test_out_of_range_friction_is_bad_input(tmp_path, capsys, option, words):
    obj = tmp_path / "ball.yaml"
    obj.write_text("shape: sphere\nsize: [0.015]\nmass_kg: 0.03\n")
    out = tmp_path / "out"
    code = main(["synth", "icub_right", str(obj), "-n", "1", "--max-attempts", "2", "-q", "-o", str(out), *option])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err
    assert not out.exists()
