"""Hand files (issue 35, item 4): a hand.yaml's URDF and meshes, and the URDF of ``regrasp
hand init``, are checked by `planner.urdf_check` before pinocchio, coal or pybullet see
them. Each class of bad input ends with exit 2 and one stderr line naming the file the
user gave, the line and the element; no traceback, no C++ source path, no hang."""

from __future__ import annotations

import glob
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.cli import main
from planner.errors import SpecError
from planner.urdf_check import MAX_MESH_TRIANGLES, MAX_NAME_CHARS, check_urdf

ROOT = Path(__file__).resolve().parent.parent
ICUB = ROOT / "robots/icub_right"
URDF_TEXT = (ICUB / "icub_right.urdf").read_text()
BOX_IR2M = ROOT / "grasps/icub/box_ir2m.yaml"


def _run(capsys, *argv) -> tuple[int, list[str]]:
    """main(argv) in-process: (exit code, stderr lines)."""
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip().splitlines()


def _one_line(code, err, *names):
    """Exit 2, one stderr line holding every one of ``names``, no C++ source, no traceback."""
    assert code == 2 and len(err) == 1, (code, err)
    line = err[0]
    for name in names:
        assert str(name) in line, (name, line)
    assert ".cpp" not in line and "/project/" not in line and "Traceback" not in line, line
    return line


def _hand(tmp_path, urdf_text: str, folder: str = "h") -> Path:
    """A copy of the bundled iCub's hand.yaml beside ``urdf_text``; returns the folder."""
    d = tmp_path / folder
    d.mkdir()
    shutil.copy(ICUB / "hand.yaml", d / "hand.yaml")
    (d / "icub_right.urdf").write_text(urdf_text)
    return d


def _edit(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text, old
    return text.replace(old, new, count)


def _both(tmp_path, capsys, urdf_text: str, *names):
    """`hand init` of the URDF and `hand check` of a hand.yaml naming it: both exit 2 with
    one line naming the file given (and ``names``); returns the two lines."""
    urdf = tmp_path / "bad.urdf"
    urdf.write_text(urdf_text)
    init = _one_line(*_run(capsys, "hand", "init", urdf, "-o", tmp_path / "out.yaml"), "bad.urdf", *names)
    assert init.startswith(f"regrasp hand: error: {urdf}: line "), init  # the URDF, not a hand.yaml beside it
    assert not (tmp_path / "out.yaml").exists()
    d = _hand(tmp_path, urdf_text)
    check = _one_line(*_run(capsys, "hand", "check", d / "hand.yaml"), d / "hand.yaml", d / "icub_right.urdf", *names)
    return init, check


# ------------------------------------------------------------------ files that are not files


def _subprocess(argv, cwd):
    """The CLI in a child process (a hang would hang the test runner): (exit code, stderr lines)."""
    proc = subprocess.run([sys.executable, "-m", "planner", *map(str, argv)], cwd=cwd, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    return proc.returncode, proc.stderr.strip().splitlines()


@pytest.mark.parametrize("kind, expect", [("fifo", "not a regular file"), ("device", "not a regular file"),
                                          ("sparse", "at most 5000000 bytes")])
def test_a_urdf_that_is_no_regular_file_or_too_large_is_refused_before_reading(tmp_path, kind, expect):
    """A FIFO (pinocchio waited for a writer forever), /dev/zero (a MemoryError at 2-4 GB)
    and a 1 GiB sparse file (2 GB read before the refusal), as `hand init`'s URDF and as a
    hand.yaml's, and the same as a collision mesh."""
    bad = tmp_path / "bad.urdf"
    if kind == "fifo":
        os.mkfifo(bad)
    elif kind == "device":
        bad.symlink_to("/dev/zero")
    else:
        with open(bad, "wb") as fh:
            fh.truncate(1 << 30)
    code, err = _subprocess(["hand", "init", bad.name, "-o", "out.yaml"], tmp_path)
    _one_line(code, err, "bad.urdf:", expect)
    d = _hand(tmp_path, "")
    (d / "icub_right.urdf").unlink()
    (d / "icub_right.urdf").symlink_to(bad)
    code, err = _subprocess(["hand", "check", "h/hand.yaml"], tmp_path)
    _one_line(code, err, "h/hand.yaml: urdf:", "bad.urdf" if kind != "device" else "/dev/zero", expect)
    # the same file as a collision mesh: refused before pinocchio (assimp) opens it
    mesh = _edit(URDF_TEXT, '<geometry><box size="0.079 0.067 0.03"/></geometry>',
                 f'<geometry><mesh filename="{bad}"/></geometry>')
    (d / "icub_right.urdf").unlink()
    (d / "icub_right.urdf").write_text(mesh)
    code, err = _subprocess(["hand", "check", "h/hand.yaml"], tmp_path)
    line = _one_line(code, err, "h/hand.yaml: urdf:", "link 'palm': collision mesh", "bad.urdf")
    assert ("at most 64000000" if kind == "sparse" else "not a regular file") in line


# ------------------------------------------------------------------ numbers


#: Where a URDF holds a size or a physical quantity: (the text, a format for the bad value,
#: the element and what the message says).
QUANTITIES = [
    ('<sphere radius="0.0065"/>', '<sphere radius="{}"/>', "link 'thumb_proximal'", "collision sphere radius"),
    ('<cylinder radius="0.0065" length="0.026"/>', '<cylinder radius="0.0065" length="{}"/>',
     "link 'thumb_proximal'", "collision cylinder length"),
    ('<box size="0.079 0.067 0.03"/>', '<box size="0.079 {} 0.03"/>', "link 'palm'", "collision box size"),
    ('<mass value="0.015"/>', '<mass value="{}"/>', "link 'thumb_proximal'", "mass"),
    ('ixx="3.16875e-07"', 'ixx="{}"', "link 'thumb_proximal'", "inertia ixx"),
    ('<limit lower="0" upper="1.5708" effort="0.5"', '<limit lower="0" upper="{}" effort="0.5"', "joint 'thumb_0'",
     "<limit> upper"),
    ('<axis xyz="0 -1 0"/>', '<axis xyz="0 {} 0"/>', "joint 'thumb_1'", "<axis> xyz"),
    ('<origin xyz="0.0211 0 0" rpy="0 0 0"/>', '<origin xyz="0.0211 0 0" rpy="0 {} 0"/>', "joint 'thumb_1'",
     "<origin> rpy"),
]
#: Values refused wherever a number is read (sizes and masses refuse -1 too).
NOT_NUMBERS = ["nan", "NaN", "inf", "-inf", "1e999", "abc", "1_0", "${r}", "0x10"]


def test_non_finite_and_non_positive_numbers_are_refused_naming_the_element(tmp_path, capsys):
    """Seeded: NaN, infinities, text, Python-only forms (1_0), and for sizes 0 and negative
    values, at a random place of the URDF, through `hand init` and `hand check`."""
    rng = np.random.default_rng(35)
    for k in range(10):
        old, fmt, element, label = QUANTITIES[rng.integers(len(QUANTITIES))]
        sizes = label.startswith("collision") or label == "mass"
        value = str(rng.choice(NOT_NUMBERS + (["0", "-1", "-0.002"] if sizes else [])))
        if label == "mass" and value == "0":
            value = "-3"  # a massless link is valid
        case = tmp_path / str(k)
        case.mkdir()
        init, check = _both(case, capsys, _edit(URDF_TEXT, old, fmt.format(value)), element, label)
        if value in ("abc", "1_0", "${r}", "0x10"):
            assert "not one" in init and value not in init  # the file's text is not quoted
        elif value in ("nan", "NaN", "inf", "-inf", "1e999"):
            assert "finite" in init, init
        else:
            assert (">= 0" if label == "mass" else "> 0") in init, init


@pytest.mark.parametrize("old, new, expect", [
    ('<axis xyz="0 -1 0"/>', '<axis xyz="0 0 0"/>', "joint 'thumb_1': <axis> xyz must be a non-zero direction"),
    ('<axis xyz="0 -1 0"/>', '<axis xyz="0 1e-9 0"/>', "joint 'thumb_1': <axis> xyz must be a non-zero direction"),
    ('<limit lower="0" upper="1.5708" effort="0.5"', '<limit lower="2" upper="1.5708" effort="0.5"',
     "joint 'thumb_0': <limit> lower 2 > upper 1.5708"),
    ('<limit lower="0" upper="1.5708" effort="0.5"', '<limit lower="0" upper="1.5708" effort="-0.5"',
     "joint 'thumb_0': <limit> effort must be >= 0, got -0.5"),
    ('<limit lower="0" upper="1.5708" effort="0.5" velocity="3.0"/>', '', "joint 'thumb_0': a revolute joint needs"),
    ('<geometry><sphere radius="0.0065"/></geometry>', '<geometry><mesh filename="t.stl" scale="1 nan 1"/></geometry>',
     "collision mesh scale must be finite non-zero numbers, got 1 nan 1"),
    ('<geometry><sphere radius="0.0065"/></geometry>', '<geometry><mesh filename="t.stl" scale="1 0 1"/></geometry>',
     "collision mesh scale must be non-zero, got 1 0 1"),
    ('<geometry><sphere radius="0.0065"/></geometry>', '<geometry><mesh filename="nowhere.stl"/></geometry>',
     "collision mesh 'nowhere.stl': file not found"),
    ('<geometry><sphere radius="0.0065"/></geometry>', '<geometry><capsule radius="0.0065"/></geometry>',
     "collision capsule length: missing"),
    ('<geometry><sphere radius="0.0065"/></geometry>', '<geometry><cone radius="1"/></geometry>',
     "holds no box, cylinder, sphere or mesh"),
    ('type="revolute"', 'type="hinge"', "joint 'thumb_0': unknown type"),
    ('<box size="0.079 0.067 0.03"/>', '<box size="1e30 0.067 0.03"/>',
     "link 'palm': collision box size must be at most 100 m, got 1e+30 0.067 0.03"),
    ('<origin xyz="0.0211 0 0"', '<origin xyz="0.0211 -1e300 0"', "joint 'thumb_1': <origin> xyz must be within 100 m"),
    ('<origin xyz="0.0211 0 0"', '<origin xyz="0.0211 0"', "<origin> xyz: expected 3 numbers, got 2 values"),
    ('ixx="6.73625e-05"', 'ixx="-6.73625e-05"', "link 'palm': inertia ixx must be >= 0 (a moment of inertia), got -6.73625e-05"),
])
def test_joint_and_shape_rules_are_one_line(tmp_path, capsys, old, new, expect):
    _both(tmp_path, capsys, _edit(URDF_TEXT, old, new), expect)


# ------------------------------------------------------------------ structure


def _extra_link(text: str, name: str) -> str:
    return _edit(text, '<robot name="icub_right_hand">', f'<robot name="icub_right_hand"><link name="{name}"/>')


STRUCTURE = {
    "two roots": (lambda t: _extra_link(t, "ghost"), "<robot>: 2 root links ('ghost', 'palm')"),
    "two parents": (lambda t: _edit(t, '<child link="thumb_proximal"/>', '<child link="index_proximal"/>'),
                    "link 'index_proximal' has two parents"),
    "own child": (lambda t: _edit(t, '<child link="thumb_base"/>', '<child link="palm"/>'),
                  "joint 'thumb_0': link 'palm' is both its parent and its child"),
    "cycle": (lambda t: _edit(t, '<parent link="palm"/>\n    <child link="thumb_base"/>',
                              '<parent link="thumb_tip"/>\n    <child link="thumb_base"/>'),
              "link 'thumb_base': not connected to the root link 'palm': the joints form a cycle"),
    "unknown link": (lambda t: _edit(t, '<parent link="thumb_base"/>', '<parent link="nobody"/>'),
                     "joint 'thumb_1': its parent link 'nobody' is not a link of the URDF"),
    "duplicate link": (lambda t: _extra_link(t, "thumb_base"), "link 'thumb_base': a second link of that name"),
    "duplicate joint": (lambda t: _edit(t, 'name="thumb_1"', 'name="thumb_0"'),
                        "joint 'thumb_0': a second joint of that name"),
    "long name": (lambda t: _edit(t, '"thumb_base"', '"' + "b" * (MAX_NAME_CHARS + 1) + '"', count=99),
                  f"<link>: its name is {MAX_NAME_CHARS + 1} characters long; at most {MAX_NAME_CHARS}"),
    "megabyte name": (lambda t: _edit(t, 'name="icub_right_hand"', 'name="' + "r" * 1_000_000 + '"'),
                      "<robot> attribute 'name' is 1000000 characters long"),
    "no name": (lambda t: _edit(t, 'name="icub_right_hand"', ''), "<robot>: has no name"),
    "doctype": (lambda t: _edit(t, '<robot', '<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;">]>\n<robot'),
                "a DOCTYPE (entity declarations) is not accepted"),
    "deep": (lambda t: _edit(t, "</robot>", "<g>" * 40 + "</g>" * 40 + "</robot>"), "nested deeper than 32 levels"),
    "not xml": (lambda t: t[: len(t) // 2], "not well-formed XML"),
    "not a robot": (lambda t: "<html><body/></html>", "the top element is <html>, not <robot>"),
    "xacro": (lambda t: _edit(t, "</robot>", '<xacro:include filename="x.xacro"/></robot>'), "a xacro file"),
}


@pytest.mark.parametrize("case", sorted(STRUCTURE))
def test_a_urdf_that_is_not_one_tree_of_named_links_is_refused(tmp_path, capsys, case):
    """One root, a tree (no second parent, no self-parent, no cycle), existing and unique
    names of sane length, no DOCTYPE, plain XML: pinocchio refused some with a message
    naming nothing, dropped the palm and its fingers for others, and pybullet crashed
    (exit 139) on a link with two parents and on a 10 MB name."""
    edit, expect = STRUCTURE[case]
    _both(tmp_path, capsys, edit(URDF_TEXT), expect)


def test_every_command_that_loads_a_hand_says_the_same_line(tmp_path, capsys):
    """check, plan, synth and view load the hand through the same check."""
    d = _hand(tmp_path, STRUCTURE["two parents"][0](URDF_TEXT))
    grasp = re.sub(r"(?m)^hand:.*$", "hand: h/hand.yaml", BOX_IR2M.read_text())
    g = tmp_path / "g.yaml"
    g.write_text(grasp)
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.025]\nmass_kg: 0.05\n")
    lines = set()
    for argv in (["check", g], ["plan", g, g, "--no-motion", "-o", tmp_path / "p.yaml"],
                 ["synth", d / "hand.yaml", ball, "--fingers", "thumb,index", "-n", "1", "-o", tmp_path / "s"],
                 ["view", g, "-o", tmp_path / "v.html"]):
        line = _one_line(*_run(capsys, *argv), "hand.yaml", "link 'index_proximal' has two parents")
        lines.add(line.split(": error: ", 1)[1].split("link 'index_proximal'")[1])
    assert len(lines) == 1
    assert not any(p.name in ("p.yaml", "v.html", "s") for p in tmp_path.iterdir())




# ------------------------------------------------------------------ meshes


def _binary_stl(path: Path, triangles: np.ndarray) -> None:
    rec = np.zeros(len(triangles), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["v"] = triangles
    with open(path, "wb") as fh:
        fh.write(b"\0" * 80 + np.uint32(len(triangles)).tobytes() + rec.tobytes())


def _cone(n: int, r: float = 0.006, h: float = 0.02) -> np.ndarray:
    """A cone of ``n`` base segments: its apex and base centre have ``n`` neighbours."""
    a = 2 * np.pi * np.arange(n) / n
    rim = np.c_[r * np.cos(a), r * np.sin(a), np.zeros(n)]
    nxt = np.roll(rim, -1, axis=0)
    apex, centre = np.tile([0, 0, h], (n, 1)), np.zeros((n, 3))
    return np.concatenate([np.stack([rim, nxt, apex], 1), np.stack([nxt, rim, centre], 1)])


def _mesh_hand(tmp_path, name: str) -> Path:
    """The iCub with the thumb's first sphere replaced by mesh ``name`` (in the hand's folder)."""
    return _hand(tmp_path, _edit(URDF_TEXT, '<geometry><sphere radius="0.0065"/></geometry>',
                                 f'<geometry><mesh filename="{name}"/></geometry>'))


def test_a_collision_mesh_past_the_triangle_limit_is_refused_before_coal(tmp_path, capsys):
    """Seeded: a random triangle soup of 10^6 triangles (50 MB binary STL; coal ended in
    'Too many neighbors'), refused from the STL's header; and a header claiming more
    triangles than the file holds."""
    rng = np.random.default_rng(4)
    d = _mesh_hand(tmp_path, "big.stl")
    _binary_stl(d / "big.stl", rng.normal(scale=0.005, size=(1_000_000, 3, 3)).astype(np.float32))
    _one_line(*_run(capsys, "hand", "check", d / "hand.yaml"), "hand.yaml: urdf:", "link 'thumb_proximal'",
              f"collision mesh 'big.stl' has 1000000 triangles; at most {MAX_MESH_TRIANGLES}", "simplify it")
    with open(d / "big.stl", "r+b") as fh:
        fh.truncate(84 + 50 * 10)
    _one_line(*_run(capsys, "hand", "check", d / "hand.yaml"), "big.stl': binary STL header counts 1000000 "
              "triangles, the file holds 10")


@pytest.mark.parametrize("name, content, expect", [
    ("m.ply", b"ply\nformat ascii 1.0\nelement vertex 999999999\nend_header\n",
     "a .ply file: meshes are STL, OBJ or COLLADA (.dae), the formats pybullet reads"),  # assimp: no answer in 60 s
    ("m.dae", b'<COLLADA><float_array count="900000000000">0 0 0</float_array></COLLADA>',
     "a COLLADA count of 900000000000 items in a file of"),
    ("m.stl", b"\0" * 80 + (4_000_000_000).to_bytes(4, "little"), "binary STL header counts 4000000000 triangles"),
    ("m.stl", b"\0" * 40, "not an STL file"),
])
def test_a_mesh_whose_loader_would_wait_or_allocate_for_its_claims_is_refused(tmp_path, capsys, name, content, expect):
    d = _mesh_hand(tmp_path, name)
    (d / name).write_bytes(content)
    _one_line(*_run(capsys, "hand", "check", d / "hand.yaml"), "hand.yaml: urdf:", "link 'thumb_proximal'",
              f"collision mesh '{name}': {expect}")


def test_a_mesh_coal_cannot_hull_or_a_format_counted_after_loading_is_one_line(tmp_path, capsys, monkeypatch):
    """A cone of 300 segments (a hull vertex with 300 neighbours: coal's 'Too many
    neighbors'), and the count of a loaded mesh (formats the check does not read)."""
    d = _mesh_hand(tmp_path, "cone.stl")
    _binary_stl(d / "cone.stl", _cone(300))
    _one_line(*_run(capsys, "hand", "check", d / "hand.yaml"), "hand.yaml: urdf:", str(d / "icub_right.urdf"),
              "link 'thumb_proximal': collision mesh 'cone.stl': coal cannot take its convex hull", "simplify")
    # `hand init` refuses it in the hand it builds to make its guesses: naming the URDF given,
    # not a hand.yaml beside it that does not exist
    line = _one_line(*_run(capsys, "hand", "init", d / "icub_right.urdf", "-o", tmp_path / "out.yaml"),
                     f"error: {d / 'icub_right.urdf'}: link 'thumb_proximal': collision mesh 'cone.stl': coal cannot")
    assert "hand.yaml" not in line
    _binary_stl(d / "cone.stl", _cone(40))
    monkeypatch.setattr("planner.hand.MAX_MESH_TRIANGLES", 50)
    _one_line(*_run(capsys, "hand", "check", d / "hand.yaml"), "collision mesh 'cone.stl' has 80 triangles; at most 50")


def test_a_mirrored_mesh_and_a_fine_mesh_load(tmp_path):
    """A negative scale (a mirror, as published models use) and a mesh under the limit load."""
    from planner.hand import Hand

    d = _hand(tmp_path, _edit(URDF_TEXT, '<geometry><sphere radius="0.0065"/></geometry>',
                              '<geometry><mesh filename="cone.stl" scale="1 -1 1"/></geometry>'))
    _binary_stl(d / "cone.stl", _cone(40))
    hand = Hand.load(d)
    assert "thumb_proximal" in hand.links


# ------------------------------------------------------------------ what must keep loading


def _published_urdfs() -> list[str]:
    from planner.hand import _share_dirs

    found = sorted(glob.glob(str(ICUB.parent / "*/*.urdf")))
    for share in _share_dirs():
        found += sorted(glob.glob(os.path.join(share, "example-robot-data", "robots", "*", "*", "*.urdf")))
        found += sorted(glob.glob(os.path.join(share, "iCub", "robots", "*", "*.urdf")))
    return found


def test_the_check_passes_every_urdf_pinocchio_reads():
    """Bundled and installed models (example-robot-data's, icub-models' when installed):
    the check refuses none that pinocchio reads (their meshes included)."""
    import pinocchio as pin

    from planner.hand import _share_dirs

    urdfs = _published_urdfs()
    assert len(urdfs) > 10
    refused = []
    for urdf in urdfs:
        try:
            pin.buildModelFromUrdf(urdf)
        except (RuntimeError, ValueError):
            with pytest.raises(SpecError):  # (example-robot-data's ur3.urdf has no robot name)
                check_urdf(urdf, _share_dirs())
            continue
        try:
            check_urdf(urdf, [os.path.dirname(urdf), *_share_dirs()])
        except SpecError as err:
            refused.append(str(err))
    assert not refused, refused
