"""Error hierarchy: every failure a user can cause is a `PlannerError`.

The CLI turns a `PlannerError` into one line on stderr and a non-zero exit code;
any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations


def one_line(text) -> str:
    """``text`` fit for a one-line message: line breaks and every other control or
    non-printing character (a file, key or option name may hold any: form feed, U+2028,
    a terminal escape) shown escaped, e.g. ``\\n``, ``\\x1b``, ``\\u2028``."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in text)


class PlannerError(Exception):
    """Root of every error the planner raises on purpose."""


class InputError(PlannerError, ValueError):
    """An argument has the wrong shape, a non-finite value or is out of range."""


class SpecError(PlannerError):
    """A YAML file (hand spec, grasp, plan) is invalid.

    Args:
        path: the file.
        key: dotted key path inside the file, e.g. ``fingers.index.contact.point``.
        message: what was wrong and what was expected.
    """

    def __init__(self, path: str, key: str, message: str):
        self.path = str(path)
        self.key = key
        self.message = message
        where = f"{one_line(self.path)}: {one_line(key)}: " if key else f"{one_line(self.path)}: "
        super().__init__(where + message)

    def __reduce__(self):  # rebuilt from its own arguments (a replay in a worker process raises it)
        return (type(self), (self.path, self.key, self.message))


def _plural(kind: str) -> str:
    """"strategy" -> "strategies", "finger with collision geometry" -> "fingers with collision
    geometry" ("strategys", "finger with collision geometrys" before), "hand" -> "hands"."""
    head, sep, tail = kind.partition(" with ")
    head = head[:-1] + "ies" if head.endswith("y") and head[-2:-1] not in "aeiou" else head + "s"
    return head + sep + tail


class UnknownNameError(PlannerError, KeyError):
    """A name (finger, link, joint, planner...) is not one of the valid choices."""

    def __init__(self, kind: str, name: str, valid):
        self.kind = kind
        self.name = name
        self.valid = sorted(valid)
        super().__init__(f"unknown {kind} {one_line(repr(name))}; {_plural(kind)} are {', '.join(map(one_line, self.valid))}")

    def __reduce__(self):
        return (type(self), (self.kind, self.name, self.valid))

    def __str__(self) -> str:  # KeyError would otherwise quote the message
        return self.args[0]


class KinematicsError(PlannerError):
    """Inverse kinematics failed: a target is out of reach or outside joint limits."""


class NoSequenceError(PlannerError):
    """No finger-gaiting sequence connects the two grasps; the message says why."""

    def __init__(self, message: str, report: dict | None = None):
        self.report = report or {}
        super().__init__(message)


class InitialGraspDrops(NoSequenceError):
    """The initial grasp does not hold in the simulator: every plan starts there, so no sequence
    and no reposing move can pass (`planner.regrasp.plan_gaits` raises it; the reposing routes
    are not tried after it)."""


class MotionError(PlannerError):
    """A finger path could not be planned within its time budget."""


class SimulationError(PlannerError):
    """The physics back end failed or the replay could not be set up."""


class OutputError(PlannerError):
    """An output file cannot be written: it is an input, a directory, or the OS refused it."""


class IntegrityError(SpecError):
    """A plan file is incomplete or altered: its digest, counts or step chain do not match."""


class AuditError(SpecError):
    """A plan file is intact but physically wrong: a contact off the object, a path through
    it, a chain that does not reach the final grasp (`planner.audit`)."""


class PlannerWarning(UserWarning):
    """Something the user should know that does not stop the command (the CLI prints one
    ``warning:`` line per warning on stderr), e.g. a plan's input file changed since planning."""
