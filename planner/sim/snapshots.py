"""Replays resumed where an earlier replay of a plan with the same beginning stood.

The planner's verification replays sequence after sequence: when one fails, its failed move
is taken out of the graph and the next best sequence is replayed, first in the directions
that rejected one before. That sequence mostly begins with the moves of the one rejected,
so its replay repeats their simulation. Inside a `scope` (the planner's verification), a
replay running in a forked worker process leaves a snapshot at every plan state it has
measured: a forked copy of itself, stopped, listening on a socket named by a digest of
everything the simulation up to that state depends on (`Chain`: the replay's parameters,
the engine, the plan's hand, object, friction and parameters, its states and steps up to
there). A later replay whose digest at some state matches resumes from the latest such
snapshot: the snapshot forks again, and the copy swaps in the new plan's states and steps
and goes on from there. Its memory is the snapshot's, byte for byte, and the simulation is
deterministic and reads nothing else up to that state, so its report is the report of a
replay from the start (the wall time it gives is that of the simulation it ran, as if in
one go; a replay stopped because a direction before it failed may stop at another state
than from the start, as its timing does anyway: a verification leaves its row out). Whatever
fails in this (a snapshot gone, a socket refused, a copy that dies), the replay runs from the
start.

Snapshots live until their scope ends (they exit within `POLL_S` once its directory is
gone, or when the process that opened the scope has exited: the first to see that removes
the directory); at most `MAX_SNAPSHOTS` per scope. A replay in the scope's own process (one
worker) leaves none: it would fork the planner.
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import json
import os
import pickle
import shutil
import socket
import tempfile
import time
from multiprocessing.connection import Connection

#: How often a stopped snapshot checks that its scope still exists (s), and a resumed
#: replay's requester forwards the other directions' stop line (s).
POLL_S = 0.5
FORWARD_S = 0.02
#: Snapshots kept per scope at most (each holds the memory its replay changed after it).
MAX_SNAPSHOTS = 96

_SCOPE: dict = {}


@contextlib.contextmanager
def scope():
    """Replays run in worker processes while this is open leave snapshots and resume from
    them (`replay_plan`'s ``snapshots``: `current`). Nested scopes share the outer one."""
    if _SCOPE:
        yield _SCOPE["dir"]
        return
    if not hasattr(os, "fork") or not hasattr(socket, "AF_UNIX"):
        yield None
        return
    d = tempfile.mkdtemp(prefix="regrasp-snap-")
    _SCOPE.update(dir=d, pid=os.getpid())
    try:
        yield d
    finally:
        _SCOPE.clear()
        shutil.rmtree(d, ignore_errors=True)  # the snapshots see it gone and exit


def current() -> tuple[str, int] | None:
    """(directory, pid of the process that opened it) of the open scope, or None."""
    return (_SCOPE["dir"], _SCOPE["pid"]) if _SCOPE else None


def _h(*parts) -> str:
    h = hashlib.blake2b(digest_size=16)
    for p in parts:
        h.update(json.dumps(p, sort_keys=True, default=repr).encode())
        h.update(b"\0")
    return h.hexdigest()


class Chain:
    """The digests of a replay's prefixes: ``at(k)`` names the simulation once state 0
    (``k = -1``) or plan step ``k`` and the state it reaches are measured. Each covers the
    replay's parameters (``setting``: its parameter dict, the engine, what it loads), the
    plan's hand, object, friction, parameters and joints, state 0, and every step up to ``k``
    with the states it goes from and to: all the replay reads up to there."""

    BASE_KEYS = ("schema_version", "kind", "hand", "object", "friction", "parameters", "joints")

    def __init__(self, plan, setting):
        d = plan.to_dict()
        states, steps = d["states"], d["steps"]
        head = _h(setting, {k: d.get(k) for k in self.BASE_KEYS}, states[0] if states else None)
        self.digests = [head]
        for st in steps:
            fs, ts = st.get("from_state"), st.get("to_state")
            self.digests.append(_h(self.digests[-1], st, states[fs] if isinstance(fs, int) else None,
                                   states[ts] if isinstance(ts, int) else None))

    def at(self, k: int) -> str:
        return self.digests[k + 1]


class _LineProxy:
    """A `planner.sim.replay.StopLine` seen through the requester's connection (a resumed
    copy cannot share the requester's memory): the requester says when a replay before it
    failed, and a failure here is marked there."""

    def __init__(self, conn: Connection):
        self.conn, self._stopped = conn, False

    def stopped(self) -> bool:
        while not self._stopped and self.conn.poll(0):
            self._stopped = self.conn.recv()[0] == "stop"
        return self._stopped

    def fail(self) -> None:
        self.conn.send(("fail", None))


class Snapshots:
    """One replay's part: `resume` (before it builds anything), `checkpoint` (at every
    measured state), `finish` (a resumed copy hands its report back and exits)."""

    def __init__(self, where: tuple[str, int], chain: Chain):
        self.dir, self.owner = where
        self.chain = chain
        self.resumed: Connection | None = None
        self.paused_s = 0.0  # time the replay stood as a snapshot (not simulating)

    def _path(self, digest: str) -> str:
        return os.path.join(self.dir, digest + ".s")

    # -- the requester ---------------------------------------------------------------

    def resume(self, plan, line):
        """The report of this plan's replay from the latest snapshot of its prefix, or None
        (no snapshot, or it failed: replay from the start)."""
        for k in range(len(self.chain.digests) - 2, -2, -1):
            path = self._path(self.chain.at(k))
            if not os.path.exists(path):
                continue
            try:
                s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                s.connect(path)
            except OSError:
                continue
            conn = Connection(s.detach())
            try:
                conn.send(("resume", plan.to_dict(), self.chain.digests))
                return self._wait(conn, line)
            except (OSError, EOFError, pickle.PicklingError):
                return None
            finally:
                conn.close()
        return None

    @staticmethod
    def _wait(conn: Connection, line):
        told = False
        while True:
            if line is not None and not told and line.stopped():
                with contextlib.suppress(OSError):  # (a copy that has just sent its report and exited)
                    conn.send(("stop", None))
                told = True
            if conn.poll(FORWARD_S):
                kind, v = conn.recv()
                if kind == "fail":
                    if line is not None:
                        line.fail()
                elif kind == "done":
                    return v
                else:  # "error": the copy failed; a replay from the start says how
                    return None

    # -- the replay that leaves snapshots ----------------------------------------------

    def checkpoint(self, sim, k: int) -> None:
        """Leave a snapshot of ``sim`` once state 0 (-1) or plan step ``k`` is measured; in a
        copy resumed from it, return with the new plan swapped in (`_swap`)."""
        if os.getpid() == self.owner or not os.path.isdir(self.dir):
            return
        path = self._path(self.chain.at(k))
        try:
            if os.path.exists(path) or len(os.listdir(self.dir)) >= MAX_SNAPSHOTS:
                return
            pid = os.fork()
        except OSError:
            return
        if pid:  # the replay goes on (the snapshot outlives it: never waited for here)
            # the objects so far are left out of the garbage collector's passes: a pass over
            # the whole heap would write every page, which the snapshot shares (copy on write)
            gc.freeze()
            return
        try:
            got = self._serve(path)
        except BaseException:  # noqa: BLE001 - a snapshot never returns into the replay unless resumed
            os._exit(0)
        conn, data, digests, stood = got
        from planner.plan import plan_from_data  # the plan as the requester's replay reads it

        gc.freeze()  # (as the replay that left the snapshot does: its pages stay shared)
        self.resumed = conn
        self.paused_s += stood
        self.chain.digests = list(digests)
        sim.swap_plan(plan_from_data(data), _LineProxy(conn))

    def _serve(self, path: str):
        """Stand as a snapshot: answer every request by a forked copy that returns (the
        request's connection, plan, digests, seconds stood); exit when the scope ends."""
        t0 = time.perf_counter()
        # the replay's output pipes are not held open by a snapshot (a caller reading the
        # planner's output to its end would wait for the scope's end)
        null = os.open(os.devnull, os.O_RDWR)
        for fd in (1, 2):
            os.dup2(null, fd)
        os.close(null)
        srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        tmp = path + f".{os.getpid()}"
        srv.bind(tmp)
        srv.listen(16)
        os.rename(tmp, path)
        srv.settimeout(POLL_S)
        while True:
            with contextlib.suppress(ChildProcessError):
                while os.waitpid(-1, os.WNOHANG)[0]:
                    pass
            try:
                s, _ = srv.accept()
            except socket.timeout:
                if not os.path.isdir(self.dir):
                    os._exit(0)
                if not _alive(self.owner):
                    # the planner is gone without closing its scope (killed): its directory
                    # goes too, and its other snapshots, seeing it gone, exit
                    shutil.rmtree(self.dir, ignore_errors=True)
                    os._exit(0)
                continue
            s.setblocking(True)
            conn = Connection(s.detach())
            try:
                kind, plan, digests = conn.recv()
            except (EOFError, OSError, ValueError, TypeError, AttributeError, ImportError, IndexError, KeyError,
                    pickle.UnpicklingError):  # a bad request (what unpickling raises): dropped
                conn.close()
                continue
            if kind != "resume" or os.fork():
                conn.close()
                continue
            srv.close()
            return conn, plan, digests, time.perf_counter() - t0

    def finish(self, report=None, error: BaseException | None = None) -> None:
        """In a copy resumed from a snapshot: send the report (or that it failed) to the
        requester and exit; nothing in any other replay."""
        if self.resumed is None:
            return
        with contextlib.suppress(BaseException):
            self.resumed.send(("done", report) if error is None else ("error", repr(error)))
        os._exit(0)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
