"""The documentation says what the code does.

- docs/EXAMPLE.md runs as written: its python blocks, in order, in one namespace.
- README.md is short (at most 3 500 words), keeps the two set-up commands CI runs, and its
  command examples run (the quick ones) or parse (the ones that simulate; other tests run them).
- Every relative link of README.md and docs/*.md resolves; README links every docs/*.md file.
- Every option the README or the synopsis of docs/USAGE.md names is an option of its command.
- The module table of docs/ARCHITECTURE.md names every module of the package, and only those.
"""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
MAX_README_WORDS = 3500


def test_the_python_example_runs(tmp_path, monkeypatch, capsys):
    text = (ROOT / "docs/EXAMPLE.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) >= 5
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for code in blocks:
        exec(compile(code, "docs/EXAMPLE.md", "exec"), namespace)  # noqa: S102 - our own documentation
    out = capsys.readouterr().out
    assert "gait steps" in out and "plan verified" in out and "PASS" in out and "palm_down" in out


# ------------------------------------------------------------------ README: short, links resolve


def test_readme_is_at_most_3500_words():
    """`wc -w README.md` <= 3 500: the rest belongs in docs/."""
    words = len(README.read_text().split())
    assert words <= MAX_README_WORDS, f"README.md has {words} words (at most {MAX_README_WORDS}); move detail to docs/"


def _links(path: Path) -> list[str]:
    """Targets of the markdown links and images of a file, without URLs and in-page anchors."""
    text = path.read_text()
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # code blocks hold no links
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    return [t for t in targets if not re.match(r"[a-z]+:", t) and not t.startswith("#")]


@pytest.mark.parametrize("path", [README, *DOCS], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves(path):
    """A link or image of README.md or docs/*.md names a file that exists (relative to the linking file)."""
    missing = [t for t in _links(path) if not (path.parent / t.split("#")[0]).exists()]
    assert not missing, f"{path.relative_to(ROOT)}: links to missing files: {missing}"


def test_readme_links_every_docs_file():
    """Each docs/*.md is reachable from the README ("where the rest is")."""
    linked = {(README.parent / t.split("#")[0]).resolve() for t in _links(README)}
    assert {p for p in DOCS if p.resolve() not in linked} == set()
    assert any(t.startswith("docs/") for t in _links(README))


# ------------------------------------------------------------------ README: the two set-up commands


def test_readme_setup_commands_are_make_demo_and_make_test_and_ci_runs_the_test_one():
    """The set-up block of the README is `make demo` and `make test`, both Makefile targets, and
    .ci/run runs the README's test command."""
    text = README.read_text()
    section = text.split("## Set up and run", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, flags=re.S).group(1)
    commands = [line.split("#", 1)[0].strip() for line in block.splitlines() if line.strip()]
    assert commands == ["make demo", "make test"]
    makefile = (ROOT / "Makefile").read_text()
    for target in ("demo", "test"):
        assert re.search(rf"^{target}:", makefile, flags=re.M), target
    ci = [line.strip() for line in (ROOT / ".ci/run").read_text().splitlines()]
    assert "make test" in ci


# ------------------------------------------------------------------ README: the examples


def _readme_commands() -> list[str]:
    """The `regrasp ...` command lines of the README: its bash blocks, and the one-line examples
    of "Other commands" (`- \\`regrasp ...\\``, possibly after a `mkdir DIR && `)."""
    text = README.read_text()
    commands = [line for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S)
                for line in block.splitlines() if line.startswith("regrasp ")]
    commands += re.findall(r"^- `((?:mkdir \S+ && )?regrasp [^`]*)`", text, flags=re.M)
    return commands


def _argv(command: str) -> tuple[list[str], list[str]]:
    """(directories the command makes first, the argv after `regrasp`)."""
    mkdirs = []
    while command.startswith("mkdir "):
        made, command = command.split(" && ", 1)
        mkdirs += shlex.split(made)[1:]
    words = shlex.split(command)
    assert words[0] == "regrasp", command
    return mkdirs, words[1:]


def _subparsers(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    """Every (sub)command of the parser by its words ("", "plan", "hand init", ...)."""
    found = {prefix: parser}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_subparsers(sub, f"{prefix} {name}".strip()))
    return found


def _command_words(argv: list[str], commands: dict) -> str:
    words = ""
    for word in argv:
        if f"{words} {word}".strip() not in commands:
            break
        words = f"{words} {word}".strip()
    return words


def test_readme_examples_parse_and_name_bundled_files():
    """Every README example is a valid command line (the CLI's own parser), covers the five
    main commands and the others, and every bundled file it names exists."""
    from planner.cli import build_parser

    commands = _readme_commands()
    subcommands = _subparsers(build_parser())
    named = set()
    for command in commands:
        _, argv = _argv(command)
        if argv == ["--version"]:
            named.add("--version")
            continue
        build_parser().parse_args(argv)  # exits 2 on an unknown option or a missing argument
        named.add(_command_words(argv, subcommands))
        for word in argv:
            if word.startswith(("grasps/", "robots/")):
                assert (ROOT / word).exists(), f"{command}: {word} does not exist"
    assert {"check", "plan", "verify", "replay", "view", "synth", "hand init", "hand check", "demo",
            "--version"} <= named
    main_section = README.read_text().split("## The five main commands", 1)[1].split("\n## ", 1)[0]
    assert len(re.findall(r"^### `", main_section, flags=re.M)) == 5


#: README examples quick enough to run here (about a second each); plan, verify, replay, view
#: and demo simulate or plan for seconds, and tests/test_package.py and test_sim.py run them.
QUICK = ("check", "synth", "hand init", "hand check", "--version")


def test_quick_readme_examples_run_as_written(tmp_path, monkeypatch, capsys):
    """The quick README examples, run in order from a folder laid out like the repository root
    (grasps/ and robots/), exit 0."""
    from planner.cli import build_parser, main

    for name in ("grasps", "robots"):
        (tmp_path / name).symlink_to(ROOT / name, target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    subcommands = _subparsers(build_parser())
    ran = set()
    for command in _readme_commands():
        mkdirs, argv = _argv(command)
        words = "--version" if argv == ["--version"] else _command_words(argv, subcommands)
        if words not in QUICK:
            continue
        for folder in mkdirs:
            Path(folder).mkdir()
        if argv == ["--version"]:
            with pytest.raises(SystemExit) as done:
                main(argv)
            code = done.value.code
        else:
            code = main(argv)
        out = capsys.readouterr()
        assert code == 0, f"{command}: exit {code}\n{out.out[-2000:]}\n{out.err[-2000:]}"
        ran.add(words)
    assert ran == set(QUICK)


# ------------------------------------------------------------------ options named in the docs


def _options_of(parser: argparse.ArgumentParser) -> set[str]:
    return {s for action in parser._actions for s in action.option_strings}


def test_every_option_the_readme_names_exists():
    """Each `--option` of the README is an option of some command."""
    from planner.cli import build_parser

    known = set().union(*(_options_of(p) for p in _subparsers(build_parser()).values()))
    named = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*", README.read_text()))
    assert named and named - known == set()


def test_usage_synopsis_options_belong_to_their_command():
    """In the synopsis of docs/USAGE.md ("## Command line"), every option on a command's lines
    is an option of that command."""
    from planner.cli import build_parser

    subcommands = _subparsers(build_parser())
    text = (ROOT / "docs/USAGE.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text.split("## Command line", 1)[1], flags=re.S).group(1)
    entries: list[str] = []
    for line in block.splitlines():
        if line.startswith("regrasp "):
            entries.append(line)
        elif line.startswith(" ") and entries:
            entries[-1] += " " + line
    assert len(entries) >= 9
    seen = set()
    for entry in entries:
        argv = entry.split("#", 1)[0].split()[1:]
        words = _command_words(argv, subcommands)
        seen.add(words)
        options = set(re.findall(r"(?<![\w-])--?[a-z][a-z-]*", " ".join(argv)))
        unknown = options - _options_of(subcommands[words])
        assert not unknown, f"regrasp {words}: {sorted(unknown)} are not its options"
    assert {"check", "plan", "replay", "verify", "view", "synth", "hand init", "hand check", "demo"} <= seen


# ------------------------------------------------------------------ the module table


def test_architecture_table_lists_every_module():
    """The module table of docs/ARCHITECTURE.md names every module of planner/ and planner/sim/,
    and every module it names exists."""
    text = (ROOT / "docs/ARCHITECTURE.md").read_text()
    table = "\n".join(line for line in text.splitlines() if line.startswith("| "))
    modules = sorted((ROOT / "planner").glob("*.py"))
    missing = [p.name for p in modules if f"`planner/{p.name}`" not in table]
    assert "`planner/sim/`" in table
    sim = [p.name for p in sorted((ROOT / "planner/sim").glob("*.py")) if p.name != "__init__.py"]
    missing += [f"sim/{name}" for name in sim if f"`{name}`" not in table]
    assert not missing, f"docs/ARCHITECTURE.md: modules missing from the table: {missing}"
    for named in re.findall(r"`planner/([\w/]+\.py)`", table):
        assert (ROOT / "planner" / named).exists(), named
    for named in re.findall(r"\(`(\w+\.py)`\)", table):
        assert (ROOT / "planner/sim" / named).exists(), named


def test_every_option_a_message_names_exists(capsys):
    """A refusal or hint that tells the user to pass ``--option`` names an option of the command
    line (the execution refusal named --verify-attempts before plan had it); an out-of-range
    value of it is one line with the valid range and exit 2."""
    import re

    from planner.cli import build_parser, main

    known = {s for p in _subparsers(build_parser()).values() for s in _options_of(p)}
    named = set()
    for path in sorted((ROOT / "planner").rglob("*.py")):
        for text in re.findall(r'"[^"\n]*"', path.read_text()):
            named.update(re.findall(r"\((--[a-z][a-z-]+)[ ;)]", text))
    assert named and named <= known, sorted(named - known)
    box = ROOT / "grasps/icub"
    code = main(["plan", str(box / "box_parallel_extension.yaml"), str(box / "box_ir2m.yaml"), "--execution",
                 "--verify-attempts", "0"])
    err = capsys.readouterr().err
    assert code == 2 and "--verify-attempts: 0 is out of range; valid: [1, 100]" in err and len(err.strip().splitlines()) == 1


def test_the_exit_code_table_has_every_signal_a_command_unwinds_for():
    """README's exit codes and USAGE's hardening paragraph name the code of each signal a command
    unwinds for (SIGHUP's 129 came with session 56 and was in neither)."""
    from planner.cli import EXIT_INTERRUPTED, HungUp, Terminated

    usage = (ROOT / "docs/USAGE.md").read_text()
    for code in (EXIT_INTERRUPTED, 128 + Terminated.signum, 128 + HungUp.signum):
        assert f"\n| {code} |" in README.read_text(), code
        assert f"{code}: " in usage, code


def test_usage_says_check_execution_replays_the_grasp():
    """docs/USAGE.md's `check` paragraph said `--execution` decides by the static test alone and
    listed `--json`'s `execution` without the replay (`simulator`) session 56 added."""
    text = " ".join((ROOT / "docs/USAGE.md").read_text().split())
    para = text[text.index("- `check` realizes one grasp"):text.index("- `plan` searches")]
    assert "physics engine" in para and "`--no-verify`" in para and "`simulator`" in para
