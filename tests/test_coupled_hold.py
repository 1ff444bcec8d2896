"""A one-actuator finger (one joint, or a driver and its followers: Alex's Psyonic fingers) holds
what its motor pushes through the normal force, not what friction would carry for it.

Measured (docs/YOUR_HAND.md, section 2): the Psyonic box plan's state 7 (the thumb lifted),
replayed as a one-state hold in MuJoCo with gravity off, had the index commanded 0.71 N at its
distal link and delivering 0.18 N; the motor's torque divided by ``v.n + mu |v_t|`` (friction
at the cone's edge against the motor, the finger slid closed) gives the delivered force to two
digits (index 0.28 N of 0.028 N m over 0.0988 m, little 0.30 N measured 0.32 N). The grip model
states that friction as linear rows (`planner.grip.one_actuator_rows`), opt-in in the
planner's programs and the controller's force solution (off by default: see the module
docstring of `planner.grip`); these tests check their maths.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.grip import (FRICTION_MARGIN, FingerStatics, balance_forces, grip_program, hold_capacity,
                          one_actuator_rows, torque_rows)
from planner.model import Friction

MU = 0.9


def _jac(v, a=(0.0, 0.0, 0.0)):
    return np.r_[np.asarray(v, float), np.asarray(a, float)].reshape(1, 6, 1)


def test_rows_hold_the_friction_at_the_cone_edge_along_the_fingers_slide():
    v = np.array([0.02, 0.0, 0.08])  # the point moves mostly along the surface (x is the normal)
    n = np.array([1.0, 0.0, 0.0])
    rows = one_actuator_rows(_jac(v), [n], MU)
    assert rows.shape == (1, 7) and rows[0, 0] == 0
    t = np.array([0.0, 0.0, 1.0])
    f = 0.5 * (n + MU * t)  # the force the motor works against: friction along its slide
    assert rows[0, 1:4] @ f == pytest.approx(0.0, abs=1e-12)
    assert rows[0, 1:4] @ (0.5 * n) != pytest.approx(0.0)  # no friction: not what it delivers
    # the torque of that force: the normal force times v.n + mu |v_t|
    assert v @ f == pytest.approx(0.5 * (v @ n + MU * np.linalg.norm(v - (v @ n) * n)))


def test_a_finger_moving_along_the_normal_or_with_two_actuators_has_no_friction_row():
    n = np.array([0.0, 1.0, 0.0])
    assert len(one_actuator_rows(_jac(0.03 * n), [n], MU)) == 0
    two = np.zeros((1, 6, 2))
    two[0, :3, 0], two[0, :3, 1] = [0.0, 0.03, 0.01], [0.01, 0.02, 0.0]
    assert one_actuator_rows(two, [n], MU).shape == (0, 7)


def test_torsion_about_the_normal_carries_none_of_the_motors_load():
    n = np.array([0.0, 0.0, 1.0])
    rows = one_actuator_rows(_jac([0.0, 0.0, 0.02], a=[0.0, 0.0, 1.0]), [n], MU)  # turning about n
    assert len(rows) == 1 and np.allclose(rows[0, 1:4], 0) and rows[0, 6] != 0


def _pinch(effort=0.05, lateral=0.08, normal=0.02):
    """Two one-actuator fingers on opposite faces of a 4 cm cube (normals +-x), each sliding
    upward (+z) as it closes."""
    P = np.array([[-0.02, 0.0, 0.0], [0.02, 0.0, 0.0]])
    N = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    patches = {"a": (P[:1], N[:1]), "b": (P[1:], N[1:])}
    statics = {f: FingerStatics(f, (f"{f}_1",), _jac(np.array([normal * N[i, 0], 0.0, lateral])), np.zeros((1, 3)),
                                np.array([effort])) for i, f in enumerate("ab")}
    return patches, statics


def test_friction_of_one_actuator_fingers_lifts_a_load_against_their_slide_not_with_it():
    patches, statics = _pinch()
    fr = Friction(MU, 0.0)
    m_g = 0.05 * 9.81
    prog = grip_program(patches, statics, fr, one_actuator=True)
    down = hold_capacity(patches, statics, fr, [0, 0, -m_g, 0, 0, 0], [0, 0, -9.81], program=prog)
    up = hold_capacity(patches, statics, fr, [0, 0, m_g, 0, 0, 0], [0, 0, 9.81], program=prog)
    # without the rows (the default) the friction may point either way: both directions hold
    assert hold_capacity(patches, statics, fr, [0, 0, m_g, 0, 0, 0], [0, 0, 9.81]).factor > 2.0
    assert up.factor == 0.0  # the friction pushes the way the fingers close (+z): it cannot hold a +z load
    # down: 2 mu' f_n = alpha m g, each motor at its limit f_n (v.n + mu' |v_t|) = effort
    mu_p = FRICTION_MARGIN * MU * math.cos(math.pi / 16)
    expected = 2 * mu_p * 0.05 / ((0.02 + mu_p * 0.08) * m_g)
    assert down.factor == pytest.approx(expected, rel=2e-3)
    f = down.forces["a"][0]
    assert f[2] / f[0] == pytest.approx(mu_p, rel=1e-6)  # at the cone's edge along the slide


def test_fingers_with_two_actuators_keep_the_symmetric_model():
    patches, statics = _pinch()
    two = {f: FingerStatics(f, (f"{f}_1", f"{f}_2"), np.concatenate([s.jacobians, _jac([0, 0.02, 0])], axis=2),
                            np.zeros((2, 3)), np.array([0.05, 0.05])) for f, s in statics.items()}
    fr = Friction(MU, 0.0)
    m_g = 0.05 * 9.81
    assert len(grip_program(patches, two, fr, one_actuator=True).one_actuator) == 0
    up = hold_capacity(patches, two, fr, [0, 0, m_g, 0, 0, 0], [0, 0, 9.81])
    assert up.factor > 2.0


def test_the_controllers_forces_take_the_same_rows_at_each_margin():
    P = np.array([[-0.02, 0.0, 0.0], [0.02, 0.0, 0.0]])
    N = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    J = [np.r_[np.array([0.02 * N[i, 0], 0.0, 0.08]), np.zeros(3)].reshape(6, 1) for i in range(2)]
    load = [0, 0, -0.05 * 9.81, 0, 0, 0]
    rows = [([i], *torque_rows([J[i][:3]], [0.05], [0.0])) for i in range(2)]
    fr = Friction(MU, 0.0)
    f = balance_forces(P, N, 0.3 * N, load, np.zeros(3), fr, 0.1, math.inf, margins=((0.5, 0.0),),
                       joint_rows=rows, one_actuator=[(0, J[0]), (1, J[1])])
    assert f is not None
    mu_s = 0.5 * MU * math.cos(math.pi / 8)
    for i in range(2):
        assert f[i, 2] == pytest.approx(mu_s * (f[i] @ N[i]), rel=1e-6)
    # a load along the fingers' slide: no balance at any margin
    assert balance_forces(P, N, 0.3 * N, [0, 0, 0.05 * 9.81, 0, 0, 0], np.zeros(3), fr, 0.1, math.inf,
                          joint_rows=rows, one_actuator=[(0, J[0]), (1, J[1])]) is None


def test_slide_directions_are_the_unit_tangential_part_of_the_point_velocity():
    """A one-actuator finger's slide at a contact is v - (v.n) n, normalized; none for a point
    moved along its normal or a finger with two actuated coordinates."""
    from planner.grip import slide_directions

    rng = np.random.default_rng(0)
    for _ in range(20):
        v, n = rng.normal(size=3), rng.normal(size=3)
        n /= np.linalg.norm(n)
        [(i, t)] = slide_directions(_jac(v), [n])
        assert i == 0 and np.linalg.norm(t) == pytest.approx(1.0)
        assert t @ n == pytest.approx(0.0, abs=1e-12)
        assert v @ t == pytest.approx(np.linalg.norm(v - (v @ n) * n))
    assert slide_directions(_jac([0.0, 0.0, 0.03]), [[0.0, 0.0, 1.0]]) == []
    assert slide_directions(np.zeros((1, 6, 2)), [[0.0, 0.0, 1.0]]) == []


def test_no_wedge_rows_keep_the_slide_friction_between_none_and_the_closing_edge():
    """With ``one_actuator="no_wedge"`` the friction along a one-actuator finger's slide may
    resist its closing but not hold it open: the two-finger pinch holds a load that needs the
    friction along the slide (+z: fingers close upward, a -z load) and not one that needs it
    against the slide; "none" holds neither by friction."""
    patches, statics = _pinch()
    fr = Friction(MU, 0.0)
    m_g = 0.05 * 9.81
    down = [0, 0, -m_g, 0, 0, 0]
    up = [0, 0, m_g, 0, 0, 0]
    wedge = grip_program(patches, statics, fr, one_actuator="no_wedge")
    assert wedge.one_actuator_ub.shape == (2, wedge.W.shape[0]) and len(wedge.one_actuator) == 0
    # a -z load: the friction at the closing edge is the best there (the motors' limits bind),
    # as under the "edge" rows
    edge = grip_program(patches, statics, fr, one_actuator="edge")
    expected = hold_capacity(patches, statics, fr, down, [0, 0, -9.81], program=edge).factor
    assert expected > 1.0
    assert hold_capacity(patches, statics, fr, down, [0, 0, -9.81], program=wedge).factor == pytest.approx(expected, rel=0.01)  # (the polygon cones differ)
    assert hold_capacity(patches, statics, fr, up, [0, 0, 9.81], program=wedge).factor == 0.0
    none = grip_program(patches, statics, fr, one_actuator="none")
    assert hold_capacity(patches, statics, fr, down, [0, 0, -9.81], program=none).factor == 0.0
    f = hold_capacity(patches, statics, fr, down, [0, 0, -9.81], program=wedge).forces["a"][0]
    assert f[2] >= -1e-9 and f[2] <= FRICTION_MARGIN * MU * f[0] + 1e-9  # along the slide, inside the cone


def test_release_equilibrium_needs_something_to_take_the_closing_slide_friction():
    """Two one-actuator fingers closing upward on opposite faces push the object up with their
    closing-slide friction: no equilibrium at release, unless a contact on the top face (the
    palm) pushes back; a two-actuator finger's whole cone balances it too."""
    from planner.grip import release_equilibrium
    from planner.model import PALM

    patches, statics = _pinch()
    fr = Friction(MU, 0.0)
    assert not release_equilibrium(patches, statics, fr)
    top = {**patches, PALM: (np.array([[0.0, 0.0, 0.02]]), np.array([[0.0, 0.0, -1.0]]))}
    assert release_equilibrium(top, statics, fr)
    two = {f: FingerStatics(f, (f"{f}_1", f"{f}_2"), np.concatenate([s.jacobians, _jac([0, 0.02, 0])], axis=2),
                            np.zeros((2, 3)), np.array([0.05, 0.05])) for f, s in statics.items()}
    assert release_equilibrium(patches, two, fr)
