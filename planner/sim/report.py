"""What a replay reports: one `StateReport` per plan state, the `ReplayReport` of a replay
and the `GravitySetReport` of replays under several gravity directions, each with its plain
(strict JSON) data for ``regrasp replay --report``.

`planner.sim.replay` fills them in; `planner.sim.verify` collects them per direction.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from planner.model import PALM


@dataclass(frozen=True)
class StateReport:
    """Simulated check of one plan state.

    Attributes:
        index: index into the plan's states.
        reached: False when the replay stopped (object dropped) before this state.
        time_s: simulated time at which the state was measured.
        planned_fingers: owners with contact patches in the plan: its touching fingers, and
            "palm" when the plan has the palm hold (`planner.model.PALM`).
        sim_fingers: fingers (or "palm") touching the object in the filtered sim contacts.
        planned_force_closure, planned_metric: the plan's closure of this state.
        sim_force_closure, sim_metric: closure recomputed from the filtered sim contacts
            (None when not reached).
        sim_points: number of filtered contact points used.
        drift_mm, drift_deg: object displacement and rotation since the start of the replay.
        sim_patches: finger (or "palm") -> (p_obj (n, 3), n_in_obj (n, 3)): the filtered sim
            contacts in the object frame, normals INTO the object.
        carried_n: finger (or "palm") -> mean normal force it pressed on the object with
            over the measurement window, N (the simulator's contact forces).
        contact_offset_mm: planned finger -> distance from its planned contact (the patch
            mean) to where the simulator has it touch (its filtered points' mean), object
            frame, mm (fingers touching in both only).
        carriers: the fingers (or "palm") that carry the object: a mean normal force of at
            least ``CARRY_SHARE`` of the larger of the object's weight and the squeeze. A state
            holds as planned (`holds_as_planned`) when no other link carries it and every
            planned finger touches.
    """

    index: int
    reached: bool
    time_s: float
    planned_fingers: tuple[str, ...]
    sim_fingers: tuple[str, ...]
    planned_force_closure: bool
    planned_metric: float
    sim_force_closure: bool | None
    sim_metric: float | None
    sim_points: int
    drift_mm: float
    drift_deg: float
    sim_patches: Mapping[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    carried_n: Mapping[str, float] = field(default_factory=dict)
    carriers: tuple[str, ...] = ()
    contact_offset_mm: Mapping[str, float] = field(default_factory=dict)

    @property
    def not_touching(self) -> tuple[str, ...]:
        """Planned fingers the simulator has off the object (a planned palm may be: it only
        pushes), sorted."""
        return tuple(sorted(set(self.planned_fingers) - {PALM} - set(self.sim_fingers)))

    @property
    def unplanned_carriers(self) -> tuple[str, ...]:
        """Carriers the plan does not hold with (the palm when the plan does not count it, a
        lifted finger), sorted."""
        return tuple(sorted(set(self.carriers) - set(self.planned_fingers)))

    @property
    def holds_as_planned(self) -> bool:
        """The object is held by the plan's contacts: nothing else carries it (not the palm
        unless the plan has it hold, not a finger the plan has lifted) and every planned
        finger touches it (a planned palm need not: it only pushes, and under a gravity that
        pulls the object off it the fingers hold alone, as the grip model has it)."""
        return self.reached and not self.unplanned_carriers and not self.not_touching


@dataclass(frozen=True)
class CouplingError:
    """How far the simulated hand broke one coupled joint (`planner.hand.Coupling`,
    ``q_f = m q_d + o``) over a replay.

    Attributes:
        joint, follows: the follower and its driver.
        max_error: the largest ``|q_f - (m q_d + o)|`` over every physics step, rad (m).
        tolerance: what a plan may show (`planner.hand.Hand.coupling_tolerances`: the follower
            angle that moves no point of its links by more than the IK's accepted error).
        step: the plan step during which the largest error happened (-1: at state 0, i.e.
            acquiring, the gravity ramp or settling).
        time_s: the simulated time of it, s.
    """

    joint: str
    follows: str
    max_error: float
    tolerance: float
    step: int
    time_s: float

    @property
    def within(self) -> bool:
        """The coupling held within its tolerance throughout."""
        return self.max_error <= self.tolerance


@dataclass(frozen=True)
class ReplayReport:
    """Outcome of `replay_plan`.

    Attributes:
        passed: no drop, the drift stayed within both thresholds at every step, every state
            was reached and the simulator's force closure agreed with the plan's at each.
        verdict: one line, e.g. "PASS: max drift 0.8 mm / 0.4 deg (limits 5 mm / 5 deg)".
        dropped: the object left the hand (moved more than ``drop_mm``).
        max_drift_mm, max_drift_deg: largest drift over every simulation step.
        final_drift_mm, final_drift_deg: drift at the end of the replay.
        drift_mm_max, drift_deg_max: the thresholds used.
        closure_agreement: states where sim and plan agree on force closure / states reached.
        states: one `StateReport` per plan state, in plan order.
        sim_time_s, wall_time_s, sim_steps: simulated time, wall-clock time, physics steps.
        gif, gif_frames, mp4: output files written (None when not asked).
        parameters: the physics and control parameters used.
        reasons: why it failed: where the object first left the limits (the phase: step,
            finger, action; contacts lost, slip, rotation axis), every state whose
            simulated closure disagrees with the plan's and every state carried by other
            links than the plan's fingers.
        failed_step: index of the plan step during which the replay first failed (the drift
            left the limits, or it led into a state that failed), -1 when it failed at state
            0 (acquiring, gravity ramp, settling), None when it passed.
        failed_at_state: the failure is the state that step reaches (measured there: its
            closure or the links holding the object), not the motion of the step itself.
        trajectory: what the simulator did, sampled every ``TRAJECTORY_DT_S`` of simulated
            time (`view --report` plays it): ``joints`` (names), ``t`` (s), ``q`` (rad, one row
            per sample), ``object_position`` (m) and ``object_quat_xyzw`` (palm frame).
        engine: the physics engine that replayed it (`planner.sim.engine`); a report written
            before engines were named has none and was pybullet's.
        coupling_errors: one `CouplingError` per coupled joint of the hand (`planner.hand
            .Hand.couplings` order; none for a hand without couplings, and in a report written
            before the replay measured them). A replay whose coupling error exceeds its
            tolerance does not pass.
        stopped_after: the plan step after which the replay stopped unfailed because a
            replay before it in the order of the planner's verification had failed
            (`planner.sim.replay.StopLine`); not passed, no failed step. None: it ran to its
            end or its own failure.
    """

    passed: bool
    verdict: str
    dropped: bool
    max_drift_mm: float
    max_drift_deg: float
    final_drift_mm: float
    final_drift_deg: float
    drift_mm_max: float
    drift_deg_max: float
    closure_agreement: tuple[int, int]
    states: tuple[StateReport, ...]
    sim_time_s: float
    wall_time_s: float
    sim_steps: int
    gif: str | None = None
    gif_frames: int = 0
    mp4: str | None = None
    parameters: Mapping[str, Any] = field(default_factory=dict)
    reasons: tuple[str, ...] = ()
    failed_step: int | None = None
    failed_at_state: bool = False
    trajectory: Mapping[str, Any] | None = None
    engine: str = "pybullet"
    coupling_errors: tuple[CouplingError, ...] = ()
    stopped_after: int | None = None

    def to_dict(self) -> dict:
        """Plain data for JSON (``json.dumps(report.to_dict())``)."""
        data = asdict(self)
        data["parameters"] = dict(self.parameters)
        for st, src in zip(data["states"], self.states):
            st["sim_patches"] = {f: {"points": np.asarray(pt).tolist(), "normals": np.asarray(nr).tolist()}
                                 for f, (pt, nr) in src.sim_patches.items()}
        data["closure_agreement"] = list(self.closure_agreement)
        return _no_nan(json.loads(json.dumps(data, default=_json_default)))


def _no_nan(value):
    """NaN (not measured) becomes null, so the JSON is strict."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_no_nan(v) for v in value]
    return value


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"not JSON serializable: {type(value).__name__}")


@dataclass(frozen=True)
class GravitySetReport:
    """Outcome of `replay_gravity_set`: one replay per gravity direction.

    Attributes:
        passed: every direction passed.
        verdict: one line: PASS/FAIL with the directions that failed.
        directions: (name, gravity (3,), ReplayReport) per direction, in `planner.gravity` order.
    """

    passed: bool
    verdict: str
    directions: tuple[tuple[str, tuple[float, float, float], ReplayReport], ...]

    def to_dict(self) -> dict:
        """Plain data for JSON."""
        return {"passed": self.passed, "verdict": self.verdict,
                "directions": [{"name": n, "gravity": list(g), "report": r.to_dict()} for n, g, r in self.directions]}
