"""Gravity directions in the palm frame: the hand orientations a plan is planned and replayed for.

Grasp validation in the literature (e.g. DexGraspNet, BODex) shakes or re-orients a grasp
under several gravity directions rather than one. Here a hand's grasping face is its
``palm_normal`` (hand.yaml, palm frame): gravity along it is "palm down" (the object hangs
from the fingers), against it "palm up" (the object rests towards the palm), and the four
directions orthogonal to it are "sideways". `named_gravity` resolves these names, and the
anatomical ones (thumb_up, fingers_down, ...) derived from the hand's kinematics, to one
vector (``--gravity NAME``). Pure numpy; no back end (the anatomical names read a loaded
`planner.hand.Hand` through its own methods).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from planner.errors import PlannerError

#: Standard gravity, m/s^2.
G_MPS2 = 9.81
#: Valid ``--gravity-set`` sizes: 1 palm down; 2 palm down and up; 6 those plus the four
#: sideways directions; 7 those six plus gravity off.
GRAVITY_SET_SIZES = (1, 2, 6, 7)
#: Names `named_gravity` knows (``--gravity NAME``): those of `gravity_directions` (the
#: sideways pair along a palm axis is side_+x ... side_-z; side_+a ... side_-b for an oblique
#: palm normal), the anatomical ones of `hand_axes`, and gravity off. Which sideways names a
#: hand has depends on its ``palm_normal``.
ANATOMICAL_NAMES = ("thumb_up", "thumb_down", "fingers_up", "fingers_down")
GRAVITY_NAMES = (("palm_down", "palm_up") + tuple(f"side_{s}{a}" for a in "xyzab" for s in "+-")
                 + ANATOMICAL_NAMES + ("off",))
#: Below this (m), a finger base is too close to the palm centre (projected on the palm's
#: plane) to give a direction.
_MIN_OFFSET_M = 1e-3


def gravity_directions(palm_normal: Sequence[float], n: int, g_mps2: float = G_MPS2) -> list[tuple[str, tuple[float, float, float]]]:
    """Named gravity vectors in the palm frame.

    Args:
        palm_normal: (3,) unit normal of the grasping face, palm frame (``Hand.palm_normal``).
        n: set size, one of ``GRAVITY_SET_SIZES``.
        g_mps2: magnitude, m/s^2.

    Returns:
        [(name, (gx, gy, gz))], in the order palm_down, palm_up, side_+a, side_-a, side_+b,
        side_-b, off; ``a``, ``b`` are the palm-frame axes orthogonal to ``palm_normal`` in
        x, y, z order (for a normal along a palm axis; otherwise an orthonormal pair).

    Raises:
        PlannerError: ``n`` not in ``GRAVITY_SET_SIZES`` or a zero/non-finite normal.
    """
    if isinstance(n, bool) or n not in GRAVITY_SET_SIZES:  # (True == 1)
        raise PlannerError(f"gravity set size must be one of {', '.join(map(str, GRAVITY_SET_SIZES))}, got {n!r}")
    nrm = np.asarray(palm_normal, dtype=float).reshape(3)
    length = float(np.linalg.norm(nrm))
    if not (math.isfinite(length) and length > 0):
        raise PlannerError(f"palm normal must be a non-zero vector, got {list(nrm)}")
    nrm = nrm / length
    out = [("palm_down", nrm * g_mps2)] + ([("palm_up", -nrm * g_mps2)] if n >= 2 else [])
    if n >= 6:
        names = "xyz"
        axes = [(names[i], np.eye(3)[i]) for i in range(3) if abs(nrm[i]) < 1.0 - 1e-9]
        if len(axes) == 3:  # oblique normal: an orthonormal pair, named a and b
            a = np.cross(nrm, np.eye(3)[int(np.argmin(np.abs(nrm)))])
            a /= np.linalg.norm(a)
            axes = [("a", a), ("b", np.cross(nrm, a))]
        for name, axis in axes:
            axis = axis - nrm * float(axis @ nrm)
            axis /= np.linalg.norm(axis)
            out += [(f"side_+{name}", axis * g_mps2), (f"side_-{name}", -axis * g_mps2)]
    if n == 7:
        out.append(("off", np.zeros(3)))
    return [(name, tuple(float(x) + 0.0 for x in v)) for name, v in out]


def gravity_label_of(gravity, name: str | None = None) -> str | None:
    """How a ``--gravity`` given is said in verdicts and suggested commands: its name, else its
    three numbers (None: no gravity given, execution mode's own directions)."""
    if gravity is None:
        return None
    if name:
        return name
    return " ".join(f"{float(v):g}" for v in np.asarray(gravity, dtype=float).reshape(-1)[:3])


def gravity_name_error(what: str = "--gravity") -> str:
    """The one line refusing a gravity that is neither 3 numbers nor a name."""
    return f"{what}: expected 3 numbers GX GY GZ or one of {', '.join(GRAVITY_NAMES)}"


def _palm_centre(state) -> np.ndarray:
    """The palm's centre in the palm frame: the mean of the bounding-sphere centres of the
    hand's finger-less collision shapes (the palm's links; `HandState.center`), else the palm
    frame's origin."""
    centres = [state.center(i) for i in state.model.finger_geometries(None)]
    return np.mean(centres, axis=0) if centres else np.zeros(3)


def _finger_base(state, finger) -> np.ndarray:
    """Palm-frame position of a finger's first joint in ``state`` (a `HandState`)."""
    km = state.model.kinematic_model
    M = state.kinematics.joint_placement(km.model.getJointId(finger.joints[0]))
    return np.asarray(km.T_palm_world.act(M.translation), dtype=float)


def hand_axes(hand) -> dict[str, np.ndarray | None]:
    """The hand's anatomical directions (palm frame, unit, orthogonal to ``palm_normal``),
    read from its kinematics at the open posture (`planner.hand.Hand`: ``q_open``, the
    fingers' first joints, the palm's collision shapes), never written per hand.

    ``fingers``: from the palm centre (`_palm_centre`) to the knuckles, the mean of the
    first-joint positions of every finger but the one named ``thumb``, projected on the
    palm's plane. ``thumb``: from the palm centre to the first joint of the finger named
    ``thumb``, projected on the palm's plane and made orthogonal to ``fingers`` too (the hand's
    lateral axis: thumb_up is the handshake orientation). Either is None when the hand has
    no such finger or its base is within 1 mm of the palm centre on that plane.
    """
    nrm = np.asarray(hand.palm_normal, dtype=float).reshape(3)
    nrm = nrm / np.linalg.norm(nrm)
    state = hand.state(hand.q_open)  # one kinematic state for the palm centre and every finger base
    centre = _palm_centre(state)

    def planar(v, *against):
        v = np.asarray(v, dtype=float) - centre
        for a in (nrm,) + against:
            v = v - a * float(v @ a)
        length = float(np.linalg.norm(v))
        return v / length if length >= _MIN_OFFSET_M else None

    others = [f for name, f in hand.fingers.items() if name != "thumb"]
    fingers = planar(np.mean([_finger_base(state, f) for f in others], axis=0)) if others else None
    thumb = None
    if "thumb" in hand.fingers:
        base = _finger_base(state, hand.fingers["thumb"])
        thumb = planar(base, fingers) if fingers is not None else planar(base)
    return {"fingers": fingers, "thumb": thumb}


def named_gravity(name: str, hand, g_mps2: float = G_MPS2) -> tuple[float, float, float]:
    """A named hand orientation as a gravity vector of ``g_mps2`` (palm frame, m/s^2).

    palm_down, palm_up and the sideways names are those of `gravity_directions` (the names of
    ``--gravity-set 7``; which side_ names exist depends on the hand's ``palm_normal``); off
    is no gravity. The anatomical names come from `hand_axes`: thumb_up (the thumb points up:
    gravity against the palm-to-thumb-base direction), thumb_down (along it), fingers_up
    (the fingers point up: gravity against the palm-to-knuckles direction), fingers_down
    (along it).

    Args:
        name: one of `GRAVITY_NAMES`.
        hand: a loaded `planner.hand.Hand` (``palm_normal``; its kinematics for the
            anatomical names).
        g_mps2: magnitude.

    Raises:
        PlannerError: an unknown name (one line listing the valid ones), a sideways name the
            hand's palm normal does not have, or an anatomical name the hand cannot give (no
            finger named thumb, a finger base on the palm centre).
    """
    if not isinstance(name, str) or name not in GRAVITY_NAMES:
        raise PlannerError(f"unknown gravity {name!r}; " + gravity_name_error("--gravity").split(": ", 1)[1])
    named = dict(gravity_directions(hand.palm_normal, 7, g_mps2))
    if name in named:
        return named[name]
    if name.startswith("side_"):
        sides = [n for n in named if n.startswith("side_")]
        raise PlannerError(f"gravity {name}: not a sideways direction of hand {hand.name} (palm_normal "
                           f"{list(hand.palm_normal)}); its sideways directions are {', '.join(sides)}")
    part, way = name.split("_")
    axis = hand_axes(hand)[part]
    if axis is None:
        if part == "thumb" and "thumb" not in hand.fingers:
            why = f"has no finger named thumb (fingers: {', '.join(hand.fingers)})"
        elif part == "fingers" and not [f for f in hand.fingers if f != "thumb"]:
            why = "has no finger besides the thumb"
        else:
            why = f"has its {'thumb' if part == 'thumb' else 'knuckles'} on the palm centre (no direction)"
        raise PlannerError(f"gravity {name}: hand {hand.name} {why}; give a vector GX GY GZ or another name")
    g = (-axis if way == "up" else axis) * g_mps2
    return tuple(float(v) + 0.0 for v in g)
