"""Package-level checks: public API, command line wiring, and the bundled data an install ships."""

import subprocess
import sys
from pathlib import Path

import pytest

import planner


def test_all_names_exist_and_sorted():
    """Every name in planner.__all__ exists and the list is sorted."""
    assert list(planner.__all__) == sorted(planner.__all__)
    for name in planner.__all__:
        assert hasattr(planner, name), name


def test_version_is_the_installed_distributions():
    """`regrasp --version` and planner.__version__ give the installed version (exit 0)."""
    from importlib.metadata import version

    out = subprocess.run([sys.executable, "-m", "planner", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"regrasp {version('regrasp-planner')}"
    assert planner.__version__ == version("regrasp-planner")


def test_python_dash_m_runs():
    """`python -m planner --help` exits 0 and names the subcommands."""
    out = subprocess.run([sys.executable, "-m", "planner", "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    assert "demo" in out.stdout


def test_core_maths_imports_without_heavy_back_ends():
    """planner.closure, planner.graph, planner.gait_search and planner.explain import without pinocchio, coal, OMPL or pybullet."""
    code = (
        "import sys, planner.closure, planner.graph, planner.gait_search, planner.explain, planner.plan\n"
        "heavy = [m for m in ('pinocchio', 'coal', 'ompl', 'pybullet') if m in sys.modules]\n"
        "print(','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_only_motion_imports_ompl_and_only_sim_imports_pybullet():
    """OMPL is imported only by planner/motion.py, pybullet only under planner/sim/."""
    from pathlib import Path

    root = Path(planner.__file__).parent
    for path in root.rglob("*.py"):
        text = path.read_text()
        rel = path.relative_to(root).as_posix()
        if "import ompl" in text or "from ompl" in text:
            assert rel == "motion.py", rel
        if "import pybullet" in text:
            assert rel.startswith("sim/"), rel


# ------------------------------------------------------------------ installs (issue 16)
REPO = Path(__file__).resolve().parents[1]


def _run(code: str, cwd) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_bundled_hands_and_grasps_resolve_from_any_directory(tmp_path):
    """From a directory outside the repository, a hand name loads the bundled hand (even
    with a folder of that name here), an unknown name lists the bundled hands, and a grasp
    file copied here finds its hand by name."""
    (tmp_path / "icub_right").mkdir()  # a decoy: a bare name is the bundled hand
    (tmp_path / "box.yaml").write_text((REPO / "grasps/icub/box_ir2m.yaml").read_text())
    code = (
        "from planner import resources as r\n"
        "from planner.errors import UnknownNameError\n"
        "from planner.hand import Hand\n"
        "from planner.grasp import load_grasp\n"
        "h = Hand.load('icub_right')\n"
        "print(h.spec_path.resolve() == (r.robots_dir() / 'icub_right' / 'hand.yaml').resolve())\n"
        "print(Hand.load(r.hand_dir('icub_right')).name)\n"
        "try:\n    Hand.load('no_such_hand')\nexcept UnknownNameError as e:\n    print(e)\n"
        "print(load_grasp('box.yaml').hand_ref)\n"
        "print(r.robots_dir(), r.grasps_dir(), sep='\\n')\n"
    )
    lines = _run(code, tmp_path).splitlines()
    assert lines[:4] == ["True", "icub_right", "unknown hand 'no_such_hand'; hands are allegro_right, icub_right",
                         "icub_right"]
    assert lines[4:] == [str(REPO / "robots"), str(REPO / "grasps")]  # this checkout (editable install)


def test_bundled_grasp_names():
    """Bundled grasps are named by their path under grasps/; the name of a bundled file
    round-trips; unknown names and escapes out of grasps/ are refused with the valid names."""
    from planner import resources as r
    from planner.errors import UnknownNameError

    names = r.bundled_grasps()
    assert "icub/box_ir2m.yaml" in names and "allegro/box_tripod.yaml" in names
    assert len(names) == len(list((REPO / "grasps").rglob("*.yaml")))
    path = r.bundled_grasp("icub/box_ir2m.yaml")
    assert path.read_bytes() == (REPO / "grasps/icub/box_ir2m.yaml").read_bytes()
    assert r.bundled_grasp_name(path) == "icub/box_ir2m.yaml"
    assert r.bundled_grasp_name(REPO / "pyproject.toml") is None
    for bad in ("icub/nope.yaml", "../pyproject.toml", "icub"):
        with pytest.raises(UnknownNameError, match="icub/box_ir2m.yaml"):
            r.bundled_grasp(bad)
    assert r.bundled_hands() == sorted(d.parent.name for d in (REPO / "robots").glob("*/hand.yaml"))


def test_source_checkout_without_install_finds_the_top_level_folders(tmp_path):
    """Without the install's package-dir mapping (a checkout on PYTHONPATH) the resources
    are the repository's robots/ and grasps/."""
    code = (
        "import sys\n"
        f"sys.path.insert(0, {str(REPO)!r})\n"
        "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f).lower()]\n"
        "from planner import resources as r\n"
        "print(r.robots_dir(), r.grasps_dir(), r.bundled_hands(), sep='\\n')\n"
    )
    assert _run(code, tmp_path).splitlines() == [str(REPO / "robots"), str(REPO / "grasps"),
                                                 "['allegro_right', 'icub_right']"]


def test_wheel_ships_every_bundled_file_and_package():
    """pyproject.toml's package-data globs (expanded the way setuptools does) cover every data
    file under robots/ and grasps/, and `packages` lists every package under planner/ (the
    wheel itself is built, installed and run by .ci/wheel_check)."""
    import glob
    import os

    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert cfg["package-dir"] == {"planner.robots": "robots", "planner.grasps": "grasps"}
    for package, folder in cfg["package-dir"].items():
        root = REPO / folder
        shipped = {os.path.relpath(f, root) for pattern in cfg["package-data"][package]
                   for f in glob.glob(os.path.join(root, pattern), recursive=True) if os.path.isfile(f)}
        data = {str(p.relative_to(root)) for p in root.rglob("*")
                if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts}
        assert data and data <= shipped, sorted(data - shipped)
        assert (root / "__init__.py").is_file()  # a regular package: the editable finder maps it
    code_packages = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "planner").rglob("__init__.py")}
    assert set(cfg["packages"]) == code_packages | set(cfg["package-dir"])
    listed = {str(REPO / "planner" / f) for f in cfg["package-data"].get("planner", [])}
    code_data = [str(p) for p in (REPO / "planner").rglob("*")
                 if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts]
    assert set(code_data) == listed == {str(REPO / "planner/py.typed")}, \
        "data under planner/ ships only if [tool.setuptools.package-data] lists it (the py.typed marker)"
    assert tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["license"] == "BSD-3-Clause"


def test_demo_out_names_a_directory(tmp_path):
    """`regrasp demo` writes into ./regrasp-demo/ by default; an --out that is a file is refused
    (exit 2, one line) and left as it was."""
    from planner.cli import build_parser, main

    assert build_parser().parse_args(["demo"]).out == "regrasp-demo"
    f = tmp_path / "taken"
    f.write_text("mine")
    assert main(["demo", "--out", str(f)]) == 2
    assert f.read_text() == "mine"


# ------------------------------------------------------------------ plans name their files portably


def _no_machine_paths(text: str, *roots) -> None:
    for root in (REPO, *roots):
        assert str(root) not in text
    assert "\ninputs:\n" in text and "path: /" not in text and "spec: /" not in text


def test_plan_of_bundled_grasps_names_them_and_replays_from_anywhere(tmp_path, monkeypatch, capsys):
    """Bundled grasps are recorded by name (``bundled:``) and the bundled hand by its name: the
    same bytes whatever folder the plan is written to, and the plan copied alone elsewhere
    reads strictly (inputs found, sha256 equal) and replays, its bytes unchanged."""
    import warnings

    from planner.cli import main
    from planner.plan import read_plan
    from planner.plan_data import plan_hand_ref
    from planner.resources import bundled_grasp

    a, b = (bundled_grasp(n) for n in ("icub/cylinder_parallel_extension.yaml", "icub/cylinder_ir2m.yaml"))
    monkeypatch.chdir(tmp_path)
    for out in ("one/p.yaml", "two/deeper/p.yaml"):  # verified in pybullet palm down before it is written
        (tmp_path / out).parent.mkdir(parents=True)
        assert main(["plan", str(a), str(b), "--execution", "--gravity-set", "1", "-o", out]) == 0
    text = (tmp_path / "one/p.yaml").read_text()
    assert (tmp_path / "two/deeper/p.yaml").read_text() == text
    assert "initial: {bundled: icub/cylinder_parallel_extension.yaml, sha256: " in text
    assert "final: {bundled: icub/cylinder_ir2m.yaml, sha256: " in text
    assert "hand:\n  name: icub_right\n  spec: icub_right\n  files: {hand.yaml: " in text
    _no_machine_paths(text, tmp_path)
    far = tmp_path / "far" / "away"
    far.mkdir(parents=True)
    (far / "p.yaml").write_bytes((tmp_path / "one/p.yaml").read_bytes())
    monkeypatch.chdir(far.parent)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plan = read_plan("away/p.yaml", strict=True)
    assert plan_hand_ref(plan.hand, plan.source) == "icub_right"
    assert main(["replay", "away/p.yaml"]) == 0
    assert capsys.readouterr().out.rstrip().splitlines()[-1].startswith("PASS")
    assert (far / "p.yaml").read_text() == text


def test_plan_records_other_files_relative_to_itself(tmp_path):
    """A grasp outside the bundle and a hand.yaml outside the bundle are recorded relative to
    the plan file (a folder moved whole replays the same bytes); a hand.yaml given by the path
    of a bundled hand is recorded by the hand's name."""
    import shutil

    from planner.grasp import load_grasp
    from planner.plan import read_plan
    from planner.plan_data import plan_hand_ref, write_plan
    from planner.grasp import input_record
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.resources import bundled_grasp, hand_dir

    shutil.copytree(hand_dir("icub_right"), tmp_path / "hands" / "mine")
    grasps = []
    for name in ("cylinder_parallel_extension", "cylinder_ir2m"):
        text = bundled_grasp(f"icub/{name}.yaml").read_text()
        assert "hand: icub_right\n" in text
        path = tmp_path / "g" / f"{name}.yaml"
        path.parent.mkdir(exist_ok=True)
        path.write_text(text.replace("hand: icub_right\n", "hand: ../hands/mine/hand.yaml\n"))
        grasps.append(path)
    specs = [load_grasp(p) for p in grasps]
    inputs = {k: input_record(p) for k, p in zip(("initial", "final"), grasps)}
    result = plan_regrasp(*(realize(s) for s in specs), PlanOptions(motion=False), inputs)
    out = write_plan(result.plan, tmp_path / "out" / "p.yaml")
    text = out.read_text()
    assert "initial: {path: ../g/cylinder_parallel_extension.yaml, sha256: " in text
    assert "  spec: ../hands/mine/hand.yaml\n" in text
    _no_machine_paths(text, tmp_path)
    moved = tmp_path.parent / (tmp_path.name + "-moved")
    shutil.copytree(tmp_path, moved)
    try:
        plan = read_plan(moved / "out" / "p.yaml", strict=True)
        assert plan_hand_ref(plan.hand, plan.source) == str(moved / "hands" / "mine" / "hand.yaml")
        assert (moved / "out" / "p.yaml").read_text() == text
    finally:
        shutil.rmtree(moved)
    bundled = type(result.plan)(**{**result.plan.__dict__, "hand": {"name": "icub_right",
                                                                    "spec": str(hand_dir("icub_right") / "hand.yaml")}})
    assert "hand: {name: icub_right, spec: icub_right}" in write_plan(bundled, tmp_path / "b.yaml").read_text()


def test_data_is_found_only_through_planner_resources():
    """No module but planner/resources.py locates data from its own file (a repo-root fallback
    works in a checkout and breaks in a wheel); a plan's relative file is looked up next to
    the plan only, never in the repository."""
    from planner.plan_data import plan_file, plan_hand_ref

    root = Path(planner.__file__).parent
    users = sorted(p.relative_to(root).as_posix() for p in root.rglob("*.py")
                   if "Path(__file__)" in p.read_text() and p.name != "resources.py")
    assert users == []
    plan_path = REPO.parent / "no-such-dir" / "p.yaml"
    assert plan_file("robots/icub_right/hand.yaml", plan_path) is None
    assert plan_file("robots/icub_right/hand.yaml", REPO / "p.yaml") == REPO / "robots/icub_right/hand.yaml"
    assert plan_hand_ref({"name": "icub_right", "spec": "robots/icub_right/hand.yaml"}, plan_path) == "icub_right"


def test_no_submodule_shadows_a_public_name():
    """Importing a submodule binds it as an attribute of the package: a module named like a
    name of ``planner.__all__`` replaces that function once anything imports it (the API's
    ``planner.synth`` became the module after its first call). Only ``planner.plan`` is both,
    on purpose: the module is callable."""
    import pkgutil

    import planner

    modules = {m.name for m in pkgutil.iter_modules(planner.__path__)}
    assert set(planner.__all__) & modules == {"plan"}
    import planner.gait_search  # noqa: F401 - the imports that used to rebind the names
    import planner.synthesis  # noqa: F401

    assert callable(planner.synth) and not isinstance(planner.synth, type(planner))
    assert callable(planner.search) and not isinstance(planner.search, type(planner))
    assert callable(planner.plan) and hasattr(planner.plan, "read_plan")
