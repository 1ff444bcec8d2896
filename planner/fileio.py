"""Files at the boundary: bounded YAML reading, output guards and atomic writes.

Everything a user hands the planner is read through limits stated here (and in the
README's "Hardening / plan integrity" paragraph), so no input makes a command hang, run
out of memory or end in a traceback:

* file size: `MAX_GRASP_BYTES` for grasp and hand YAML, `MAX_PLAN_BYTES` for plans;
* YAML: at most `MAX_YAML_DEPTH` levels of nesting, `MAX_YAML_ALIASES` aliases expanding to
  at most `MAX_YAML_NODES_PER_CHAR` values per character of the file,
  integers of at most `MAX_INT_DIGITS` digits, and no duplicate keys (``mu: -1`` then
  ``mu: 0.9`` is refused, not silently the last one);
* messages name the file, the line and the problem; they never quote the file's content
  (a ``hand:`` path may point at any readable file).

Outputs: `check_output` refuses, before any work, an output path that is (or resolves
to, through a symlink or a hard link) one of the command's inputs, a directory, or lies
under something that is not a writable directory; `write_atomic` writes a temporary file
in the same directory and renames it over the target, so a crash, Ctrl-C or a full disk
leaves the old file or none, never half a file.
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

import yaml

from planner.errors import OutputError, SpecError
from planner.resources import is_hand_path

#: Largest grasp or hand YAML file read, bytes (the bundled ones are under 5 kB).
MAX_GRASP_BYTES = 1_000_000
#: Largest plan file read, bytes (a plan with finger paths is ~0.1-1 MB).
MAX_PLAN_BYTES = 20_000_000
#: Deepest YAML nesting accepted (grasp and plan files need 5).
MAX_YAML_DEPTH = 32
#: Most YAML aliases accepted (the planner writes none; an alias bomb needs many).
MAX_YAML_ALIASES = 100
#: Longest integer literal accepted, digits.
MAX_INT_DIGITS = 30
#: Most values a YAML document may hold once its aliases are expanded, per character of
#: the file (at least `MIN_YAML_EXPANDED_NODES`): an alias bomb stays small as a file and as
#: PyYAML's shared objects, but anything walking it (a check, a digest, a message) expands
#: it. Without aliases a document holds fewer values than it has characters; the planner
#: writes no aliases, and a person reusing a block a few times stays far below.
MAX_YAML_NODES_PER_CHAR = 2
MIN_YAML_EXPANDED_NODES = 10_000


def _where(node_or_mark) -> str:
    mark = getattr(node_or_mark, "start_mark", node_or_mark)
    line = getattr(mark, "line", None)
    return f"line {line + 1}" if line is not None else "somewhere"


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with the limits of this module."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0
        self._max_nodes = max(MIN_YAML_EXPANDED_NODES, MAX_YAML_NODES_PER_CHAR * len(stream)) \
            if isinstance(stream, str) else MIN_YAML_EXPANDED_NODES

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_YAML_ALIASES:
                raise yaml.YAMLError(f"more than {MAX_YAML_ALIASES} YAML aliases ({_where(self.peek_event())})")
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.YAMLError(f"nested deeper than {MAX_YAML_DEPTH} levels ({_where(self.peek_event())})")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def compose_document(self):
        node = super().compose_document()
        if node is not None and self._aliases:  # without aliases the size is the file's
            sizes: dict[int, int] = {}

            def expanded(n) -> int:
                k = id(n)
                if k not in sizes:
                    sizes[k] = 1  # (a node inside itself counts once: recursion is refused later)
                    if isinstance(n, yaml.SequenceNode):
                        sizes[k] = 1 + sum(expanded(c) for c in n.value)
                    elif isinstance(n, yaml.MappingNode):
                        sizes[k] = 1 + sum(expanded(a) + expanded(b) for a, b in n.value)
                    if sizes[k] > self._max_nodes:
                        raise yaml.YAMLError(f"its aliases expand to more than {self._max_nodes} values, "
                                             f"{MAX_YAML_NODES_PER_CHAR} per character of the file ({_where(n)})")
                return sizes[k]

            expanded(node)
        return node

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            if key is not None and key in seen:
                raise yaml.YAMLError(f"duplicate key {_short(key)} ({_where(key_node)})")
            seen.add(key)
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node):
        if len(str(node.value)) > MAX_INT_DIGITS:
            raise yaml.YAMLError(f"integer longer than {MAX_INT_DIGITS} digits ({_where(node)})")
        return super().construct_yaml_int(node)


_BoundedLoader.add_constructor("tag:yaml.org,2002:int", _BoundedLoader.construct_yaml_int)
_BoundedLoader.add_constructor("tag:yaml.org,2002:map", _BoundedLoader.construct_yaml_map)


def _short(text, limit: int = 40) -> str:
    """A name for a message: one line, at most `limit` characters, quoted."""
    text = str(text).replace("\n", "\\n").replace("\r", "\\r")
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")


def read_limited(path: str | os.PathLike, max_bytes: int, what: str) -> str:
    """The text of a file no larger than ``max_bytes``; SpecError (file, no content) otherwise."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise SpecError(str(path), "", f"cannot read {what}: not a regular file")
        if size > max_bytes:
            raise SpecError(str(path), "", f"{what} is {size} bytes; at most {max_bytes} bytes are read")
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
    except OSError as err:
        raise SpecError(str(path), "", f"cannot read {what}: {err.strerror}") from err
    if len(raw) > max_bytes:
        raise SpecError(str(path), "", f"{what} is larger than {max_bytes} bytes")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise SpecError(str(path), "", f"{what} is not UTF-8 text") from None


def load_yaml(text: str, path: str | os.PathLike, what: str):
    """Parse YAML text within this module's limits.

    Raises:
        SpecError: naming the file and the line of the problem, never quoting its content.
    """
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = (err.problem or "syntax error").splitlines()[0]
        raise SpecError(str(path), "", f"{what} is malformed YAML{where}: {problem}") from None
    except yaml.YAMLError as err:
        raise SpecError(str(path), "", f"{what} is malformed YAML: {str(err).splitlines()[0]}") from None
    except RecursionError:
        raise SpecError(str(path), "", f"{what} is nested too deeply") from None


def load_json(text: str, path: str | os.PathLike):
    """Parse JSON text: a `SpecError` naming the file (and the first line of the parser's
    complaint, never the content) for bad syntax, out-of-range numbers or deep nesting."""
    import json

    try:
        return json.loads(text)
    except (ValueError, RecursionError) as err:  # JSONDecodeError is a ValueError
        first = str(err).splitlines()[0] if isinstance(err, json.JSONDecodeError) else "numbers or nesting out of range"
        raise SpecError(str(path), "", f"not valid JSON: {first[:120]}") from None


def read_yaml(path: str | os.PathLike, max_bytes: int = MAX_GRASP_BYTES, what: str = "YAML file"):
    """`read_limited` then `load_yaml`."""
    return load_yaml(read_limited(path, max_bytes, what), path, what)


# --------------------------------------------------------------------------- outputs


def _same_file(a: Path, b: Path) -> bool:
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path: str | os.PathLike, inputs=(), option: str = "-o") -> Path:
    """Refuse an output path before any work is done.

    Args:
        path: the output file the user named.
        inputs: files the command reads; the output may not be (or link to) any of them.
        option: the command-line option, for the message.

    Returns:
        The path.

    Raises:
        OutputError: the path is empty, an input (also through a symlink or hard link),
            a directory, lies under a regular file, or its directory is not writable.
    """
    text = os.fspath(path)
    if not text or "\n" in text or "\0" in text:
        raise OutputError(f"{option}: not a usable file name: {_short(text)}")
    out = Path(text)
    for inp in inputs:
        if inp is not None and _same_file(out, Path(inp)):
            raise OutputError(f"{option} {text}: is the input {inp}; refusing to overwrite an input file")
    if out.is_dir():
        raise OutputError(f"{option} {text}: is a directory; give a file name")
    parent = out.absolute().parent
    if not parent.exists():  # a typo in a path is an error, not a new folder
        above = parent
        while not above.exists():
            above = above.parent
        if not above.is_dir():
            raise OutputError(f"{option} {text}: {above} is not a directory")
        raise OutputError(f"{option} {text}: folder {parent} does not exist; create it first")
    if not parent.is_dir():
        raise OutputError(f"{option} {text}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {text}: directory {parent} is not writable")
    return out


def write_atomic(path: str | os.PathLike, data: str | bytes) -> Path:
    """Write a file atomically: a temporary file in the same directory, then ``os.replace``.

    The new file gets the permissions a plain ``open(path, "w")`` would give.

    Raises:
        OutputError: the OS refused (no such directory, read-only, disk full...); no
            temporary file is left behind and an existing file is untouched.
    """
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
        tmp = None
    except OSError as err:
        raise OutputError(f"cannot write {path}: {err.strerror or err}") from err
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return path


def check_hand_file(path: str | os.PathLike, source: str, key: str = "hand") -> dict:
    """A hand spec file must be a YAML mapping within the limits; the message names
    ``source`` (the file that refers to it) and ``key``, never the hand file's content.
    Returns the parsed mapping (`planner.hand.Hand` takes it: the file is read once)."""
    try:
        data = read_yaml(path, MAX_GRASP_BYTES, "hand spec")
    except SpecError as err:
        raise SpecError(source, key, f"hand spec {path}: {err.message}") from None
    if not isinstance(data, dict):
        raise SpecError(source, key, f"hand spec {path} is not a YAML mapping (a hand.yaml)")
    return data


def check_grasp_file(path: str | os.PathLike):
    """Read a grasp file within bounds, for the grasp parser (`planner.grasp.load_grasp`):
    size, YAML limits, and a ``hand:`` path that must be a hand spec (checked without
    echoing the file).

    Returns:
        The parsed YAML (any type: the grasp parser says what it expected).
    """
    data = read_yaml(path, MAX_GRASP_BYTES, "grasp file")
    hand = data.get("hand") if isinstance(data, dict) else None
    if isinstance(hand, str) and is_hand_path(hand):
        p = Path(hand)
        if not p.is_absolute():
            p = Path(path).resolve().parent / p
        if p.is_dir():
            p = p / "hand.yaml"
        check_hand_file(p, str(path))
    return data


def sha256_file(path: str | os.PathLike, max_bytes: int | None = None) -> str | None:
    """Hex sha256 of a regular file, read in 1 MiB chunks (a huge or sparse file never sits
    in memory); None when it is not a regular file, cannot be read or holds more than
    ``max_bytes``."""
    import hashlib

    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode) or (max_bytes is not None and st.st_size > max_bytes):
            return None
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        return h.hexdigest()
    except OSError:
        return None
