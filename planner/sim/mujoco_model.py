"""The MuJoCo scene of a replay: the hand and the object built from the project's own types.

`build` turns a `planner.hand.Hand`, a `planner.objects.GraspObject` and the grasp's
`planner.model.Friction` into a `MujocoScene`: MuJoCo's compiled ``MjModel`` and its
``MjData``, with every accessor keyed by NAME (URDF joint names, URDF link names), never by
a MuJoCo index. The engine seam of the replay (``planner.sim.engine``) is meant to sit on
top of it. Importing this module imports ``mujoco``; nothing outside ``planner.sim`` does.

How the scene is made, and why (docs/ENGINES.md compares it with the pybullet replay):

* **Hand.** The hand's URDF, its mesh paths resolved as every command resolves them
  (`planner.urdf_check.rewritten_urdf`: ``package://`` in the hand's package dirs, relative
  paths in the URDF's folder, written absolute), read by MuJoCo's URDF parser through
  ``MjSpec`` with ``fusestatic`` off (every URDF link stays a body of its own name) and
  ``strippath`` off. Its root link is fixed where the pybullet replay puts it: the world
  IS the palm frame, so the root sits at ``T_palm_root`` (identity when the root is the
  palm). Joints outside every finger are removed, i.e. locked at 0, as the pinocchio model
  of `planner.hand.Hand` locks them. Joint limits are the URDF's; joint damping, friction
  loss and armature are 0 (the pybullet replay switches Bullet's joint damping off; the
  controller damps). Collision meshes collide as their convex hulls (MuJoCo always does,
  and so does pybullet for a moving link); visual geoms are dropped unless asked for.
* **Masses.** The URDF's inertias, except where the pybullet replay replaces them, with the
  same project functions: a link without inertia gets `planner.urdf_check.stated_inertias`
  (about the link's origin and axes), a placeholder inertia the solid box of
  `planner.handtool.replay_inertia` (on the URDF's ``<inertial>`` frame, as pybullet's
  ``localInertiaDiagonal`` puts it). MuJoCo refuses an inertia whose principal moments
  break the triangle inequality A + B >= C, which pinocchio and Bullet accept (the
  example-robot-data Allegro's link_3.0 is one): the two smaller moments are raised just
  enough, the largest and the principal axes kept (`_balanced`; `MujocoScene.balanced_links`
  names those links). Every coupling of the hand (`planner.hand.Hand.couplings`: a URDF
  ``<mimic>`` or a hand.yaml coupling, ``q_f = m q_d + o``) is a stiff joint equality,
  ``polycoef = (o, m, 0, 0, 0)`` (``couplings=False``: none, every joint free). The
  controller commands the drivers only (a follower's motor gets zero).
* **Torques.** One ``motor`` actuator (gear 1) per movable joint, named after the joint,
  ``ctrlrange`` +/- the hand's effort limit (`planner.hand.Hand.effort`: the URDF's
  ``<limit effort>`` or the hand.yaml's override; unlimited when neither gives one).
  Actuators rather than ``qfrc_applied``: MuJoCo clips the torque to the joint's limit
  itself, and ``data.actuator_force`` records what was applied.
* **Object.** A free body of the object's mass (the plan's; volume x density without one:
  `planner.sim.inputs.object_mass`, as the pybullet replay) with its centre of mass at the
  object's origin (as pybullet and the planner's weight wrench have it) and Bullet's
  inertia for the same shape (`object_inertia`): exact for box, cylinder and sphere, the bounding
  box's (grown by Bullet's margin) for a mesh. Its geom is the primitive, or the mesh,
  which collides as its convex hull.
* **Friction.** MuJoCo's contact friction is (sliding, torsional, rolling); a pair of geoms
  of different ``priority`` takes the higher one's friction, ``condim``, ``solref`` and
  ``solimp`` whole. The object's geom has priority 1 and friction ``(mu, gamma, 0)``, so
  every finger-object contact has exactly the grasp's ``mu`` (Coulomb) and ``gamma``
  (torsional: MuJoCo's torsional coefficient is a length, torque per unit normal force,
  the soft-finger ``gamma`` of thesis eq. 1). ``condim`` 4 (normal, 2 tangents, torsion);
  3 when ``gamma`` is 0 and 1 when ``mu`` is 0 too (MuJoCo cannot take a zero coefficient
  in a cone it builds). Hand links do not collide with each other (pybullet loads the hand
  without self-collision).
* **Cone.** Elliptic by default: ``(f_t1 / mu)^2 + (f_t2 / mu)^2 + (tau / gamma)^2 <= f_n^2``,
  the circular Coulomb cone with torsion coupled in one ellipsoid. The planner's and
  Bullet's soft finger bound torsion separately (``|f_t| <= mu f_n`` and
  ``|tau| <= gamma f_n``): a contact using both at once has less in MuJoCo. A pyramidal
  cone (``cone="pyramidal"``) is more conservative still (its edges make a diamond).
* **Soft contacts.** See `contact_solref` and `CONTACT_SOLIMP`: the stiffest stable
  reference (time constant 2 dt, critically damped) and an impedance near 1, so a contact
  carrying a squeezing finger sinks sub-millimetre; ``impratio`` (`IMPRATIO`) makes
  friction ten times as stiff as the normal direction so a held object does not creep.
* **Hold.** A weld between the object and a mocap body, toggled with ``eq_active``:
  `MujocoScene.hold_object` welds the object where it is, `release_object` frees it
  (`HOLD_SOLIMP`: stiffer than a contact).

Quaternions: the project is ``quat_xyzw`` everywhere; MuJoCo stores ``wxyz``. Every
accessor here takes and returns ``xyzw``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from planner.errors import InputError, SimulationError, UnknownNameError
from planner.sim.inputs import T_palm_root as T_palm_base
from planner.sim.inputs import object_mass

# No MuJoCo GL context is ever opened here (pictures come from pybullet's CPU renderer), and
# mujoco's import otherwise loads GLFW, which probes its version in a subprocess (refused under
# pdoc, the API reference's builder): no OpenGL back end unless the user chose one.
os.environ.setdefault("MUJOCO_GL", "disable")

import mujoco  # noqa: E402 (the one back end of this module)

#: Name of the object's body, its free joint, its geom, the mocap anchor that holds it and
#: the weld between them; no URDF link name may be one of these.
OBJECT_BODY = "object"
OBJECT_JOINT = "object_free"
OBJECT_GEOM = "object_geom"
ANCHOR_BODY = "object_anchor"
HOLD_WELD = "object_hold"

#: Contact impedance (dmin, dmax, width m, midpoint, power). At rest MuJoCo's soft
#: constraint satisfies ``(1 - d) a0 = d k r`` with ``k = d / (dmax^2 tau^2)`` (damping
#: ratio 1): the penetration that carries an unconstrained acceleration a0 is
#: ``r = (1 - d) dmax^2 tau^2 a0 / d^2``. An object resting on a link (a0 = g, tau = 2/240 s)
#: sinks 37 um at d = 0.95 (measured: the tests' weld sag and resting sphere); a 10 g
#: phalanx pressing 5 N (a0 ~ 500 m/s^2) sinks 0.35 mm at d = 0.99, five times that at
#: MuJoCo's default dmax 0.95 (more than the replay's touch tolerance, 0.5 mm,
#: `planner.sim.controller.TOUCH_TOL_M`). The impedance
#: rises from 0.95 to 0.99 over the first 1 mm of penetration (softer at first touch, which
#: keeps making and breaking a contact smooth).
CONTACT_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)
#: Impedance of the hold weld (`MujocoScene.hold_object`): the pybullet replay holds the
#: object with a fixed constraint of up to 1000 N while the fingers squeeze it (a few N on a
#: few tens of grams: a0 ~ 100 m/s^2); by the formula above the contacts' impedance would
#: let it sag 0.35 mm, this one (d = 0.99 at once) 70 um, and 7 um under its own weight.
HOLD_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
#: Contact damping ratio: critical (penetration decays without a bounce; pybullet's contacts
#: have no restitution either).
CONTACT_DAMPRATIO = 1.0
#: Friction-to-normal impedance ratio. A soft friction constraint lets a sticking contact
#: creep at a speed proportional to its tangential load over its impedance; the replay
#: holds an object for seconds, so friction is made ten times as stiff as the normal
#: direction (MuJoCo's advice for grasping, with elliptic cones). The slip limit (mu) is
#: unchanged.
IMPRATIO = 10.0
#: Bullet's inertia of a convex hull (a mesh object) is the solid box of its bounding box
#: grown by its collision margin on every side (btPolyhedralConvexShape::calculateLocalInertia;
#: pybullet's convex-hull margin, measured: every moment of a 40 x 40 x 80 mm hull and of
#: its 80 x 40 x 120 mm scaling matches 3 mm a side to 1e-7). The same here, so that both
#: engines give one object one inertia.
BULLET_HULL_MARGIN_M = 0.003
#: A closest-point segment shorter than this has no reliable direction (MuJoCo's convex
#: distance is exact to its ``ccd_tolerance``, 1e-6 m: measured, two cylinders touching
#: within 0.1 um gave a direction 45 deg off, at 1 um the exact one); `closest_points` then
#: takes the normal from the distance's gradient, by differences of this step.
DIRECTION_MIN_M = 1e-5
#: Bits of the collision filter: hand geoms collide with the object, not with each other.
_HAND_BIT, _OBJECT_BIT = 1, 2


def contact_solref(dt_s: float) -> tuple[float, float]:
    """(time constant s, damping ratio) of every contact and of the hold weld: the time
    constant is 2 dt, the smallest MuJoCo integrates stably (a stiffer reference is
    clamped to it anyway), critically damped (`CONTACT_DAMPRATIO`)."""
    return (2.0 * float(dt_s), CONTACT_DAMPRATIO)


# --------------------------------------------------------------------------- values


@dataclass(frozen=True)
class ContactPoint:
    """One hand-object contact (or closest pair of points) in the world (= palm) frame.

    The fields of `planner.sim.engine.ContactPoint`, in its order.

    Attributes:
        link: the hand link's URDF name.
        point_m: (3,) the contact point (MuJoCo's: midway between the two surfaces; a closest
            pair: the point on the object's surface).
        normal: (3,) unit normal INTO the object (the direction the link pushes).
        distance_m: signed distance between the surfaces, m (negative: penetration).
        normal_force_n: normal force, N (>= 0; 0 for a closest pair or a contact outside
            the solver).
    """

    link: str
    point_m: np.ndarray
    normal: np.ndarray
    distance_m: float
    normal_force_n: float


@dataclass(frozen=True)
class SolverSettings:
    """What `build` sets in ``mjModel.opt`` and on every contact (recorded in a report)."""

    dt_s: float
    cone: str
    impratio: float
    iterations: int
    solref: tuple[float, float]
    solimp: tuple[float, ...]
    condim: int


# --------------------------------------------------------------------------- helpers


def _wxyz(quat_xyzw) -> np.ndarray:
    x, y, z, w = (float(v) for v in quat_xyzw)
    return np.array([w, x, y, z])


def _xyzw(quat_wxyz) -> tuple[float, float, float, float]:
    w, x, y, z = (float(v) for v in quat_wxyz)
    return (x, y, z, w)


def _pose(pos, quat_wxyz) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(_xyzw(quat_wxyz)).as_matrix()
    T[:3, 3] = pos
    return T


def object_inertia(obj, mass_kg: float) -> np.ndarray:
    """Principal moments (3,) about the object's origin and axes, kg m^2, as Bullet gives the
    same shape: solid box, solid cylinder (axis z), solid sphere exactly; a mesh the solid box
    of its bounding box grown by `BULLET_HULL_MARGIN_M` a side (Bullet's convex-hull rule)."""
    from planner.handtool import box_inertia

    m, s = float(mass_kg), obj.size
    if obj.shape == "box":
        return box_inertia(m, s)
    if obj.shape == "cylinder":
        r, length = s
        side = m * (3 * r * r + length * length) / 12.0
        return np.array([side, side, m * r * r / 2.0])
    if obj.shape == "sphere":
        return np.full(3, 0.4 * m * s[0] ** 2)
    return box_inertia(m, np.asarray(obj.extents, float) + 2.0 * BULLET_HULL_MARGIN_M)


def _urdf_text(hand, visual: bool) -> str:
    """The hand's URDF, mesh paths absolute, with MuJoCo's compiler options written in (the
    URDF parser reads them from a ``<mujoco>`` element)."""
    from planner.errors import SpecError
    from planner.urdf_check import rewritten_urdf

    try:
        text = rewritten_urdf(hand.urdf_path, hand.package_dirs)
    except SpecError as err:
        raise SimulationError(f"MuJoCo cannot load the hand URDF: {err}") from None
    options = (f'<mujoco><compiler fusestatic="false" strippath="false" balanceinertia="true" '
               f'discardvisual="{"false" if visual else "true"}" inertiafromgeom="false"/></mujoco>')
    end = text.rfind("</robot>")
    if end < 0:
        raise SimulationError(f"MuJoCo cannot load the hand URDF {hand.urdf_path}: no </robot> end tag")
    return text[:end] + options + text[end:]


def _balanced(body) -> bool:
    """Make a URDF inertia (``fullinertia``: xx, yy, zz, xy, xz, yz in the ``iquat`` frame)
    whose principal moments break A + B >= C one MuJoCo accepts, changing it least: the
    largest moment (the axis a phalanx mostly turns about) and the principal axes kept, the
    two smaller raised by the same amount until A + B = C. (MuJoCo's own ``balanceinertia``
    sets all three to their mean, which for the Allegro's fingertip links lowers the largest
    by 40 %.) Returns whether it changed anything."""
    xx, yy, zz, xy, xz, yz = (float(v) for v in body.fullinertia)
    if math.isnan(xx):
        return False
    ev, V = np.linalg.eigh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))  # ascending
    deficit = ev[2] - ev[0] - ev[1]
    if deficit <= 1e-9 * ev[2]:
        return False
    ev = ev + np.array([1.0, 1.0, 0.0]) * deficit * (0.5 + 1e-6)  # (a hair over: A + B >= C in floats)
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    R = Rotation.from_quat(_xyzw(body.iquat)).as_matrix() @ V
    body.iquat = _wxyz(Rotation.from_matrix(R).as_quat()).tolist()
    body.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
    body.inertia = ev.tolist()
    return True


def _set_inertias(spec, hand) -> tuple[str, ...]:
    """The pybullet replay's inertia replacements on the parsed hand (see the module
    docstring); returns the links whose URDF inertia had to be balanced (`_balanced`)."""
    from planner.handtool import replay_inertia

    bodies = {b.name: b for b in spec.bodies}
    for link, (mass, moments) in hand.stated_inertia.items():
        b = bodies.get(link)
        if b is None:
            continue
        b.explicitinertial = True
        b.mass, b.ipos, b.iquat = float(mass), [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        b.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
        b.inertia = [float(v) for v in moments]
    for link, (_, _, box) in replay_inertia(hand).items():
        b = bodies.get(link)
        if b is None:
            continue
        # the URDF's centre of mass and inertial frame, on whose axes pybullet puts the box's
        # moments too (`localInertiaDiagonal`; a placeholder's tensor is diagonal there)
        b.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
        b.inertia = [float(v) for v in box]
    return tuple(b.name for b in spec.bodies if b.explicitinertial and _balanced(b))


def _check_meshes(spec, urdf_path) -> None:
    for mesh in spec.meshes:
        ext = Path(mesh.file).suffix.lower()
        if ext not in (".stl", ".obj", ".msh"):
            raise SimulationError(f"{urdf_path}: mesh {Path(mesh.file).name}: MuJoCo reads STL, OBJ and MSH meshes, "
                                  f"not {ext or 'a file without suffix'}; convert it")


# --------------------------------------------------------------------------- build


def build(hand, obj, friction, *, dt_s: float, gravity=(0.0, 0.0, 0.0), density_kg_m3: float = 500.0,
          object_mass_kg: float | None = None,
          cone: str = "elliptic", impratio: float = IMPRATIO, solver_iterations: int = 100,
          hold: bool = False, visual: bool = False, couplings: bool = True) -> "MujocoScene":
    """The hand and the object as one MuJoCo model (see the module docstring for every choice).

    Args:
        hand: a `planner.hand.Hand`; the world frame is its palm frame.
        obj: a `planner.objects.GraspObject` at its pose in the palm frame.
        friction: the grasp's `planner.model.Friction` (``mu``, ``gamma``).
        dt_s: the time step, s.
        gravity: gravity in the world (= palm) frame, m/s^2 (`MujocoScene.set_gravity` later).
        density_kg_m3: the object's density when it has no ``mass_kg`` (as the pybullet replay).
        object_mass_kg: the object's mass, kg, when the caller has it already (the replay's
            `planner.sim.engine.World`); None: from the object and ``density_kg_m3``.
        cone: "elliptic" or "pyramidal" friction cones.
        impratio: MuJoCo's friction-to-normal impedance ratio (`IMPRATIO`).
        solver_iterations: MuJoCo's Newton solver iterations per step.
        hold: start with the object welded at its pose (`MujocoScene.hold_object`).
        visual: keep the URDF's visual geoms (for pictures; they never collide).
        couplings: every coupling of the hand (a URDF ``<mimic>`` or a hand.yaml coupling)
            as a joint equality (the follower follows its driver); False: none (every
            joint free).

    Returns:
        A `MujocoScene` with the hand at its open posture and the object at rest at its pose.

    Raises:
        InputError: a bad ``dt_s``, ``gravity``, ``cone``, ``impratio`` or iteration count.
        SimulationError: MuJoCo cannot read or compile the hand or the object.
    """
    if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and dt_s > 0):
        raise InputError(f"dt_s must be a positive number of seconds, got {dt_s!r}")
    cones = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}
    if cone not in cones:
        raise UnknownNameError("friction cone", str(cone), cones)
    if not (isinstance(impratio, (int, float)) and math.isfinite(impratio) and impratio >= 1):
        raise InputError(f"impratio must be a number >= 1, got {impratio!r}")
    if isinstance(solver_iterations, bool) or not isinstance(solver_iterations, int) or solver_iterations < 1:
        raise InputError(f"solver_iterations must be a positive integer, got {solver_iterations!r}")
    g = _gravity(gravity)
    mass = object_mass(obj, density_kg_m3)[0] if object_mass_kg is None else object_mass_kg
    if isinstance(mass, bool) or not (isinstance(mass, (int, float)) and math.isfinite(mass) and mass > 0):
        raise InputError(f"object_mass_kg must be a positive number of kg, got {mass!r}")

    text = _urdf_text(hand, visual)
    try:
        spec = mujoco.MjSpec.from_string(text)
    except ValueError as err:
        raise SimulationError(f"MuJoCo cannot read the hand URDF {hand.urdf_path}: {_one_line(err)}") from None
    _check_meshes(spec, hand.urdf_path)
    taken = {OBJECT_BODY, ANCHOR_BODY} & {b.name for b in spec.bodies}
    if taken:
        raise SimulationError(f"{hand.urdf_path}: link {sorted(taken)[0]!r} is a name the MuJoCo scene reserves")
    spec.modelname = f"{hand.name}_scene"

    # the root link at its pose in the palm frame (= world)
    roots = [b for b in spec.worldbody.bodies]
    if len(roots) != 1:
        raise SimulationError(f"{hand.urdf_path}: MuJoCo reads {len(roots)} root links; a hand has one")
    root = roots[0]
    if hand.model.frames[1].name != root.name:
        raise SimulationError(f"{hand.urdf_path}: MuJoCo's root link {root.name!r} is not pinocchio's "
                              f"{hand.model.frames[1].name!r}")
    T_palm_root = T_palm_base(hand)
    root.pos = T_palm_root[:3, 3].tolist()
    root.quat = _wxyz(Rotation.from_matrix(T_palm_root[:3, :3]).as_quat()).tolist()
    if root.joints:  # (a URDF root never has one; a floating base would)
        raise SimulationError(f"{hand.urdf_path}: root link {root.name!r} is not fixed")

    # joints: the hand's (its fingers'); any other is locked at 0, as in pinocchio's model
    names = set(hand.joint_names)
    for j in list(spec.joints):
        if j.name not in names:
            spec.delete(j)
    missing = [j for j in hand.joint_names if j not in {x.name for x in spec.joints}]
    if missing:
        raise SimulationError(f"{hand.urdf_path}: joints {missing[:4]} of the hand are not joints MuJoCo reads")
    effort = dict(zip(hand.joint_names, (float(e) for e in hand.effort)))
    for j in spec.joints:
        j.damping, j.frictionloss, j.armature = [0.0, 0.0, 0.0], 0.0, 0.0
        j.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE  # the actuator's ctrlrange limits it
    for name in hand.joint_names:
        act = spec.add_actuator(name=name, trntype=mujoco.mjtTrn.mjTRN_JOINT, target=name)
        act.set_to_motor()
        tau = effort[name]
        if math.isfinite(tau):
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.ctrlrange = [-tau, tau]
        else:
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE

    balanced = _set_inertias(spec, hand)
    # coupled joints: the hand's (`planner.hand.Coupling`: a URDF <mimic>, or a hand.yaml coupling
    # the URDF has none for, or one whose <mimic> names no joint), each a joint equality
    # q_f = o + m q_d (polycoef "o m 0 0 0"); the parser's own equalities from <mimic> give way
    for eq in list(spec.equalities):
        spec.delete(eq)
    for c in getattr(hand, "couplings", ()) if couplings else ():
        if c.joint in names and c.follows in names:  # (a coupling to a locked joint: the joint is gone)
            data = np.zeros(12)
            data[:2] = float(c.offset), float(c.multiplier)
            # as stiff as the hold weld: the coupling is a gear train, not a spring
            spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, objtype=mujoco.mjtObj.mjOBJ_JOINT, name1=c.joint,
                              name2=c.follows, data=data.tolist(), solref=list(contact_solref(dt_s)),
                              solimp=list(HOLD_SOLIMP))

    solref, solimp = contact_solref(dt_s), CONTACT_SOLIMP
    mu, gamma = float(friction.mu), float(friction.gamma)
    condim = 4 if gamma > 0 else (3 if mu > 0 else 1)
    for geom in spec.geoms:
        if geom.contype == 0 and geom.conaffinity == 0:
            continue  # a visual geom (the URDF parser gives them no collision bits)
        geom.contype, geom.conaffinity = _HAND_BIT, _OBJECT_BIT
        geom.priority, geom.condim = 0, condim
        geom.friction = [mu, gamma, 0.0]
        geom.solref, geom.solimp = list(solref), list(solimp)
        geom.margin = geom.gap = 0.0

    _add_object(spec, obj, friction, solref, solimp, condim, float(mass))

    opt = spec.option
    opt.timestep = float(dt_s)
    opt.gravity = g.tolist()
    opt.cone = cones[cone]
    opt.impratio = float(impratio)
    opt.iterations = int(solver_iterations)
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    try:
        model = spec.compile()
    except ValueError as err:
        raise SimulationError(f"MuJoCo cannot compile the scene of {hand.name!r}: {_one_line(err)}") from None
    settings = SolverSettings(float(dt_s), cone, float(impratio), int(solver_iterations), solref, solimp, condim)
    scene = MujocoScene(model, hand, friction, settings, balanced, spec, _urdf_parents(text))
    scene.set_joint_positions(dict(zip(hand.joint_names, (float(v) for v in hand.q_open))))
    if hold:
        scene.hold_object()
    return scene


def _add_object(spec, obj, friction, solref, solimp, condim, mass_kg) -> None:
    pos = [float(v) for v in obj.position]
    quat = _wxyz(obj.quat_xyzw).tolist()
    body = spec.worldbody.add_body(name=OBJECT_BODY, pos=pos, quat=quat)
    body.add_freejoint(name=OBJECT_JOINT)
    body.explicitinertial = True
    body.mass = float(mass_kg)
    body.ipos, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
    body.inertia = object_inertia(obj, mass_kg).tolist()
    geom = body.add_geom(name=OBJECT_GEOM)
    s = [float(v) for v in obj.size]
    if obj.shape == "box":
        geom.type, geom.size = mujoco.mjtGeom.mjGEOM_BOX, [v / 2 for v in s]
    elif obj.shape == "cylinder":
        geom.type, geom.size = mujoco.mjtGeom.mjGEOM_CYLINDER, [s[0], s[1] / 2, 0.0]
    elif obj.shape == "sphere":
        geom.type, geom.size = mujoco.mjtGeom.mjGEOM_SPHERE, [s[0], 0.0, 0.0]
    elif obj.shape == "mesh":
        path = Path(obj.mesh_path).resolve()
        if path.suffix.lower() not in (".stl", ".obj"):
            raise SimulationError(f"object mesh {path.name}: MuJoCo reads STL and OBJ meshes, not {path.suffix}")
        spec.add_mesh(name="object_mesh", file=str(path), scale=s * 3 if len(s) == 1 else s)
        geom.type, geom.meshname = mujoco.mjtGeom.mjGEOM_MESH, "object_mesh"
    else:
        raise SimulationError(f"cannot build a MuJoCo shape for object shape {obj.shape!r}")
    # the higher priority: every hand-object contact takes this geom's friction, condim,
    # solref and solimp whole (MuJoCo's rule for geoms of different priorities)
    geom.priority = 1
    geom.contype, geom.conaffinity = _OBJECT_BIT, _HAND_BIT
    geom.condim = condim
    geom.friction = [float(friction.mu), float(friction.gamma), 0.0]
    geom.solref, geom.solimp = list(solref), list(solimp)
    geom.rgba = [0.85, 0.45, 0.15, 1.0]  # (the replay's object colour)
    # the hold: a weld to a mocap body placed where the object is to be held, relative pose
    # the identity (welded, the object takes the anchor's pose). A weld's data is MuJoCo's
    # (anchor point (3), relative pose: position (3), quaternion wxyz (4), torque scale);
    # any further entries keep their defaults.
    spec.worldbody.add_body(name=ANCHOR_BODY, pos=pos, quat=quat, mocap=True)
    weld = spec.add_equality(name=HOLD_WELD, type=mujoco.mjtEq.mjEQ_WELD, objtype=mujoco.mjtObj.mjOBJ_BODY,
                             name1=OBJECT_BODY, name2=ANCHOR_BODY, active=0, solref=list(solref),
                             solimp=list(HOLD_SOLIMP))
    data = np.array(weld.data, dtype=float)
    data[:11] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    weld.data = data.tolist()


def _urdf_parents(text: str) -> dict[str, tuple[str, str]]:
    """Child link -> (its URDF joint, parent link), every joint of the URDF (fixed ones too:
    MuJoCo keeps no name for a joint it does not simulate)."""
    import xml.etree.ElementTree as ET

    out = {}
    for j in ET.fromstring(text).findall("joint"):
        child, parent = j.find("child"), j.find("parent")
        if child is not None and parent is not None:
            out[child.get("link")] = (j.get("name"), parent.get("link"))
    return out


def _gravity(gravity) -> np.ndarray:
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise InputError(f"gravity must be 3 finite numbers (palm frame, m/s^2), got {gravity!r}")
    return g


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split())


# --------------------------------------------------------------------------- the scene


class MujocoScene:
    """A built scene (`build`): ``model`` (``mujoco.MjModel``), ``data`` (``mujoco.MjData``)
    and accessors keyed by URDF joint and link names. The world frame is the palm frame.

    Attributes:
        model, data: MuJoCo's model and data (read them freely; write through the accessors).
        hand: the `planner.hand.Hand` it was built from.
        friction: the grasp's friction.
        settings: the solver and contact settings (`SolverSettings`).
        joint_names: the hand's movable joints (the hand's order).
        link_names: every hand link (URDF names) MuJoCo has a body for, the root first.
        object_mass_kg: the object's mass.
        balanced_links: links whose URDF inertia was balanced for MuJoCo (`_balanced`).
        spec: the ``MjSpec`` it was compiled from (``spec.to_xml()`` shows the model).
    """

    def __init__(self, model, hand, friction, settings: SolverSettings, balanced_links, spec, urdf_parents=None):
        self.model, self.data = model, mujoco.MjData(model)
        self.hand, self.friction, self.settings, self.spec = hand, friction, settings, spec
        self.balanced_links = tuple(balanced_links)
        m = model
        name = lambda obj, i: mujoco.mj_id2name(m, obj, i)  # noqa: E731
        self.joint_names = tuple(hand.joint_names)
        self._jid = {j: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in self.joint_names}
        self._qadr = np.array([m.jnt_qposadr[self._jid[j]] for j in self.joint_names])
        self._dadr = np.array([m.jnt_dofadr[self._jid[j]] for j in self.joint_names])
        self._act = {j: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, j) for j in self.joint_names}
        skip = {"world", OBJECT_BODY, ANCHOR_BODY}
        self._body = {name(mujoco.mjtObj.mjOBJ_BODY, b): b for b in range(m.nbody)
                      if name(mujoco.mjtObj.mjOBJ_BODY, b) not in skip}
        self.link_names = tuple(self._body)  # (MuJoCo's depth-first body order: the root first)
        self._parents = {l: jp for l, jp in (urdf_parents or {}).items() if l in self._body and jp[1] in self._body}
        self._obj_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, OBJECT_BODY)
        self._obj_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, OBJECT_GEOM)
        self.object_mass_kg = float(m.body_mass[self._obj_body])
        oj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, OBJECT_JOINT)
        self._obj_q, self._obj_v = int(m.jnt_qposadr[oj]), int(m.jnt_dofadr[oj])
        self._weld = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, HOLD_WELD)
        self._mocap = int(m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, ANCHOR_BODY)])
        body_link = {b: l for l, b in self._body.items()}
        #: hand collision geom id -> its link
        self._geom_link = {g: body_link[int(m.geom_bodyid[g])] for g in range(m.ngeom)
                           if int(m.geom_bodyid[g]) in body_link and (m.geom_contype[g] or m.geom_conaffinity[g])}
        self._hand_geoms = np.array(sorted(self._geom_link), dtype=int)
        self._geom_links = np.array([self._geom_link[g] for g in self._hand_geoms], dtype=object)
        self._is_hand = np.zeros(m.ngeom, dtype=bool)
        self._is_hand[self._hand_geoms] = True
        mujoco.mj_forward(m, self.data)

    # ----------------------------------------------------------------- names
    def _joints(self, names) -> list[str]:
        bad = [j for j in names if j not in self._jid]
        if bad:
            raise UnknownNameError("joint", str(bad[0]), self.joint_names)
        return list(names)

    def _link(self, link: str) -> int:
        try:
            return self._body[link]
        except KeyError:
            raise UnknownNameError("link", str(link), self.link_names) from None

    # ----------------------------------------------------------------- joints
    def set_joint_positions(self, q: Mapping[str, float], *, zero_velocity: bool = True) -> None:
        """Put joints at these values (rad or m; others unchanged), their velocities 0
        unless told otherwise; kinematics and contacts are recomputed."""
        for j in self._joints(q):
            jid = self._jid[j]
            self.data.qpos[self.model.jnt_qposadr[jid]] = float(q[j])
            if zero_velocity:
                self.data.qvel[self.model.jnt_dofadr[jid]] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def set_joint_velocities(self, qd: Mapping[str, float]) -> None:
        """Set joint velocities (rad/s or m/s; others unchanged)."""
        for j in self._joints(qd):
            self.data.qvel[self.model.jnt_dofadr[self._jid[j]]] = float(qd[j])
        mujoco.mj_forward(self.model, self.data)

    def joint_positions(self, names: Sequence[str] | None = None) -> dict[str, float]:
        """Joint name -> position (rad or m), every hand joint unless ``names``."""
        names = self.joint_names if names is None else self._joints(names)
        return {j: float(self.data.qpos[self.model.jnt_qposadr[self._jid[j]]]) for j in names}

    def joint_velocities(self, names: Sequence[str] | None = None) -> dict[str, float]:
        """Joint name -> velocity (rad/s or m/s), every hand joint unless ``names``."""
        names = self.joint_names if names is None else self._joints(names)
        return {j: float(self.data.qvel[self.model.jnt_dofadr[self._jid[j]]]) for j in names}

    def q(self) -> np.ndarray:
        """The hand's joint positions (nq,), in `joint_names` order (the Hand's q vector)."""
        return self.data.qpos[self._qadr].copy()

    def qd(self) -> np.ndarray:
        """The hand's joint velocities (nq,), in `joint_names` order."""
        return self.data.qvel[self._dadr].copy()

    def apply_joint_torques(self, tau: Mapping[str, float]) -> None:
        """Command joint torques (N m; force N for a prismatic joint), held until changed;
        MuJoCo clips each to the joint's effort limit (``ctrlrange``). Joints not named keep
        their last command."""
        for j in self._joints(tau):
            self.data.ctrl[self._act[j]] = float(tau[j])

    def applied_torques(self) -> dict[str, float]:
        """Joint name -> the torque applied in the last step (after the effort clip), N m."""
        return {j: float(self.data.actuator_force[a]) for j, a in self._act.items()}

    def effort_limits(self) -> dict[str, float]:
        """Joint name -> effort limit of its motor, N m (inf: unlimited)."""
        m = self.model
        return {j: float(m.actuator_ctrlrange[a][1]) if m.actuator_ctrllimited[a] else math.inf
                for j, a in self._act.items()}

    def joint_limits(self) -> dict[str, tuple[float, float]]:
        """Joint name -> (lower, upper) (rad or m; +/- inf when unlimited)."""
        m = self.model
        return {j: (float(m.jnt_range[i][0]), float(m.jnt_range[i][1])) if m.jnt_limited[i] else (-math.inf, math.inf)
                for j, i in self._jid.items()}

    # ----------------------------------------------------------------- time
    def step(self, n: int = 1) -> None:
        """Advance ``n`` time steps."""
        for _ in range(int(n)):
            mujoco.mj_step(self.model, self.data)

    @property
    def time_s(self) -> float:
        return float(self.data.time)

    @property
    def dt_s(self) -> float:
        return float(self.model.opt.timestep)

    def set_gravity(self, gravity) -> None:
        """Gravity in the world (= palm) frame, m/s^2."""
        self.model.opt.gravity[:] = _gravity(gravity)

    @property
    def gravity(self) -> np.ndarray:
        return self.model.opt.gravity.copy()

    # ----------------------------------------------------------------- object
    def object_pose(self) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """The object's (position (3,) m, quat_xyzw) in the world (= palm) frame."""
        q = self.data.qpos[self._obj_q:self._obj_q + 7]
        return q[:3].copy(), _xyzw(q[3:])

    def object_T(self) -> np.ndarray:
        """The object's pose T_palm_obj (4, 4)."""
        q = self.data.qpos[self._obj_q:self._obj_q + 7]
        return _pose(q[:3], q[3:])

    def object_velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's (linear velocity m/s, angular velocity rad/s), world frame."""
        v = self.data.qvel[self._obj_v:self._obj_v + 6]
        # a free joint's velocity: linear in the world frame, angular in the body's own frame
        return v[:3].copy(), self.data.xmat[self._obj_body].reshape(3, 3) @ v[3:]

    def set_object_pose(self, position, quat_xyzw) -> None:
        """Put the object at a pose (world = palm frame), at rest; a held object is held there."""
        pos = np.asarray(position, float)
        quat = np.asarray(quat_xyzw, float)
        if pos.shape != (3,) or quat.shape != (4,) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
            raise InputError(f"an object pose is 3 + 4 finite numbers, got {position!r}, {quat_xyzw!r}")
        norm = float(np.linalg.norm(quat))
        if norm < 1e-9:
            raise InputError(f"quat_xyzw must be a non-zero quaternion, got {quat_xyzw!r}")
        wxyz = _wxyz(quat / norm)
        self.data.qpos[self._obj_q:self._obj_q + 7] = np.concatenate([pos, wxyz])
        self.data.qvel[self._obj_v:self._obj_v + 6] = 0.0
        if self.holding:
            self.data.mocap_pos[self._mocap], self.data.mocap_quat[self._mocap] = pos, wxyz
        mujoco.mj_forward(self.model, self.data)

    def hold_object(self, position=None, quat_xyzw=None) -> None:
        """Weld the object at a pose (`set_object_pose`; default: where it is now), at rest,
        until `release_object`."""
        if position is not None or quat_xyzw is not None:
            pos, quat = self.object_pose()
            self.set_object_pose(pos if position is None else position, quat if quat_xyzw is None else quat_xyzw)
        q = self.data.qpos[self._obj_q:self._obj_q + 7]
        self.data.mocap_pos[self._mocap] = q[:3]
        self.data.mocap_quat[self._mocap] = q[3:]
        self.data.qvel[self._obj_v:self._obj_v + 6] = 0.0
        self.data.eq_active[self._weld] = 1
        mujoco.mj_forward(self.model, self.data)

    def release_object(self) -> None:
        """Free the object (the weld off)."""
        self.data.eq_active[self._weld] = 0

    @property
    def holding(self) -> bool:
        return bool(self.data.eq_active[self._weld])

    # ----------------------------------------------------------------- links
    def link_pose(self, link: str) -> np.ndarray:
        """T_palm_link (4, 4) of a hand link (URDF name) now."""
        b = self._link(link)
        return _pose(self.data.xpos[b], self.data.xquat[b])

    def link_poses(self) -> dict[str, np.ndarray]:
        """Every hand link -> T_palm_link (4, 4)."""
        return {l: _pose(self.data.xpos[b], self.data.xquat[b]) for l, b in self._body.items()}

    def link_parents(self) -> dict[str, tuple[str, str]]:
        """Link -> (the URDF joint it hangs from, its parent link), every link but the root
        (`planner.sim.engine.HandTopology.parent`); fixed and locked joints included."""
        return dict(self._parents)

    def link_masses(self) -> dict[str, float]:
        """Every hand link -> its mass in the model, kg."""
        return {l: float(self.model.body_mass[b]) for l, b in self._body.items()}

    def link_inertia(self, link: str) -> tuple[float, np.ndarray, np.ndarray]:
        """(mass kg, centre of mass (3,) in the link frame, rotational inertia (3, 3) about
        it in the link frame) of a hand link in the model."""
        b = self._link(link)
        m = self.model
        R = Rotation.from_quat(_xyzw(m.body_iquat[b])).as_matrix()
        return float(m.body_mass[b]), m.body_ipos[b].copy(), R @ np.diag(m.body_inertia[b]) @ R.T

    def raise_link_inertia(self, link: str, floor_kg_m2: float) -> None:
        """Raise every principal moment of a link's inertia to at least ``floor_kg_m2`` (the
        reflected rotor inertia of a geared motor, `planner.sim.controller`'s armature floor).
        MuJoCo's soft constraints let ``1 - d`` (5 % at first touch) of a joint's
        unconstrained acceleration through a contact, and a finger phalanx of 1e-7 kg m^2
        under a fraction of a newton metre accelerates by 1e5 rad/s^2: the floor bounds that.
        The model's constants that depend on inertia (constraint scaling) are recomputed."""
        if not (isinstance(floor_kg_m2, (int, float)) and math.isfinite(floor_kg_m2) and floor_kg_m2 >= 0):
            raise InputError(f"an inertia floor must be a non-negative number of kg m^2, got {floor_kg_m2!r}")
        b = self._link(link)
        self.model.body_inertia[b] = np.maximum(self.model.body_inertia[b], float(floor_kg_m2))
        mujoco.mj_setConst(self.model, self.data)

    # ----------------------------------------------------------------- contacts
    def contacts(self) -> list[ContactPoint]:
        """The hand-object contacts of the last step (or `mujoco.mj_forward`): link, point,
        normal INTO the object, normal force and signed distance, one per MuJoCo contact.
        A contact penetrating less than `DIRECTION_MIN_M` takes its normal from the distance's
        gradient, as `closest_points` does: MuJoCo's collision frame is as unreliable there
        (measured: an iCub phalanx 1e-8 m into a cylinder got a normal 45 deg off the
        cylinder's, pointing out of it)."""
        n = int(self.data.ncon)
        if n == 0:
            return []
        con = self.data.contact  # (MuJoCo's contact arrays, one row per contact)
        g1, g2 = con.geom1, con.geom2
        hand1 = (g2 == self._obj_geom) & self._is_hand[g1]  # the frame's normal: geom1 -> geom2
        hand2 = (g1 == self._obj_geom) & self._is_hand[g2]
        rows = np.flatnonzero(hand1 | hand2)
        if not len(rows):
            return []
        pos, normal, dist, efc = con.pos, con.frame[:, :3], con.dist, con.efc_address
        out = []
        f6 = np.zeros(6)
        for i in rows:
            link, sign = (self._geom_link[int(g1[i])], 1.0) if hand1[i] else (self._geom_link[int(g2[i])], -1.0)
            force = 0.0
            if efc[i] >= 0:
                mujoco.mj_contactForce(self.model, self.data, int(i), f6)
                force = float(f6[0])
            n = sign * normal[i]
            if abs(float(dist[i])) < DIRECTION_MIN_M:
                n = self._distance_gradient(int(g1[i]) if hand1[i] else int(g2[i]), DIRECTION_MIN_M)
            out.append(ContactPoint(link, pos[i].copy(), n, float(dist[i]), force))
        return out

    def closest_points(self, gap_m: float, link: str | None = None) -> list[ContactPoint]:
        """Per hand link (every one, or ``link`` only) within ``gap_m`` of the object: the
        closest pair of its collision geoms and the object (`mujoco.mj_geomDistance`: convex
        hulls for meshes): the point on the object's surface, the unit normal INTO the
        object (from the link's closest point to the object's, reversed when they overlap),
        signed distance, force 0. In `link_names` order."""
        if not (isinstance(gap_m, (int, float)) and math.isfinite(gap_m) and gap_m >= 0):
            raise InputError(f"gap_m must be a non-negative number of metres, got {gap_m!r}")
        if link is not None:
            self._link(link)
        # only geoms whose bounding spheres come within the gap of the object's bounding box
        # (MuJoCo's geom_aabb: centre and half sizes in the geom's frame)
        m, data, o = self.model, self.data, self._obj_geom
        ids = self._hand_geoms if link is None else self._hand_geoms[self._geom_links == link]
        local = (data.geom_xpos[ids] - data.geom_xpos[o]) @ data.geom_xmat[o].reshape(3, 3) - m.geom_aabb[o, :3]
        outside = np.maximum(np.abs(local) - m.geom_aabb[o, 3:], 0.0)
        near = ids[np.sqrt(np.einsum("ij,ij->i", outside, outside)) - m.geom_rbound[ids] < gap_m]
        best: dict[str, tuple[float, np.ndarray, int]] = {}
        fromto = np.zeros(6)
        gap, geom_link, distance = float(gap_m), self._geom_link, mujoco.mj_geomDistance
        for g in near.tolist():
            dist = distance(m, data, g, o, gap, fromto)
            if dist < gap:
                name = geom_link[g]
                if name not in best or dist < best[name][0]:
                    best[name] = (dist, fromto.copy(), g)
        out = []
        for name in (l for l in self.link_names if l in best):
            dist, ft, g = best[name]
            v = ft[3:] - ft[:3]  # link's point -> object's point: into the object when apart
            length = math.sqrt(float(v @ v))
            if length > DIRECTION_MIN_M:
                n = v * ((1.0 if dist >= 0 else -1.0) / length)
            else:
                n = self._distance_gradient(g, gap_m)
            out.append(ContactPoint(name, ft[3:], n, dist, 0.0))
        return out

    def _distance_gradient(self, geom: int, gap_m: float) -> np.ndarray:
        """The unit gradient of the signed distance between a hand geom and the object with
        respect to the object's position: the direction that separates them fastest, i.e.
        the normal INTO the object. Central differences of `DIRECTION_MIN_M` (the object's
        geom moved in ``data.geom_xpos`` only, then put back): for the surfaces that touch
        within MuJoCo's distance tolerance, where the closest-point segment has no direction."""
        m, d, o = self.model, self.data, self._obj_geom
        saved = d.geom_xpos[o].copy()
        reach = float(gap_m) + 2.0 * DIRECTION_MIN_M
        grad = np.zeros(3)
        try:
            for i in range(3):
                for sign in (1.0, -1.0):
                    d.geom_xpos[o] = saved
                    d.geom_xpos[o, i] += sign * DIRECTION_MIN_M
                    grad[i] += sign * mujoco.mj_geomDistance(m, d, geom, o, reach, None)
        finally:
            d.geom_xpos[o] = saved
        return grad / max(float(np.linalg.norm(grad)), 1e-300)


__all__ = ["ANCHOR_BODY", "BULLET_HULL_MARGIN_M", "CONTACT_SOLIMP", "DIRECTION_MIN_M", "ContactPoint", "HOLD_SOLIMP",
           "HOLD_WELD", "IMPRATIO", "MujocoScene", "OBJECT_BODY", "SolverSettings", "build", "contact_solref",
           "object_inertia"]
