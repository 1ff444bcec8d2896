"""The failure explanation (`planner.explain`) when moves were taken out after the search
found them: a lift refused in some states and taken out in others is said both ways, and
only the moves that failed themselves are said to have failed later."""

import pytest

from planner.closure import grasp_closure
from planner.errors import NoSequenceError
from planner.explain import explain_failure
from planner.gait_search import LazyGraph
from planner.graph import LIFTED
from tests.test_graph import FRICTION, problem, slot


def test_a_lift_refused_in_the_initial_grasp_and_taken_out_elsewhere_is_said_both_ways():
    """L sits opposite A: without it A, C and D hold nothing in the initial grasp (refused:
    not force closure); once D lands opposite A too, L may lift, and that lift is taken out
    (it failed later) wherever the search finds it. The explanation gives the refusal with
    its reason where it was refused and names the states where the lift was taken out, not
    one folded into a reasonless "there L cannot be lifted"."""
    slots = {"A": [slot("A", "initial", "+x")],
             "L": [slot("L", "initial", "-x"), slot("L", "final", "-x", tilt_deg=20)],
             "C": [slot("C", "initial", "+y")],
             "D": [slot("D", "initial", "+z"), slot("D", "int0", "-x", tilt_deg=-8)]}
    prob = problem(slots, dict(A=0, L=0, C=0, D=0), dict(A=0, L=1, C=0, D=0))
    assert not grasp_closure(prob.patches((0, LIFTED, 0, 0)), FRICTION).is_force_closure
    assert grasp_closure(prob.patches((0, LIFTED, 0, 1)), FRICTION).is_force_closure
    lazy, taken = LazyGraph(prob), []
    for _ in range(10):
        found = lazy.best(1)
        if not found:
            break
        s = found[0]
        k = s.order(prob).index("L:lift")
        lazy.remove_edge(s.nodes[k], s.nodes[k + 1])
        taken.append(s.nodes[k])
    assert len(taken) == 2 and all(u[3] == 1 for u in taken) and lazy.best(1) == []
    err = explain_failure(lazy.G, intermediate_tried=True)
    text = str(err)
    assert "L cannot be lifted in the initial grasp: without it the grasp (A, C, D) is not force closure" in text
    assert "L's lift in 2 states (e.g. A initial, L initial, C initial, D int0) was taken out after failing later" \
        in text
    assert "there L cannot be lifted" not in text and "lift L" not in text  # (said once, with its states)
    assert err.report["never_removable"] == ["L"]


def test_only_the_moves_that_failed_in_the_simulator_are_said_to_have_failed_later(monkeypatch):
    """Every replay fails at the state its first step reaches (a stand-in simulator): each
    rejected sequence takes out the move it failed at, and the other moves into that state go
    with it. Only the former are "taken out after failing later" (as many as sequences were
    rejected); the latter are named as taken out with a state the simulator rejected. Little,
    whose lift collides with ring in the initial grasp and whose lift with ring lifted was
    taken out, is said to be refused there (with the reason) and taken out here."""
    import planner.regrasp as regrasp
    import planner.sim.verify as verify
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.resources import bundled_grasp

    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))

    def at_first_state(plan, hand, directions, workers=None, meanwhile=None):
        if meanwhile is not None:  # (the physics check, run while the replays run)
            meanwhile()
        return verify.Verification(False, tuple((n, False, "FAIL: made up", 1, True, 9.0, 9.0)
                                                for n, _ in directions), 0.0)

    search, graphs = regrasp.anytime_search, []

    def kept(*args, **kw):
        lazy, info = search(*args, **kw)
        graphs.append(lazy.G)
        return lazy, info

    monkeypatch.setattr(verify, "verify_plan", at_first_state)
    monkeypatch.setattr(regrasp, "anytime_search", kept)
    with pytest.raises(NoSequenceError) as err:
        regrasp.plan_regrasp(a, b, PlanOptions.for_execution(motion=False, verify_attempts=100, repose=False))
    # the plan's last search graph (not the final grasp's one-state one: replayed alone once all failed)
    text, G = str(err.value), [g for g in graphs if "removed_moves" in g.graph][-1]
    rejected = int(text.split("sequences that failed in the simulator (")[1].split(")")[0])
    failed, with_state = G.graph["removed_moves"], G.graph["removed_with_state"]
    assert rejected > 1 and len(failed) == len(set(failed)) == rejected  # one move per rejected sequence
    assert with_state and not set(with_state) & set(failed)
    assert "taken out with a state the simulator rejected (reached by another move): " in text
    assert "little cannot be lifted in the initial grasp: it would collide with ring" in text
    assert "little's lift in the state (thumb initial, index initial, middle initial, ring lifted, little initial) " \
           "was taken out after failing later" in text
    assert "there little cannot be lifted" not in text


def test_moves_dropped_untried_with_a_stuck_contact_are_not_said_to_have_failed():
    """A move lifting L off its initial contact fails (its finger path), and that contact is
    one L cannot back off (`LazyGraph.forbid`): every other lift off it, never tried, goes too.
    Only the move that failed is "taken out after failing later"; the others (and the landings
    back on it) are named as taken out untried with a contact the finger cannot back off, and
    the graph records them apart."""
    slots = {"A": [slot("A", "initial", "+x")],
             "L": [slot("L", "initial", "-x"), slot("L", "final", "-x", tilt_deg=20)],
             "C": [slot("C", "initial", "+y")],
             "D": [slot("D", "initial", "+z"), slot("D", "int0", "-x", tilt_deg=-8)]}
    prob = problem(slots, dict(A=0, L=0, C=0, D=0), dict(A=0, L=1, C=0, D=0))
    lazy = LazyGraph(prob)
    s = lazy.best(1)[0]
    k = s.order(prob).index("L:lift")
    failed = (s.nodes[k], s.nodes[k + 1])
    lifts_before = [(u, v) for u, v in lazy.G.edges if u[1] == 0 and v[1] == LIFTED or u[1] == LIFTED and v[1] == 0]
    assert failed in lifts_before and len(lifts_before) >= 2  # (lifts off L's initial contact, landings on it)
    lazy.remove_edge(*failed)
    lazy.forbid(1, 0)
    assert lazy.G.graph["removed_moves"] == [failed]
    assert set(lazy.G.graph["removed_stuck"]) == set(lifts_before) - {failed}
    assert lazy.best(1) == []
    text = str(explain_failure(lazy.G, intermediate_tried=True))
    assert "after failing later" in text and "cannot back off" in text
    assert text.count("after failing later") == 1
