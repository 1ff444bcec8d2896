"""An intermediate grasp for a reposing move: contacts every holding finger keeps along the path.

Two grasps whose object poses differ (A, B) are joined today by taking an end grasp itself to
a candidate pose (`planner.pose_search`); that fails when an end grasp's contacts (mostly the
thumb's, often at a joint limit) cannot follow the object. Here the plan goes through a
synthesized grasp G* instead: finger gaits at pose A from the initial grasp to G* at A, the
reposing move of G* from A to B (`planner.repose.repose`, every check as for any move), finger
gaits at pose B from G* at B to the final grasp.

G* is built per finger (`finger_choices`): an object point (object frame) the finger touches
at pose A with its joints off their limits (`MARGIN_RAD`) and keeps, alone, along the whole
straight object path from A to B (`follow_alone`, the reposing follower on one finger: the
path is the object's, so a finger's joints depend on no other finger). A finger's own contact
in the initial grasp is kept when it follows (no gait at A for it); the final grasp's when the
finger follows it back from B to A (none at B); other points are seeded surface samples placed
by the grasp realization's own placement (`planner.realization.place_contact`, the fingertip
pad). Combinations of one choice per finger (the thumb always among them when the hand has one,
at least two fingers) are measured at A (`planner.realization.measure` with the fingers at their
choices' joints and the others open) and judged by the planner's state test (force closure, and
with gravity the load held in every planned direction) at A and at B, then reposed from A to B
in full. Work-bounded: a fixed number of samples per finger (`SAMPLES`), choices kept per finger
(`KEEP`), combinations measured (`COMBOS`) and grasps returned (`GRASPS`), seeded by
``options.seed``; never a clock.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from planner.errors import MotionError
from planner.grasp import FingerSpec
from planner.helper import cores, fork_map
from planner.realization import PENETRATION_TOL_M, measure
from planner.repose import FOLLOW_TOL_M, Reposing, _follow, _holds, object_path, repose, state_reason

#: Surface points sampled per finger (object frame, seeded).
SAMPLES = 200
#: Choices kept per finger (its own contacts first, then samples by joint margin).
KEEP = 6
#: Two contacts of a finger closer than this (m, object frame) are one choice.
DISTINCT_M = 0.003
#: Finger combinations whose closure is computed at most (`_combos`).
SCAN = 2000
#: Finger combinations measured at most.
COMBOS = 48
#: Intermediate grasps returned at most (each passed the whole reposing move).
GRASPS = 3
#: A finger's joints stay at least this far from their limits (rad) at pose A and all along
#: the path, so the finger can still move its contact where the gaits or the load need.
MARGIN_RAD = 0.03


def joint_margin(hand, finger: str, q) -> float:
    """The least distance (rad) of ``finger``'s joints in ``q`` (whole hand) to their limits."""
    idx = list(hand.fingers[finger].q_index)
    q = np.asarray(q, float)[idx]
    return float(np.min(np.minimum(q - np.asarray(hand.lower, float)[idx], np.asarray(hand.upper, float)[idx] - q)))


def follow_alone(hand, obj, finger: str, q, holds, poses, twist: bool, out: list | None = None
                 ) -> tuple[int, str, np.ndarray, float]:
    """``finger`` alone following its contacts ``holds`` (`planner.repose._holds`) while the
    object (``obj``, moved) takes the poses ``poses`` (its first the start), the reposing
    follower (`planner.repose._follow`) at every waypoint. Returns (waypoints passed, why it
    stopped: "follow" (its outermost contact off its object point by more than the follower's
    2 x tolerance, as `planner.repose.repose` refuses it), "deep" (one of its links more than
    `PENETRATION_TOL_M` inside the object) or "" (all the way), the whole-hand joints at the
    last waypoint passed, the least joint margin (`joint_margin`) over the waypoints passed);
    ``out`` (optional) gets the finger's joints at every waypoint passed, the start first."""
    lo, hi = np.asarray(hand.lower, float), np.asarray(hand.upper, float)
    q = np.array(q, dtype=float)
    passed, why, margin, last = 0, "", joint_margin(hand, finger, q), q.copy()
    idx = list(hand.fingers[finger].q_index)
    if out is not None:
        out.append(q[idx].copy())
    for k in range(1, len(poses)):
        q, worst, _ = _follow(hand, finger, q, holds, poses[k], lo, hi, twist)
        if worst > 2 * FOLLOW_TOL_M:
            why = "follow"
            break
        if hand.state(q).finger_object_distance(obj.with_pose(poses[k]), finger) < -PENETRATION_TOL_M:
            why = "deep"
            break
        passed, last = k, q.copy()
        margin = min(margin, joint_margin(hand, finger, q))
        if out is not None:
            out.append(q[idx].copy())
    return passed, why, last, margin


def touching_postures(hand, finger: str, obj, rng, n: int) -> list[np.ndarray]:
    """Whole-hand joints (the other fingers open) at which ``finger`` touches ``obj``: ``n``
    seeded postures, its free coordinates uniform within their limits less `MARGIN_RAD`, each
    one clear of the object closed onto it by the realization's closing procedure
    (`planner.hand.Hand.close_finger`, as a ``posture:`` finger is); those that touch."""
    f = hand.fingers[finger]
    idx = list(f.q_index)
    lo, hi = np.asarray(hand.lower, float)[idx], np.asarray(hand.upper, float)[idx]
    out = []
    for _ in range(n):
        q = np.array(hand.q_open, dtype=float)
        qf = np.array(q[idx])
        for j in f.free:
            a, b = lo[j] + MARGIN_RAD, hi[j] - MARGIN_RAD
            qf[j] = rng.uniform(a, b) if b > a else 0.5 * (lo[j] + hi[j])
        q[idx] = f.couple(qf)
        if hand.state(q).finger_object_distance(obj, finger) <= 0.0:
            continue
        q = hand.close_finger(f, q, obj)
        if hand.state(q).finger_object_distance(obj, finger) <= 0.0015:
            out.append(q)
    return out


@dataclass(frozen=True, eq=False)
class FingerChoice:
    """One finger's contact in an intermediate grasp.

    Attributes:
        finger: its name.
        source: "initial" or "final" (that grasp's own contact) or "sampled".
        p_obj: its outermost contact point, object frame.
        link: the link touching there.
        q_a: the finger's joints touching it at pose A.
        margin: the least joint margin (rad) at A and along the path to B.
        patch: its contact patch at A measured with it alone (`planner.model.Patch`).
        path: (m, n) its joints at every waypoint of the path from A to B, following alone.
        clashes: how many of the two end grasps (the initial at A, the final at B) it
            overlaps another finger of (`_clashes`).
    """

    finger: str
    source: str
    p_obj: np.ndarray
    link: str
    q_a: np.ndarray
    margin: float
    patch: object = None
    path: np.ndarray | None = None
    clashes: int = 0


def _single(grasp, finger: str):
    """``grasp``'s spec with only ``finger`` holding (its joints as measured)."""
    fingers = tuple(fs if fs.name == finger else FingerSpec(fs.name, "free") for fs in grasp.spec.fingers)
    return replace(grasp.spec, fingers=fingers, palm="free")


def finger_choices(initial, final, finger: str, *, samples: int = SAMPLES, keep: int = KEEP, seed: int = 0,
                   tried: dict | None = None) -> list[FingerChoice]:
    """Up to ``keep`` contacts of ``finger`` it touches at the initial grasp's pose (A) and keeps
    alone along the straight object path to the final grasp's (B), joints at least `MARGIN_RAD`
    off their limits throughout: the initial grasp's own contact, the final grasp's (followed
    from B back to A), then seeded surface samples placed at A (`place_contact`), the largest
    margin first. ``tried`` (optional) counts why candidates were dropped."""
    hand = initial.hand
    Ta, Tb = np.asarray(initial.obj.T_palm_obj, float), np.asarray(final.obj.T_palm_obj, float)
    path = object_path(Ta, Tb)
    twist = float(initial.friction.gamma) > 0.0
    counts = tried if tried is not None else {}

    def note(why):
        counts[why] = counts.get(why, 0) + 1

    out: list[FingerChoice] = []
    h = _holds(initial).get(finger)
    if h:
        qs: list = []
        k, why, _, m = follow_alone(hand, initial.obj, finger, initial.q, h, path, twist, qs)
        if k == len(path) - 1 and m >= MARGIN_RAD:
            out.append(FingerChoice(finger, "initial", np.asarray(h[0][2], float), h[0][0],
                                    np.asarray(initial.finger_q[finger], float), m, initial.patches.get(finger),
                                    np.array(qs), _clashes(final, finger, qs[-1])))
        else:
            note(f"own contact: {why or 'joint margin'}")
    h = _holds(final).get(finger)
    if h:
        qs = []
        k, why, q, m = follow_alone(hand, final.obj, finger, final.q, h, path[::-1], twist, qs)
        qa = np.array(hand.q_open, dtype=float)
        qa[list(hand.fingers[finger].q_index)] = q[list(hand.fingers[finger].q_index)]
        patch = measure(_single(initial, finger), hand, qa).patches.get(finger) if k == len(path) - 1 else None
        if k == len(path) - 1 and m >= MARGIN_RAD and patch is not None:
            out.append(FingerChoice(finger, "final", np.asarray(h[0][2], float), h[0][0],
                                    q[list(hand.fingers[finger].q_index)].copy(), m, patch, np.array(qs[::-1]),
                                    _clashes(initial, finger, q[list(hand.fingers[finger].q_index)])))
        else:
            note(f"own contact: {why or 'joint margin'}")
    objA = initial.obj
    rng = np.random.default_rng([int(seed), list(hand.fingers).index(finger)])
    sampled = []
    idx = list(hand.fingers[finger].q_index)
    postures = touching_postures(hand, finger, objA, rng, int(samples))
    if not postures:
        note("no sampled posture closes onto the object at A")
    for q in postures:
        if joint_margin(hand, finger, q) < MARGIN_RAD:
            note("at a joint limit at A")
            continue
        g1 = measure(_single(initial, finger), hand, q)
        h = _holds(g1).get(finger)
        if not h or any(d > PENETRATION_TOL_M for _, _, d in g1.collisions):
            note("not touching or colliding at A")
            continue
        if any(np.linalg.norm(h[0][2] - c.p_obj) < DISTINCT_M for c in out + sampled):
            note("a contact already kept")
            continue
        qs = []
        k, why, _, m = follow_alone(hand, objA, finger, q, h, path, twist, qs)
        if k < len(path) - 1:
            note(f"cannot follow to B ({why})")
            continue
        if m < MARGIN_RAD:
            note("at a joint limit along the path")
            continue
        sampled.append(FingerChoice(finger, "sampled", np.asarray(h[0][2], float), h[0][0], q[idx].copy(), m,
                                    g1.patches[finger], np.array(qs),
                                    _clashes(initial, finger, q[idx]) + _clashes(final, finger, qs[-1])))
    sampled.sort(key=lambda c: (c.clashes, -c.margin))
    return (out + sampled)[:keep]


def _clashes(grasp, finger: str, q_finger) -> int:
    """1 when ``finger`` at ``q_finger`` overlaps another finger or the palm as they are in
    ``grasp`` (the gaits there would have to move them out of its way first), else 0."""
    from planner.contacts import collisions

    q = np.array(grasp.q, dtype=float)
    q[list(grasp.hand.fingers[finger].q_index)] = q_finger
    return int(any(d > PENETRATION_TOL_M for _, _, d in collisions(grasp.hand, q, None, fingers=[finger])))


@dataclass(frozen=True)
class Intermediate:
    """An intermediate grasp and its reposing move: ``grasp`` at pose A, ``move`` to pose B
    (``move.end`` the grasp there), ``choices`` its fingers' contacts."""

    grasp: object
    move: Reposing
    choices: tuple[FingerChoice, ...]

    def words(self) -> str:
        return ", ".join(f"{c.finger} ({c.source})" for c in self.choices)


def _combos(hand, choices: dict[str, list[FingerChoice]], thumb: str | None, friction, model: str, scan: int):
    """Combinations (one choice per finger, at least two fingers, the thumb in every one when
    it has a choice) that are force closure with the fingers' patches measured alone, the
    fewest fingers in the way of the end grasps' (`FingerChoice.clashes`) first, then the
    largest closure metric; at most ``scan`` combinations looked at (the fewest sampled
    contacts first: a finger keeping an end grasp's contact needs no gait there, then more
    fingers), each pair of its fingers clear of each other. Closure is under the plan's contact
    model ``model``. Returns (combinations, how many looked at)."""
    from planner.closure import apply_contact_model, grasp_closure
    from planner.contacts import collisions

    clash: dict = {}

    def clear(a: FingerChoice, b: FingerChoice) -> bool:
        """The two fingers clear of each other at every waypoint, each following alone."""
        key = (id(a), id(b))
        if key not in clash:
            q = np.array(hand.q_open, dtype=float)
            clash[key] = False
            for qa, qb in zip(a.path, b.path):
                q[list(hand.fingers[a.finger].q_index)] = qa
                q[list(hand.fingers[b.finger].q_index)] = qb
                if any(d > PENETRATION_TOL_M for _, _, d in collisions(hand, q, None, fingers=[a.finger, b.finger])):
                    clash[key] = True
                    break
        return not clash[key]

    fingers = [f for f, c in choices.items() if c]
    picks = []
    for r in range(len(fingers), 1, -1):
        for sub in itertools.combinations(fingers, r):
            if thumb is not None and choices.get(thumb) and thumb not in sub:
                continue
            picks.extend(itertools.product(*(choices[f] for f in sub)))
    picks.sort(key=lambda p: (sum(c.source == "sampled" for c in p), -len(p)))
    out = []
    for pick in picks[:scan]:
        if not all(clear(a, b) for a, b in itertools.combinations(pick, 2)):
            continue
        cl = grasp_closure(apply_contact_model({c.finger: c.patch for c in pick}, model), friction)
        if cl.is_force_closure:
            out.append((sum(c.clashes for c in pick), -float(cl.metric), pick))
    out.sort(key=lambda mp: mp[:2])
    return [p for _, _, p in out], min(scan, len(picks))


def intermediate_grasps(initial, final, options, *, samples: int = SAMPLES, keep: int = KEEP,
                        combos: int = COMBOS, grasps: int = GRASPS) -> tuple[list[Intermediate], str]:
    """Up to ``grasps`` intermediate grasps (module docstring), each a valid state at A whose
    reposing move to B passes (`planner.repose.repose`); and a sentence on what was tried."""
    hand = initial.hand
    Tb = np.asarray(final.obj.T_palm_obj, float)

    def one(f: str) -> tuple:
        tried: dict = {}
        return finger_choices(initial, final, f, samples=samples, keep=keep, seed=options.seed, tried=tried), tried

    # each finger's contacts are sampled and followed on their own (seeded per finger): half the
    # fingers in a forked copy when there are two cores (`planner.helper.fork_map`)
    counts: dict[str, dict] = {}
    choices = {}
    fingers = list(hand.fingers)
    for f, (c, tried) in zip(fingers, fork_map(one, fingers, options.workers or cores())):
        choices[f], counts[f] = c, tried
    thumb = "thumb" if "thumb" in hand.fingers else None
    have = ", ".join(f"{f} {len(c)}" for f, c in choices.items())
    if thumb is not None and not choices[thumb]:
        why = "; ".join(f"{k} {v}" for k, v in sorted(counts[thumb].items(), key=lambda kv: -kv[1]))
        return [], (f"no thumb contact follows the object from A to B ({samples} points sampled: {why})")
    out, reasons = [], {}
    todo, scanned = _combos(hand, choices, thumb, initial.friction, options.contact_model, SCAN)

    def measured_at_a(pick):
        q = np.array(hand.q_open, dtype=float)
        for c in pick:
            q[list(hand.fingers[c.finger].q_index)] = c.q_a
        chosen = {c.finger: c for c in pick}
        spec = replace(initial.spec, fingers=tuple(
            FingerSpec(fs.name, "contact", point_obj=tuple(float(v) for v in chosen[fs.name].p_obj),
                       link=chosen[fs.name].link) if fs.name in chosen else FingerSpec(fs.name, "free")
            for fs in initial.spec.fingers), name=f"{initial.spec.name} (intermediate)", path="")
        return measure(spec, hand, q)

    def judged(pick) -> tuple:
        """(why the pick is no intermediate grasp or None, its grasp at A, its move to B)."""
        g = measured_at_a(pick)
        if g.missing:
            return "a finger misses the object at A", None, None
        if any(d > PENETRATION_TOL_M for _, _, d in g.collisions):
            return "fingers collide at A", None, None
        why = state_reason(g, options)
        if why is not None:
            return why, None, None
        try:
            return None, g, repose(g, Tb, options)
        except MotionError as err:
            return "reposing: " + _short(str(err)), None, None

    def taken(pick) -> bool:  # one grasp per thumb contact: the thumb's gait is what the gaits must make
        return any(c is x for it in out for x in it.choices for c in pick if c.finger == thumb)

    # the picks in order, judged a few at a time, half of them in a forked copy when there are
    # two cores (only the reason comes back: a pick that passes is judged again here, its grasp
    # and move being this process's); the picks are used in order as one at a time would use
    # them (a pick judged beyond the last one needed, or whose thumb contact a pick before it in
    # the batch took, counts for nothing), so the grasps and words are the same either way
    procs = options.workers or cores()
    measured, i = 0, 0
    while i < len(todo) and measured < combos and len(out) < grasps:
        batch = []
        while i < len(todo) and len(batch) < min(2 * procs, combos - measured):
            if not taken(todo[i]):
                batch.append(todo[i])
            i += 1
        if not batch:
            continue
        here: dict = {}  # the picks judged in this process: kept whole

        def judge(k: int):
            here[k] = judged(batch[k])
            return here[k][0]

        whys = fork_map(judge, range(len(batch)), procs)
        for k, pick in enumerate(batch):
            if measured >= combos or len(out) >= grasps:
                break
            if taken(pick):
                continue
            measured += 1
            why, g, move = here[k] if k in here else (whys[k], None, None) if whys[k] is not None else judged(pick)
            if why is None:
                out.append(Intermediate(g, move, pick))
            else:
                reasons[why] = reasons.get(why, 0) + 1
    words = (f"intermediate grasps: contacts that follow the object ({have} per finger), {len(todo)} of "
             f"{scanned} combinations clear and force closure, {measured} measured, {len(out)} reposed from A to B")
    if reasons:
        words += " (the others: " + "; ".join(f"{n} x {w}" for w, n in sorted(reasons.items(), key=lambda kv: -kv[1])[:3]) + ")"
    return out, words


def _short(text: str) -> str:
    import re

    t = re.sub(r"\(waypoint \d+/\d+\)", "", text)
    t = re.sub(r"[-+]?\d+\.\d+", "#", t)
    return t.split("; ")[0][:120]
