"""The replay film's caption of a reposing step (`planner.sim.film.ReplayRecorder._doing`): the
palm's load handed to the fingers before the object moves, the fingers re-posturing while it
rests on the palm, the object moved, the palm taking its load back; it said "the fingers move
the object" or "dwell" for all of them."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

pytestmark = pytest.mark.needs_pybullet("planner.sim.film loads the pybullet renderer")


def _caption(palm_share: float, reposing: bool, palm_holds: bool, recorder=None):
    from planner.sim.film import ReplayRecorder

    rec = recorder or object.__new__(ReplayRecorder)
    if recorder is None:
        rec._phase, rec._moved = None, False
        rec.rd = SimpleNamespace(steps=[SimpleNamespace(action="repose", finger="all", from_state=0, to_state=1)])
        rec.g = (0.0, 0.0, 9.81)
    rec.sim = SimpleNamespace(phase="step 0 repose", reposing=reposing, palm_holds=palm_holds,
                              ctl=SimpleNamespace(palm_share=palm_share, moving=None, share={}))
    return rec, rec._doing()[0].split("): ", 1)[1]


def test_a_reposing_step_off_the_palm_and_back_is_captioned_as_it_happens():
    rec, words = _caption(1.0, True, True)
    assert words == "the fingers re-posture, the object on the palm"
    _, words = _caption(0.25, True, True, rec)
    assert words == "the fingers take the load off the palm (75%)"
    _, words = _caption(0.0, True, False, rec)
    assert words == "the fingers move the object"
    _, words = _caption(0.6, True, True, rec)
    assert words == "the palm takes its load back (60%)"
    _, words = _caption(0.6, False, True, rec)  # (the handover after the last waypoint)
    assert words == "the palm takes its load back (60%)"
    _, words = _caption(1.0, False, True, rec)
    assert words == "dwell at state 1"


def test_a_reposing_step_without_the_palm_is_the_fingers_moving_the_object():
    rec, words = _caption(1.0, True, False)  # (a palm that holds at neither end keeps its share 1)
    assert words == "the fingers move the object"
    _, words = _caption(1.0, False, False, rec)
    assert words == "dwell at state 1"
