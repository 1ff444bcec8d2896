"""synth's rejection tables: a rejection may name a finger that does not grasp (a grasping
finger colliding with a free one); the per-finger table counts only the grasping fingers."""

from __future__ import annotations

from planner.cli import main


def test_a_rejection_naming_a_free_finger_is_counted_without_it(tmp_path, capsys):
    # Allegro thumb-index pinches of a 4 mm rod, seed 1: among the first attempts some are
    # rejected for a collision with the (free) middle finger; synth crashed (KeyError) there.
    rod = tmp_path / "rod.yaml"
    rod.write_text("shape: cylinder\nsize: [0.004, 0.15]\nmass_kg: 0.01\n")
    out = tmp_path / "out"
    code = main(["synth", "allegro_right", str(rod), "--fingers", "thumb,index", "-n", "3", "-o", str(out),
                 "--seed", "1", "--max-attempts", "400"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "3/3 grasps" in text and len(list(out.glob("*.yaml"))) == 3
    table = text[text.index("finger  dropped"):] if "finger  dropped" in text else ""
    assert "middle" not in table


def test_no_grasp_found_writes_nothing_and_makes_no_folder(tmp_path):
    """synth that finds no grasp leaves nothing behind: not even the -o folder it was given."""
    from types import SimpleNamespace

    from planner.synthesis import write_grasps

    out = tmp_path / "new" / "grasps"
    assert write_grasps(SimpleNamespace(grasps=[]), out, "icub_right", seed=0, fingers=["thumb", "index"]) == []
    assert not out.exists() and not out.parent.exists()
