"""Why no finger-gaiting sequence exists: the failure analysis of a grasp-state graph.

`failure_analysis` finds what stops the graph's start from reaching its goal (fingers
that cannot be lifted, refused landings, the closest state reached, the fingers worth
giving intermediate contacts); `explain_failure` says it in words, as the
`planner.errors.NoSequenceError` the CLI prints. The ``*_words`` helpers name states,
moves and refusals.

Pure networkx, like `planner.graph`.
"""

from __future__ import annotations

import re

import networkx as nx

from planner.closure import grasp_closure
from planner.errors import NoSequenceError, PlannerError
from planner.graph import LIFTED, Evaluator, GaitProblem, Node
from planner.model import PALM


def _slot_words(problem: GaitProblem, finger: str, s: int) -> str:
    if s == LIFTED:
        return "lifted"
    label = problem.slots[finger][s].label
    return {"initial": "its initial contact", "final": "its final contact"}.get(label, f"intermediate contact {label}")


def _state_words(problem: GaitProblem, node: Node) -> str:
    """'thumb initial, index final, middle lifted' (fingers free in both grasps left out)."""
    labels = problem.labels(node)
    keep = [f for i, f in enumerate(problem.fingers) if not (problem.start[i] == problem.goal[i] == node[i] == LIFTED)]
    return ", ".join(f"{f} {labels[f]}" for f in keep)


def _move_words(problem: GaitProblem, u: Node, v: Node) -> str:
    i = next(j for j in range(len(u)) if u[j] != v[j])
    f = problem.fingers[i]
    return f"lift {f}" if v[i] == LIFTED else f"land {f} on {_slot_words(problem, f, v[i])}"


def _reason_words(ev: Evaluator, finger: str, action: str, w: Node, reason: str) -> str:
    """A refused move in words: what goes wrong in the state it would lead to."""
    pair = ev.collision_pair(w) if reason.startswith("fingers collide") else None
    if pair is not None:
        other = pair[1] if pair[0] == finger else pair[0] if pair[1] == finger else None
        if other is not None:
            return f"it would collide with {other}" + (" (in its open posture)" if w[ev.problem.fingers.index(other)] == LIFTED else "")
        return f"{pair[0]} and {pair[1]} would collide"
    if reason == "not force closure":
        c = ev.closure.get(w)
        metric = f", metric {c.metric:.3g}" if c is not None else ""
        rest = ", ".join(f for f in ev.problem.patches(w)) or "no finger"  # the palm too, when it holds
        return f"{'without it' if action == 'lift' else 'with it'} the grasp ({rest}) is not force closure{metric}"
    return reason


def _palm_remedy(ev: Evaluator, finger: str, w: Node) -> tuple[str, bool]:
    """Whether palm support would let ``finger`` lift into state ``w`` (its contacts cannot
    hold the object): (the clause, True when it would); ("", False) when the palm holds
    already or the hand has no palm."""
    p = ev.problem
    if p.support or p.palm_hint is None:
        return "", False
    patch, gap = p.palm_hint
    patches = {**p.patches(w), PALM: patch}
    try:
        fc = grasp_closure(patches, p.friction).is_force_closure
        holds = fc and (not p.all_loads() or p.load_refusal(patches, p.statics(w)) is None)
    except PlannerError:
        return "", False
    where = f"it is {gap * 1e3:.1f} mm from it" if gap > 0 else "it touches it"
    if holds:
        return (f"; resting the object on the palm would likely let {finger} lift ({where}; with the palm's contact "
                f"added where the object is nearest it and the fingers' contacts kept, the rest holds: place the "
                f"object against the palm and write palm: hold)"), True
    return f"; palm support would not let it lift either ({where})", False


def _cannot_hold(reason: str) -> bool:
    """A state refused because its contacts cannot hold the object (not force closure, or
    over the grip force budget), not because fingers collide or too many are lifted."""
    return reason == "not force closure" or reason.startswith("need over") or "its weight" in reason


def _taken_out(G: nx.DiGraph) -> dict[tuple[Node, Node], str]:
    """The moves taken out after the search found them -> why: "failed later" (the graph's
    ``removed_moves``: no finger path, or the simulator rejected the sequence at it) or
    "rejected state" (``removed_with_state``: a move into a state the simulator rejected
    reached by another move, taken out with it, `planner.gait_search.LazyGraph.remove_state`)
    or "stuck contact" (``removed_stuck``: a lift off or a landing on a contact the finger
    cannot back off, taken out untried when a move with it failed,
    `planner.gait_search.LazyGraph.forbid`)."""
    out = {m: "rejected state" for m in G.graph.get("removed_with_state", ())}
    out.update((m, "stuck contact") for m in G.graph.get("removed_stuck", ()))
    out.update((m, "failed later") for m in G.graph.get("removed_moves", ()))
    return out


#: How a move taken out after the search found it is said, per `_taken_out` cause (in the
#: order said): after a finger's lift ("its lift ... was taken out <words>"), and as the head of
#: a list of such moves.
_TAKEN_WORDS = {
    "failed later": "after failing later",
    "rejected state": "with the state it leads to, which the simulator rejected (reached by another move)",
    "stuck contact": "untried: the finger cannot back off that contact (its lift or landing there failed)",
}
_TAKEN_HEADS = {
    "failed later": "taken out after failing later",
    "rejected state": "taken out with a state the simulator rejected (reached by another move)",
    "stuck contact": "taken out untried, a contact the finger cannot back off",
}


def failure_analysis(G: nx.DiGraph) -> dict:
    """What stops the graph's start from reaching its goal (for `explain_failure` and for
    choosing the fingers that get intermediate contacts).

    Returns a dict: ``closest`` (the reached state fewest fingers from the goal, best metric
    first), ``partial`` (the fewest-move path to it), ``lift_blocked`` (finger that has to
    move -> (state, why) for a finger never lifted in any reached state where it touches),
    ``unheld`` (those of them refused because the other fingers cannot hold the object
    without them), ``landing_blocked`` (finger -> {why: count of states} for refused
    landings on the final contact), ``stuck`` ((finger, action, why) of each refused next
    move from the closest state), ``blockers`` (fingers worth giving intermediate contacts, most implicated
    first), ``needs`` ((finger, state) pairs: a new contact of that finger would help if,
    added to the state, where it is lifted, it made a valid grasp: the other fingers when a
    lift leaves a state that cannot hold the object (not force closure, or over the grip
    force budget), the finger in the way of a landing),
    ``goal_reason`` (why the final grasp itself is invalid, or None), ``palm_helps`` (fingers
    that resting the object on the palm would let lift, `_palm_remedy`), ``lift_taken``
    (finger -> [(state, cause)] for a finger of ``lift_blocked`` whose lift from those reached
    states was taken out afterwards, `_taken_out`: refused in some states, taken out in others).
    A finger with a lift taken out adds no ``needs``, ``unheld`` nor blocker score for its
    refused lifts (the search's choice of new contacts: its lift was possible somewhere).
    """
    p: GaitProblem = G.graph["problem"]
    ev: Evaluator = G.graph["evaluator"]
    start, goal = G.graph["start"], G.graph["goal"]
    reach = nx.descendants(G, start) | {start}
    dist = {v: sum(a != b for a, b in zip(v, goal)) for v in reach}
    closest = min(reach, key=lambda v: (dist[v], -G.nodes[v]["metric"], v))
    partial = nx.shortest_path(G, start, closest)
    moves = [m for m in G.graph.get("blocked_moves", []) if m[0] in reach]
    on_partial = {v: k for k, v in enumerate(partial)}
    lift_blocked, landing_blocked, score = {}, {}, {f: 0 for f in p.fingers}
    needs: list[tuple[str, Node]] = []
    unheld: list[str] = []
    palm_helps: list[str] = []  # fingers that resting the object on the palm would let lift
    lift_taken: dict[str, list[tuple[Node, str]]] = {}
    taken_out = _taken_out(G)

    def need_holders(w: Node, lifted: str) -> None:
        """Lifting ``lifted`` left ``w`` unable to hold the object: another finger could help by a
        new contact: a lifted one added to ``w``, a touching one moved within ``w``."""
        for j, g in enumerate(p.fingers):
            if g != lifted:
                needs.append((g, w[:j] + (LIFTED,) + w[j + 1:]))

    def need_room(f: str, w: Node) -> None:
        """Landing ``f`` gives ``w``, where it collides: the finger in the way could move."""
        for g in ev.collision_pair(w) or ():
            if g != f:
                j = p.fingers.index(g)
                if w[j] != LIFTED:
                    needs.append((g, w[:j] + (LIFTED,) + w[j + 1:]))

    for i, f in enumerate(p.fingers):
        if p.start[i] == p.goal[i]:
            continue
        touching = [v for v in reach if v[i] != LIFTED]
        # its lifts taken out after they were found (failed later, into a rejected state): not
        # refused there, said apart from the refusals elsewhere
        taken = [(u, cause) for (u, v), cause in taken_out.items() if u in reach and u[i] != LIFTED and v[i] == LIFTED]
        if touching and not any(G.has_edge(v, v[:i] + (LIFTED,) + v[i + 1:]) for v in touching):
            tried = [m for m in moves if m[1] == i and m[2] == "lift"]
            if tried:  # the refused lift nearest the end of the best partial sequence
                u, _, _, w = max(tried, key=lambda m: (on_partial.get(m[0], -1), -dist[m[0]]))
                remedy, helps = _palm_remedy(ev, f, w) if _cannot_hold(G.graph["blocked"][w]) else ("", False)
                lift_blocked[f] = (u, _reason_words(ev, f, "lift", w, G.graph["blocked"][w]) + remedy)
                if helps:
                    palm_helps.append(f)
                if taken:
                    lift_taken[f] = taken
                else:
                    score[f] += 3
                    if _cannot_hold(G.graph["blocked"][w]):
                        need_holders(w, f)
                    if any(_cannot_hold(G.graph["blocked"][m[3]]) for m in tried):
                        unheld.append(f)
        if p.goal[i] != LIFTED:
            why: dict[str, int] = {}
            for u, j, action, w in moves:
                if j == i and action == "land" and w[i] == p.goal[i]:
                    text = _reason_words(ev, f, "land", w, G.graph["blocked"][w])
                    why[text] = why.get(text, 0) + 1
                    if why[text] <= 2:
                        need_room(f, w)
                    pair = ev.collision_pair(w)
                    for g in pair or ():
                        if g != f:
                            score[g] += 2
            if why and not any(v[i] == p.goal[i] for v in reach):
                landing_blocked[f] = dict(sorted(why.items(), key=lambda kv: (-kv[1], kv[0])))
                score[f] += 1
        if closest[i] != goal[i]:
            score[f] += 1
    # the next move of every finger not yet at its final slot, from the closest state
    stuck = []
    for i, f in enumerate(p.fingers):
        if closest[i] == goal[i]:
            continue
        action = "lift" if closest[i] != LIFTED else "land"
        w = closest[:i] + ((LIFTED,) if action == "lift" else (goal[i],)) + closest[i + 1:]
        if w in G.graph["blocked"]:
            remedy, helps = (_palm_remedy(ev, f, w) if action == "lift" and _cannot_hold(G.graph["blocked"][w])
                             else ("", False))
            stuck.append((f, action, _reason_words(ev, f, action, w, G.graph["blocked"][w]) + remedy))
            if helps:
                palm_helps.append(f)
            if _cannot_hold(G.graph["blocked"][w]) and action == "lift":
                need_holders(w, f)
            need_room(f, w)
            for g in ev.collision_pair(w) or ():
                score[g] += 2 if g != f else 0
            if action == "lift":
                score[f] += 2
    goal_reason = None
    if goal in ev.closure or goal in G.graph["blocked"]:
        goal_reason = G.graph["blocked"].get(goal) or ev.blocked_reason(goal)
    blockers = [f for f in sorted(p.fingers, key=lambda f: (-score[f], p.fingers.index(f))) if score[f] > 0]
    return {"reach": reach, "closest": closest, "partial": partial, "lift_blocked": lift_blocked, "unheld": unheld,
            "landing_blocked": landing_blocked,
            "stuck": stuck, "needs": list(dict.fromkeys(needs)),
            "blockers": blockers, "goal_reason": goal_reason, "distance": dist[closest], "palm_helps": palm_helps,
            "lift_taken": lift_taken}


def _states_words(problem: GaitProblem, states: list[Node]) -> str:
    """'in the initial grasp', 'in the state (thumb initial, ...)', 'in 3 states (e.g. ...)',
    'in the initial grasp and 2 other states (e.g. ...)'."""
    others = [v for v in dict.fromkeys(states) if v != problem.start]
    if not others:
        return "in the initial grasp"
    eg = _state_words(problem, others[0])
    if len(others) < len(set(states)):
        return f"in the initial grasp and {len(others)} other state{'s' if len(others) > 1 else ''} (e.g. {eg})"
    return f"in the state ({eg})" if len(others) == 1 else f"in {len(others)} states (e.g. {eg})"


def _names(fingers: list[str]) -> str:
    """'thumb', 'index and ring', 'index, middle and ring'."""
    return fingers[0] if len(fingers) == 1 else f"{', '.join(fingers[:-1])} and {fingers[-1]}"


def _next_move(a: dict) -> str:
    """What the user can do next, from the analysis: palm support, more fingers lifted at once,
    room for a landing, or new contacts for the finger that most blocks progress."""
    whys = [why for _, why in a["lift_blocked"].values()] + [why for _, _, why in a["stuck"]]
    if a["palm_helps"]:
        return "to go on: rest the object on the palm (palm: hold), which lets a blocked finger lift"
    for f, why in a["landing_blocked"].items():
        m = re.match(r"it would collide with (\w+)", next(iter(why)))
        if m:
            return (f"to go on: {f}'s final contact collides with {m.group(1)}, which must move first: new contacts "
                    f"for {m.group(1)} (--max-rounds N or --intermediate N)")
    if any(why == "too many fingers lifted" for why in whys):
        return "to go on: allow more fingers off the object at once (--max-lifted N)"
    if not a["blockers"]:
        return ""
    f, others = a["blockers"][0], a["blockers"][1:3]
    also = f" (then {_names(others)})" if others else ""
    return f"to go on: new contacts for {f}{also} are the most likely to open a sequence (--max-rounds N or --intermediate N)"


def explain_failure(G: nx.DiGraph, intermediate_tried: bool, tried: str | None = None) -> NoSequenceError:
    """Why no sequence connects start and goal, in words: the error the CLI prints.

    Says whether the final grasp itself is invalid, which finger that has to move cannot be
    lifted in any reached state and why (the grasp without it is not force closure, with its
    metric, or it would collide with a named finger), which landings on the final contacts
    are refused and why, the best partial sequence and where it ends, and what was tried
    (``tried``: a sentence from the caller, e.g. the rounds of intermediate contacts).
    Moves the search found and that were taken out afterwards are named as such, not as moves
    the search did not reach: as failed later those that failed themselves (the graph's
    ``removed_moves``: no finger path, or the simulator rejected the sequence at them; the
    caller says why), apart the other moves into a state the simulator rejected
    (``removed_with_state``). A finger whose lift was refused in some states and taken out in
    others is said to be both, each with its states (the refusal with its reason).
    Fingers free in both grasps are never mentioned.
    """
    p: GaitProblem = G.graph["problem"]
    a = failure_analysis(G)
    lines = []
    if a["goal_reason"]:
        lines.append(f"the final grasp itself is not a valid state ({a['goal_reason']})")
    merged: dict[tuple[str, str], list[str]] = {}  # the same clause for several fingers is said once
    for f, (u, why) in a["lift_blocked"].items():
        other = "other " if f in a["lift_taken"] else ""  # (its lift in some states was taken out: said below)
        where = "the initial grasp" if u == p.start else f"any {other}reached state (e.g. {_state_words(p, u)})"
        merged.setdefault((where, why), []).append(f)
    for (where, why), fingers in merged.items():
        lines.append(f"{_names(fingers)} cannot be lifted in {where}: {why}")
    for f, taken in a["lift_taken"].items():
        for cause, words in _TAKEN_WORDS.items():
            states = [u for u, c in taken if c == cause]
            if states:
                lines.append(f"{f}'s lift {_states_words(p, states)} was taken out {words}")
    landing: dict[str, list[str]] = {}
    for f, why in a["landing_blocked"].items():
        parts = [text + (f" ({n} states)" if n > 1 else "") for text, n in why.items()]
        landing.setdefault("; ".join(parts), []).append(f)
    for why, fingers in landing.items():
        lines.append(f"{_names(fingers)} cannot land on {'its' if len(fingers) == 1 else 'their'} final contact: {why}")
    # moves of reached states taken out after they failed later (finger paths, the simulator),
    # or with a state the simulator rejected; the lifts said with a finger's refusals above left out
    taken_out = _taken_out(G)
    for cause, head in _TAKEN_HEADS.items():
        said = list(dict.fromkeys(
            _move_words(p, u, v) + (" in the initial grasp" if u == p.start else "")
            for (u, v), c in taken_out.items() if c == cause and u in a["reach"]
            and not any(p.fingers[i] in a["lift_taken"] and v[i] == LIFTED != u[i] for i in range(len(u)))))
        if said:
            lines.append(f"{head}: " + ", ".join(said[:3]) + (f" and {len(said) - 3} more" if len(said) > 3 else ""))
    steps = [_move_words(p, u, v) for u, v in zip(a["partial"], a["partial"][1:])]
    lines.append(f"best partial sequence ({len(steps)} moves{': ' + ', '.join(steps) if steps else ''}) ends "
                 f"{a['distance']} finger(s) from the final grasp in: {_state_words(p, a['closest'])}")
    stuck: dict[tuple[str, str], list[str]] = {}
    for f, action, why in a["stuck"]:
        if f not in a["lift_blocked"] and f not in a["landing_blocked"]:
            stuck.setdefault((action, why), []).append(f)
    for (action, why), fingers in stuck.items():
        move = "be lifted" if action == "lift" else f"land on {'its' if len(fingers) == 1 else 'their'} final contact"
        lines.append(f"there {_names(fingers)} cannot {move}: {why}")
    if not (a["lift_blocked"] or a["landing_blocked"] or a["stuck"] or a["goal_reason"]):
        # nothing was refused: the search stopped before it tried the moves that remain
        left = [(i, f) for i, f in enumerate(p.fingers) if a["closest"][i] != G.graph["goal"][i]]
        # a finger is said to have lost its moves only if a move taken out moved it
        gone = [f for i, f in left if any(u[i] != v[i] for u, v in taken_out if u in a["reach"])]
        rest = [f for _, f in left if f not in gone]
        if gone:
            one = len(gone) == 1
            lines.append(f"{', '.join(gone)} still {'has' if one else 'have'} to move: the moves the search found "
                         f"for {'it' if one else 'them'} were taken out (below), and it found no other")
        if rest:
            lines.append(f"{', '.join(rest)} still {'has' if len(rest) == 1 else 'have'} to move and no such move "
                         "was refused: the search stopped before it evaluated them (a longer --time-limit lets "
                         "it go on)")
    if tried:
        lines.append(tried)
    elif not intermediate_tried:
        lines.append("no intermediate contacts were tried (give --intermediate N or a --time-limit)")
    else:
        lines.append("intermediate contacts were tried")
    act = _next_move(a)
    if act:
        lines.append(act)
    reasons: dict[str, int] = {}
    for r in G.graph["blocked"].values():
        reasons[r] = reasons.get(r, 0) + 1
    report = {
        "never_removable": sorted(a["lift_blocked"]),
        "lift_blocked": {f: why for f, (_, why) in a["lift_blocked"].items()},
        "landing_blocked": a["landing_blocked"],
        "closest": p.labels(a["closest"]),
        "stuck": [{"finger": f, "action": action, "why": why} for f, action, why in a["stuck"]],
        "partial": [p.labels(v) for v in a["partial"]],
        "blocked": reasons,
        "blockers": a["blockers"],
        "intermediate_tried": intermediate_tried,
    }
    return NoSequenceError("no finger-gaiting sequence: " + "; ".join(lines), report=report)
