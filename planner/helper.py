"""A second process for the gait search's per-state work (half of each batch of new states).

The search's cost is mostly evaluating each new state: its force closure, whether it holds the
object's weight in every planned gravity direction (about six grip-force programs per state)
and, for a state that does not, the torque demand its refusal names
(`planner.graph.Evaluator.evaluate_states`), one state after another on one core, while the
verification replays that follow use every core. `Helper` is one process forked from the
planner's (it inherits the imports, so a start costs milliseconds), fed through a pipe: the
caller sends a function and its share of the work, computes the rest itself, then receives the
helper's answers. Results are assembled in the work's order, and each item is computed the same
way wherever it runs.

`fork_map` does the same once for work whose inputs do not pickle (a hand's models): half of it
in a copy forked for the call, which inherits the inputs (the reposing search's contacts per
finger, `planner.intermediate.intermediate_grasps`).

No threads of its own in the planner's process (the verification replays fork it later, and a
fork of a process with live threads can deadlock). A helper that fails (an exception, a lost
pipe) is closed and its share computed by the caller, so an error is raised where the work
would have raised it without a helper. Only where ``fork`` is a start method (Linux; elsewhere
everything runs in the caller).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import pickle
import signal
import traceback
from typing import Callable, Sequence

log = logging.getLogger(__name__)

#: What pickling raises for an object that does not pickle (a lock, a local function, a C++ object).
_UNPICKLABLE = (pickle.PicklingError, TypeError, AttributeError)


def available() -> bool:
    """Whether helpers can be started here (``fork``, inheriting the imported planner)."""
    return "fork" in mp.get_all_start_methods()


def die_with_parent(parent: int) -> None:
    """In a forked worker: end when the process ``parent`` ends, however it ends (SIGKILL, the
    OOM killer: nothing of it runs then). Linux's parent-death signal; elsewhere nothing.
    Without it, the replay workers of a killed planner waited for ever (one blocked writing its
    result to a pipe no one reads but its sibling, the sibling on the pipe's lock), holding the
    caller's stdout and stderr open."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux
        return
    if os.getppid() != parent:  # it ended before the signal was asked for
        os._exit(1)


def _serve(conn, theirs) -> None:
    """The helper's loop: ``(function, items)`` in, ``(True, results)`` or ``(False, text)`` out;
    None (or the pipe closing) ends it. ``theirs``, the caller's end of the pipe (inherited by
    the fork), is closed first: the pipe then closes when the caller dies, however it dies, and
    the helper ends instead of waiting for ever. Ctrl-C is the caller's to handle."""
    theirs.close()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        fn, items = msg
        _answer(conn, lambda: [fn(*item) for item in items])


def _answer(conn, work: Callable[[], list]) -> None:
    """Send ``(True, work())``, or ``(False, the traceback)`` when it raises or its result does
    not pickle (the caller then computes that share itself)."""
    try:
        out = (True, work())
    except BaseException:  # noqa: BLE001 - reported; the caller computes the share itself
        out = (False, traceback.format_exc())
    try:
        conn.send(out)
    except _UNPICKLABLE:  # a result that does not pickle (a broken pipe: the caller is gone)
        conn.send((False, traceback.format_exc()))


class Helper:
    """One forked process computing shares of batches (`map`); `close` ends it.

    Attributes:
        failure: the helper's last failure (its traceback, or why the pipe broke), None when none.
    """

    def __init__(self):
        """Fork the helper. Raises OSError when the system cannot (no pipe ends are left open)."""
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, self._conn), daemon=True, name="regrasp-search-helper")
        try:
            self._proc.start()
        except BaseException:
            self._conn.close()
            raise
        finally:
            child.close()
        self.failure: str | None = None

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def map(self, fn: Callable, items: Sequence[tuple], share: int | None = None) -> list:
        """``[fn(*item) for item in items]``, the last ``share`` items (default half, rounded
        down) computed by the helper while the caller computes the others. ``fn`` must be a
        module-level function and the items and results must pickle."""
        n = len(items)
        k = n // 2 if share is None else max(0, min(n, share))
        if k == 0 or not self.alive:
            return [fn(*item) for item in items]
        mine, theirs = items[: n - k], items[n - k :]
        try:
            self._conn.send((fn, list(theirs)))
        except (OSError, *_UNPICKLABLE) as err:  # a broken pipe or an item that does not pickle
            self._fail(f"could not send the share: {err!r}")
            return [fn(*item) for item in items]
        try:
            out = [fn(*item) for item in mine]
        except BaseException:
            self._receive(lambda *item: None, theirs)  # the helper's answer is read (the pipe stays in step)
            raise
        return out + self._receive(fn, theirs)

    def _receive(self, fn, theirs) -> list:
        try:
            ok, res = self._conn.recv()
        except (EOFError, OSError) as err:
            self._fail(f"the helper's pipe broke: {err!r}")
            ok, res = False, None
        if ok:
            return res
        if res is not None and self.failure is None:
            self._fail(res)
        return [fn(*item) for item in theirs]  # its error, if any, raised here as without a helper

    def _fail(self, why: str) -> None:
        self.failure = why
        log.info("search helper failed (its share is computed by the planner's process): %s", why)
        self.close()

    def close(self) -> None:
        """End the process (idempotent)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            self._conn.send(None)
        except OSError:  # already gone
            pass
        proc.join(timeout=5)
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=5)
        self._conn.close()

    def __enter__(self) -> "Helper":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def cores() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def fork_map(fn: Callable, items: Sequence, processes: int = 2) -> list:
    """``[fn(x) for x in items]``, the last half (rounded down) computed in a copy of this
    process forked for the call while this one computes the rest, when ``processes`` >= 2.
    ``fn`` and the items are inherited by the copy, not pickled (they may hold a hand's models);
    the copy's results are pickled back. For work whose items are computed independently of one
    another (the same results either way). A copy that fails or cannot be forked: its half is
    computed here, so an error is raised here as without it."""
    n = len(items)
    k = n - n // 2
    if processes < 2 or n < 2 or not available():
        return [fn(x) for x in items]
    ctx = mp.get_context("fork")
    mine, theirs = ctx.Pipe()

    def run() -> None:
        mine.close()  # (so the pipe closes when the caller dies)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        _answer(theirs, lambda: [fn(x) for x in items[k:]])

    proc = ctx.Process(target=run, daemon=True, name="regrasp-fork-map")
    try:
        proc.start()
    except OSError:
        mine.close()
        theirs.close()
        return [fn(x) for x in items]
    theirs.close()
    try:
        out = [fn(x) for x in items[:k]]
        try:
            ok, res = mine.recv()
        except (EOFError, OSError) as err:
            ok, res = False, f"the copy's pipe broke: {err!r}"
    except BaseException:  # an error or Ctrl-C here: the copy's half is not wanted
        proc.terminate()
        raise
    finally:
        proc.join()
        mine.close()
    if not ok:
        log.info("forked copy failed (its half is computed here): %s", res)
        res = [fn(x) for x in items[k:]]
    return out + res
