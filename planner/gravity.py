"""Gravity directions in the palm frame: the hand orientations a plan is planned and replayed for.

Grasp validation in the literature (e.g. DexGraspNet, BODex) shakes or re-orients a grasp
under several gravity directions rather than one. Here a hand's grasping face is its
``palm_normal`` (hand.yaml, palm frame): gravity along it is "palm down" (the object hangs
from the fingers), against it "palm up" (the object rests towards the palm), and the four
directions orthogonal to it are "sideways". Pure numpy; no back end.
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
    if n not in GRAVITY_SET_SIZES:
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
