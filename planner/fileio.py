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

Key paths: `Reader` is the one validator of parsed file data (grasp, plan and hand files):
a value at a key path of a file, whose checks raise one `SpecError` naming the file, the key
path (``fingers.index.contact.point``, ``states[3].q``) and what was expected.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from planner.errors import InputError, OutputError, SpecError
from planner.resources import is_hand_path

#: Largest grasp or hand YAML file read, bytes (the bundled ones are under 5 kB).
MAX_GRASP_BYTES = 1_000_000
#: Largest plan file read, bytes (a plan with finger paths is ~0.1-1 MB).
MAX_PLAN_BYTES = 20_000_000
#: Deepest YAML or JSON nesting accepted (grasp and plan files need 5).
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



def resolve_path(path) -> Path:
    """``path`` with its symlinks followed (`pathlib.Path.resolve`, not strict); OSError (ELOOP)
    when they loop, on every Python: before 3.13 ``resolve`` raised RuntimeError on a loop, since
    it returns a path that still loops."""
    p = Path(path)
    try:
        out = p.resolve()
    except RuntimeError as err:
        raise OSError(errno.ELOOP, str(err)) from None
    try:
        os.stat(out)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise OSError(errno.ELOOP, f"Symlink loop from {str(p)!r}") from None
    return out

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
            open_nodes: set[int] = set()  # the nodes being expanded: the path from the root

            def expanded(n) -> int:
                k = id(n)
                if k in open_nodes:  # every reader walks the values: it would never end (or fail deep inside)
                    raise yaml.YAMLError(f"an alias refers to a value that contains it: a recursive structure "
                                         f"({_where(n)})")
                if k not in sizes:
                    open_nodes.add(k)
                    sizes[k] = 1
                    if isinstance(n, yaml.SequenceNode):
                        sizes[k] = 1 + sum(expanded(c) for c in n.value)
                    elif isinstance(n, yaml.MappingNode):
                        sizes[k] = 1 + sum(expanded(a) + expanded(b) for a, b in n.value)
                    if sizes[k] > self._max_nodes:
                        raise yaml.YAMLError(f"its aliases expand to more than {self._max_nodes} values, "
                                             f"{MAX_YAML_NODES_PER_CHAR} per character of the file ({_where(n)})")
                    open_nodes.discard(k)
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


def as_path(value, what: str, expected: str = "a file path") -> Path:
    """A file argument of the Python API as a `Path`.

    Raises:
        InputError: ``value`` is not a str or os.PathLike naming a file (an int, None, a dict,
            bytes: pathlib's TypeError before) or is empty (the current folder before), naming
            ``what`` and what was ``expected``.
    """
    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else None
    if not isinstance(text, str):
        raise InputError(f"{what}: expected {expected}, got {describe(value)}")
    if not text:
        raise InputError(f"{what}: expected {expected}, got an empty file name")
    return Path(text)


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

    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as err:  # JSONDecodeError is a ValueError
        first = str(err).splitlines()[0] if isinstance(err, json.JSONDecodeError) else "numbers or nesting out of range"
        raise SpecError(str(path), "", f"not valid JSON: {first[:120]}") from None
    # Python 3.12+ parses thousands of levels (its C recursion limit is not sys's), which the
    # code reading the value would not survive: the YAML files' depth bound, checked here
    level, depth = [data] if isinstance(data, (dict, list)) else [], 0
    while level:  # one nesting level at a time: its containers' contained containers
        depth += 1
        if depth > MAX_YAML_DEPTH:
            raise SpecError(str(path), "", f"not valid JSON: nesting deeper than {MAX_YAML_DEPTH} levels")
        level = [v for c in level for v in (c.values() if isinstance(c, dict) else c) if isinstance(v, (dict, list))]
    return data


def read_yaml(path: str | os.PathLike, max_bytes: int = MAX_GRASP_BYTES, what: str = "YAML file"):
    """`read_limited` then `load_yaml`."""
    return load_yaml(read_limited(path, max_bytes, what), path, what)


# --------------------------------------------------------------------------- key paths


def repr_short(value, limit: int = 80) -> str:
    """``repr(value)`` for a message, at most ``limit`` characters (a name in a file may be a
    megabyte long)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def number_text_hint(value) -> str:
    """For a message: a text that reads as a number ('1e-9': YAML 1.1 reads an exponent
    without a dot as text) says how to write it; else nothing."""
    if isinstance(value, str) and len(value) < 40:
        text = value.strip()
        try:
            x = float(text)
        except ValueError:
            return ""
        mantissa, e, exponent = text.lower().partition("e")
        if math.isfinite(x) and e and "." not in mantissa:  # YAML 1.1's float: a dot, a signed exponent
            return f" (YAML reads {text} as text: write {mantissa}.0e{'' if exponent[:1] in '+-' else '+'}{exponent})"
        if math.isfinite(x):
            return " (a number in quotes is text: write it without quotes)"
    return ""


def describe(value) -> str:
    """A value for a message, with its type: ``nothing (null)``, ``str 'high'``, at most 40
    characters of its repr (the grasp file's messages)."""
    if value is None:
        return "nothing (null)"
    text = repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{type(value).__name__} {text}"


def shown(value) -> str:
    """A value for a message, short and one line: ``null``, a number (24 characters at most),
    else only its type's name (the plan file's messages: a plan is large)."""
    if value is None:
        return "null"
    if isinstance(value, (bool, int, float)):
        text = repr(value)
        return text if len(text) <= 24 else text[:21] + "..."
    return type(value).__name__


def join_key(key: str, sub, index: bool = False) -> str:
    """The key path of entry ``sub`` under ``key``: ``a.b``, or with ``index`` (a list's
    item) ``a[3]``."""
    if index:
        return f"{key}[{sub}]"
    return f"{key}.{sub}" if key else str(sub)


class Reader:
    """A value at a key path of a file, with checks that raise one `SpecError(file, key path,
    message)` on the first problem.

    The checks return the checked value (`mapping` and `seq` return the reader itself, so
    ``r.child("object").mapping()`` goes on reading); `child` and `items` give the readers of
    a mapping's entries and a list's items, whose key paths extend this one.

    Args:
        path: the file, for messages.
        value: the parsed data at ``key``.
        key: the key path ("" for the top level).
        got: how a value of the wrong type is shown in "expected ..., got ..." (`describe`,
            `shown` or `repr`).
        got_value: how a value of the right type but out of range is shown.
        ranged: number messages state the range (``expected a finite number in [0, 10]``)
            and an integer of 2**63 or more is infinite (plan files); else they say which bound
            (``expected a positive number``).
    """

    def __init__(self, path, value: Any = None, key: str = "", *, got=describe, got_value=repr, ranged: bool = False):
        self.path = str(path)
        self.value = value
        self.key = key
        self.got = got
        self.got_value = got_value
        self.ranged = ranged

    # -- navigation
    def sub_key(self, sub) -> str:
        """The key path of entry ``sub`` of this mapping, or of item ``sub`` of this list."""
        return join_key(self.key, sub, index=isinstance(self.value, (list, tuple)))

    def fail(self, message: str, sub=None) -> SpecError:
        """The error for this key path (or its entry ``sub``); the caller raises it."""
        return SpecError(self.path, self.key if sub is None else self.sub_key(sub), message)

    def at(self, value: Any, key: str | None = None) -> "Reader":
        """A reader of ``value`` in the same file, at ``key`` (default: this key path)."""
        return Reader(self.path, value, self.key if key is None else key, got=self.got, got_value=self.got_value,
                      ranged=self.ranged)

    def child(self, sub, default: Any = None) -> "Reader":
        """The reader of entry ``sub`` of this mapping (``default`` when absent) or of item
        ``sub`` of this list."""
        value = self.value[sub] if isinstance(self.value, (list, tuple)) else self.value.get(sub, default)
        return self.at(value, self.sub_key(sub))

    def items(self) -> list:
        """``(key, reader)`` for each entry of this mapping, ``(index, reader)`` for each item
        of this list."""
        if isinstance(self.value, (list, tuple)):
            return [(i, self.child(i)) for i in range(len(self.value))]
        return [(k, self.at(v, join_key(self.key, k))) for k, v in self.value.items()]

    def __contains__(self, sub) -> bool:
        return sub in self.value

    def get(self, sub, default: Any = None) -> Any:
        """The raw value of entry ``sub`` (``default`` when absent)."""
        return self.value.get(sub, default)

    # -- structure
    def mapping(self, expected: str = "a mapping", *, string_keys: bool = False, nonempty: bool = False,
                with_value: bool = True) -> "Reader":
        """This value must be a mapping (``nonempty``: with an entry; ``string_keys``: keyed by
        strings): "expected {expected}, got {value}" (``with_value=False``: without the value)."""
        v = self.value
        if not isinstance(v, Mapping) or (nonempty and not v):
            raise self.fail(f"expected {expected}, got {self.got(v)}" if with_value else f"expected {expected}")
        if string_keys:
            for k in v:
                if not isinstance(k, str):
                    raise self.fail(f"keys must be strings, got {k!r}")
        return self

    def allow(self, allowed) -> None:
        """Every key of this mapping must be one of ``allowed``."""
        for k in self.value:
            if k not in allowed:
                raise self.fail(f"unknown key {k!r}; valid keys are {', '.join(allowed)}", k)

    def require(self, *keys: str, message: str | None = None) -> None:
        """This mapping must hold every key of ``keys``: the message (default "missing
        required key 'k'") names the first missing one's key path."""
        for k in keys:
            if k not in self.value:
                raise self.fail(f"missing required key {k!r}" if message is None else message, k)

    def keys(self, allowed, required=()) -> None:
        """`allow` then `require`."""
        self.allow(allowed)
        self.require(*required)

    def seq(self, most: float = math.inf, least: int = 0) -> "Reader":
        """This value must be a list of ``least`` to ``most`` items."""
        v = self.value
        if not isinstance(v, list):
            raise self.fail(f"expected a list, got {self.got(v)}")
        if not least <= len(v) <= most:
            raise self.fail(f"expected {least} to {most} entries, got {len(v)}")
        return self

    def strings(self) -> list:
        """This value must be a list of strings: "expected a list of str, got ..."."""
        v = self.value
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise self.fail(f"expected a list of str, got {self.got(v)}")
        return v

    # -- scalars
    def string(self) -> str:
        """A non-empty string (not only blanks)."""
        v = self.value
        if not isinstance(v, str) or not v.strip():
            raise self.fail(f"expected a non-empty string, got {self.got(v)}")
        return v

    def name(self, longest: int = 200) -> str:
        """A one-line name of at most ``longest`` characters."""
        v = self.value
        if not isinstance(v, str) or not v or "\n" in v or len(v) > longest:
            raise self.fail(f"expected a one-line name, got {self.got(v)}")
        return v

    def choice(self, choices, what: str, *, valid: str | None = None, show=None):
        """One of ``choices``: "unknown {what} {value}; {what}s are a, b" (``valid`` replaces
        "{what}s are"; ``show`` how the value is shown, default ``got_value``)."""
        v = self.value
        if v not in choices:
            shown_v = (show or self.got_value)(v)
            raise self.fail(f"unknown {what} {shown_v}; {valid or what + 's are'} {', '.join(choices)}")
        return v

    def number(self, low: float = -math.inf, high: float = math.inf, *, positive: bool = False,
               nonnegative: bool = False, bools: bool = False, expected: str | None = None) -> float:
        """A finite number in [low, high] (``positive``: > 0, ``nonnegative``: >= 0; ``bools``:
        true and false count as 1 and 0), as a float.

        With ``expected``, every failure says "expected {expected}, got {value}"."""
        v = self.value

        def bad(message: str) -> SpecError:
            return self.fail(f"expected {expected}, got {self.got_value(v)}" if expected else message)

        if (isinstance(v, bool) and not bools) or not isinstance(v, (int, float)):
            raise bad(f"expected a number, got {self.got(v)}{number_text_hint(v)}")
        if self.ranged:
            x = float(v) if not isinstance(v, int) or abs(v) < 2**63 else math.inf
            if not (math.isfinite(x) and low <= x <= high and not (positive and not x > 0)
                    and not (nonnegative and x < 0)):
                bounds = f" in [{low:g}, {high:g}]" if math.isfinite(low) or math.isfinite(high) else ""
                raise bad(f"expected a finite number{bounds}, got {self.got_value(v)}")
            return x
        x = float(v)
        if not math.isfinite(x):
            raise bad(f"expected a finite number, got {self.got_value(v)}")
        if positive and not x > 0:
            raise bad(f"expected a positive number, got {self.got_value(v)}")
        if nonnegative and x < 0:
            raise bad(f"expected a non-negative number, got {self.got_value(v)}")
        if not low <= x <= high:
            raise bad(f"expected a number in [{low:g}, {high:g}], got {self.got_value(v)}")
        return x

    def quantity(self, low: float, high: float, unit: str = "", *, open_low: bool = False) -> float:
        """A finite number in [low, high] (``open_low``: in (low, high]), as a float; every
        message states the range and ``unit`` ("expected a finite number in (0, 1000] kg, got
        inf", "expected a positive number in ...", "expected a number in ...")."""
        v = self.value
        valid = f"{'(' if open_low else '['}{low:g}, {high:g}]{' ' + unit if unit else ''}"
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(f"expected a number in {valid}, got {self.got(v)}{number_text_hint(v)}")
        x = float(v) if not isinstance(v, int) or abs(v) < 2**63 else math.copysign(math.inf, v)
        if not math.isfinite(x):
            raise self.fail(f"expected a finite number in {valid}, got {self.got_value(v)}")
        if (low < x if open_low else low <= x) and x <= high:
            return x
        kind = "a positive number" if x <= 0 and (low > 0 or (open_low and low == 0)) else "a number"
        raise self.fail(f"expected {kind} in {valid}, got {self.got_value(v)}")

    def integer(self, low: float = -math.inf, high: float = math.inf, *, expected: str | None = None) -> int:
        """An integer (not a boolean) in [low, high]: "expected {expected}, got {value}"."""
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
            raise self.fail(f"expected {expected or f'an integer in [{low:g}, {high:g}]'}, got {self.got_value(v)}")
        return v

    # -- vectors
    def vector(self, lengths, meaning: str = "", quantity: tuple | None = None, **number) -> tuple[float, ...]:
        """A list of ``lengths`` (one of them) numbers, each checked by `number` (``number``:
        its keywords), or by `quantity` (``quantity``: its arguments), at its own key path
        ``key[i]``; ``meaning`` is said in the message."""
        lengths = tuple(lengths)
        expect = " or ".join(str(n) for n in lengths)
        hint = f" ({meaning})" if meaning else ""
        v = self.value
        if not isinstance(v, (list, tuple)):
            raise self.fail(f"expected a list of {expect} numbers{hint}, got {self.got(v)}")
        if len(v) not in lengths:
            raise self.fail(f"expected {expect} numbers{hint}, got {len(v)}")
        items = [self.at(x, join_key(self.key, i, index=True)) for i, x in enumerate(v)]
        return tuple(r.quantity(*quantity) if quantity else r.number(**number) for r in items)

    def numbers(self, length: int, low: float = -math.inf, high: float = math.inf) -> list[float]:
        """A list of exactly ``length`` numbers in [low, high] (`seq` then `number` per item)."""
        return [item.number(low, high) for _, item in self.seq(length, length).items()]

    def rows(self, most: int, width: int, bound: float) -> np.ndarray:
        """(n, width) array from a list of at most ``most`` lists of ``width`` numbers in
        [-bound, bound]."""
        rows = self.seq(most).items()
        for _, row in rows:
            for _, x in row.seq(width, width).items():
                x.number(-bound, bound)
        return np.array(self.value, dtype=float).reshape(len(rows), width)

    def array(self, length: int) -> np.ndarray:
        """Anything numpy reads as ``length`` finite numbers (a list, a tuple), as an array:
        "expected {length} numbers" / "expected {length} finite numbers, got ..."."""
        v = self.value
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError) as err:
            raise self.fail(f"expected {length} numbers, got {self.got_value(v)}") from err
        if a.shape != (length,) or not np.all(np.isfinite(a)):
            raise self.fail(f"expected {length} finite numbers, got {self.got_value(v)}")
        return a


# --------------------------------------------------------------------------- outputs


def _same_file(a: Path, b: Path) -> bool:
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


#: The picture and film options and the suffix each one's format takes (any case): a file
#: named otherwise would hold another format than its name says (``--png x.jpg`` was a JPEG,
#: ``--gif x.png`` a GIF).
OUTPUT_SUFFIXES = {"--png": ".png", "--gif": ".gif", "--mp4": ".mp4"}


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


def write_atomic(path: str | os.PathLike, data: str | bytes | None = None, *, write=None,
                 exclusive: bool = False) -> Path:
    """Write a file atomically: a temporary file in the same directory, then ``os.replace``
    (the one writer of every output: plans, reports, pages, films, synthesized grasps).

    The new file gets the permissions a plain ``open(path, "w")`` would give.

    Args:
        path: the file to write.
        data: its content (text is written as UTF-8); or
        write: a function that writes the temporary file given its path (a GIF encoder).
        exclusive: never replace a file: fail if ``path`` exists when it is written (a hard
            link of the temporary file, which fails if the name appeared meanwhile).

    Raises:
        OutputError: the OS refused (no such directory, read-only, disk full...), or
            ``exclusive`` and the file exists; no temporary file is left behind and an
            existing file is untouched.
    """
    if (data is None) == (write is None):
        raise InputError("write_atomic takes data or write, not both or neither")
    path = Path(path)
    raw = None if data is None else (data.encode("utf-8") if isinstance(data, str) else bytes(data))
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            if raw is not None:
                fh.write(raw)
        if write is not None:
            write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if exclusive:
            os.link(tmp, path)
        else:
            os.replace(tmp, path)
            tmp = None
    except FileExistsError as err:
        raise OutputError(f"cannot write {path}: it appeared while writing; nothing was overwritten") from err
    except OSError as err:
        raise OutputError(f"cannot write {path}: {err.strerror or err}") from err
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return path


def check_outputs(outputs, inputs=(), *, formats: bool = True) -> None:
    """Every output file of one command, before any work: none is an input (`check_output`:
    also through a link), no two are the same file and (``formats``) a picture or film is
    named with its format's suffix (`OUTPUT_SUFFIXES`).

    Args:
        outputs: (path or None, option) pairs: every file the command will write, derived
            names included (a film per gravity direction).
        inputs: every file the command reads.
        formats: check the suffixes too (False: a first check before the inputs are read, whose
            files may still be found to be inputs: that is said first).
    """
    # as given: an empty name is refused by `check_output` (Path("") is the current folder)
    named = [(p if isinstance(p, str) else os.fspath(as_path(p, option, "an output file path")), option)
             for p, option in outputs if p is not None]
    inputs = [p for p in inputs if p is not None]
    for k, (out, option) in enumerate(named):
        check_output(out, inputs, option)
        for other, other_option in named[:k]:
            if _same_file(Path(out), Path(other)):
                raise OutputError(f"{option} {out}: is also the file of {other_option}; give them different names")
    for out, option in named if formats else ():
        check_format(out, option)


def check_format(path: str | os.PathLike, option: str) -> None:
    """A picture or film (``option`` in `OUTPUT_SUFFIXES`) is named with its format's suffix."""
    suffix, out = OUTPUT_SUFFIXES.get(option), Path(os.fspath(path))
    if suffix is not None and out.suffix.lower() != suffix:
        raise OutputError(f"{option} {out}: {option} writes {suffix[1:].upper()}: name the file *{suffix} "
                          + (f"(not {out.suffix})" if out.suffix else "(this name has no suffix)"))


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
