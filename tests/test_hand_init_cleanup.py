"""`hand init --root LINK` writes the sub-tree's URDF beside the hand.yaml before it infers
the hand from it: when it then refuses the sub-tree (exit 2), no hand.urdf is left behind,
and one that was there before is left as it was."""

from planner.cli import main
from planner.hand import ROBOTS_DIR

URDF = ROBOTS_DIR / "icub_right" / "icub_right.urdf"


def test_a_refused_root_leaves_no_urdf_behind(tmp_path, capsys):
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(URDF), "-o", str(out), "--root", "index_distal"]) == 2
    assert "not a hand" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_refused_root_leaves_an_existing_urdf_as_it_was(tmp_path):
    out, cut = tmp_path / "hand.yaml", tmp_path / "hand.urdf"
    cut.write_text("<robot name='mine'/>\n")
    assert main(["hand", "init", str(URDF), "-o", str(out), "--root", "index_distal"]) == 2
    assert cut.read_text() == "<robot name='mine'/>\n" and not out.exists()


def test_an_accepted_root_still_writes_both(tmp_path):
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(URDF), "-o", str(out), "--root", "index_base"]) == 0
    assert out.is_file() and (tmp_path / "hand.urdf").is_file()


def test_an_empty_root_is_an_unknown_link(tmp_path, capsys):
    """`--root ''` (an empty shell variable) is refused as an unknown link, listing the links,
    exit 2 and nothing written: it was a ValueError traceback ('root needs cut_path')."""
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(URDF), "-o", str(out), "--root", ""]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "root: unknown link ''; links are index_base" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_empty_package_dir_is_refused(tmp_path, capsys):
    """`--package-dir ''` (an empty shell variable): one line, exit 2, nothing written; it was
    taken for the current folder and recorded in the hand.yaml's package_dirs."""
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(URDF), "-o", str(out), "--package-dir", ""]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--package-dir: an empty name" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_mesh_of_the_urdf_is_not_an_output(tmp_path, capsys):
    """`hand init -o` naming one of the URDF's own meshes: refused as an input (one line, exit
    2), the mesh untouched; the hand.yaml was written over it."""
    text = URDF.read_text()
    box = '<geometry><box size="0.079 0.067 0.03"/></geometry>'
    assert box in text
    (tmp_path / "hand.urdf").write_text(text.replace(box, '<geometry><mesh filename="palm.obj"/></geometry>', 1))
    mesh = tmp_path / "palm.obj"
    corners = [(x, y, z) for x in (-0.04, 0.04) for y in (-0.03, 0.03) for z in (-0.015, 0.015)]
    faces = [(1, 3, 4), (1, 4, 2), (5, 6, 8), (5, 8, 7), (1, 2, 6), (1, 6, 5), (3, 7, 8), (3, 8, 4), (1, 5, 7),
             (1, 7, 3), (2, 4, 8), (2, 8, 6)]
    mesh.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(f"f {a} {b} {c}\n" for a, b, c in faces))
    before = mesh.read_bytes()
    assert main(["hand", "init", str(tmp_path / "hand.urdf"), "-o", str(mesh)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refusing to overwrite an input file" in err[0] and "palm.obj" in err[0], err
    assert mesh.read_bytes() == before
