"""The pybullet scene: the one place the hand and object bodies are built.

The replay's pybullet engine (`planner.sim.engine_pybullet`) and the pictures
(`planner.sim.render`) both build their scenes here, so a hand or an object looks and
collides the same in a film as in the physics. Every call names its client: nothing relies on a global connection. Importing
this module imports pybullet (its build banner silenced). `urdf_problem` says whether
pybullet can simulate a hand's URDF at all (``regrasp hand check``).
"""

from __future__ import annotations

import contextlib
import os
import sys

from planner.errors import SimulationError


@contextlib.contextmanager
def quiet_native_output():
    """Silence what pybullet's C++ code prints on stdout/stderr (build banner, URDF
    warnings): a command's own stdout (e.g. ``--json``) must stay parseable."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


with quiet_native_output():  # pybullet prints its build banner on the C stdout at import
    import pybullet as p


@contextlib.contextmanager
def resolved_urdf(urdf_path, package_dirs=()):
    """A copy of a URDF with every mesh path resolved to an absolute path
    (`planner.urdf_check.rewritten_urdf`: ``package://`` in ``package_dirs``, the folders the
    hand was loaded with, ``ROS_PACKAGE_PATH`` and the installed wheels; a relative path in
    the URDF's folder), in a temporary folder removed on exit: pybullet knows no
    ``package://`` and keeps one search path only. The file pybullet is given to load."""
    import tempfile

    from planner.errors import SpecError
    from planner.urdf_check import rewritten_urdf

    try:
        text = rewritten_urdf(urdf_path, package_dirs)
    except SpecError as err:
        raise SimulationError(f"pybullet cannot load the hand URDF: {err}") from None
    with tempfile.TemporaryDirectory(prefix="regrasp-urdf-") as tmp:
        path = os.path.join(tmp, os.path.basename(str(urdf_path)))
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
        yield path


def hand_body(client: int, urdf_path, *, base_pos=(0.0, 0.0, 0.0), base_quat_xyzw=(0.0, 0.0, 0.0, 1.0),
              package_dirs=(), inertia_from_file: bool = False, visual: bool = True) -> int:
    """The hand's URDF as a fixed-base body.

    Args:
        client: pybullet physics client id.
        urdf_path: the hand's URDF.
        base_pos, base_quat_xyzw: pose of the URDF's root in the world.
        package_dirs: folders ``package://`` mesh paths are searched in, before those the
            hand loaded from this URDF was given (`resolved_urdf`).
        inertia_from_file: use the URDF's inertias (the replay's physics) rather than
            pybullet's from the collision shapes (enough for pictures).
        visual: load the visual shapes (False: collision only, faster).
    Raises:
        SimulationError: pybullet cannot load the URDF.
    """
    flags = (p.URDF_USE_INERTIA_FROM_FILE if inertia_from_file else 0) | (0 if visual else p.URDF_IGNORE_VISUAL_SHAPES)
    with resolved_urdf(urdf_path, package_dirs or ()) as path:
        try:
            with quiet_native_output():
                body = p.loadURDF(path, list(base_pos), list(base_quat_xyzw), useFixedBase=True, flags=flags,
                                  physicsClientId=client)
        except p.error as err:
            raise SimulationError(f"pybullet cannot load the hand URDF {urdf_path}: {err}") from err
    # links without inertia: the stated one (pybullet alone gives each 1 kg), as pinocchio has it
    from planner.urdf_check import stated_inertias

    stated = stated_inertias(urdf_path, package_dirs or ())
    if stated:
        for i in range(p.getNumJoints(body, physicsClientId=client)):
            link = p.getJointInfo(body, i, physicsClientId=client)[12].decode()
            if link in stated:
                mass, moments = stated[link]
                p.changeDynamics(body, i, mass=mass, localInertiaDiagonal=list(moments), physicsClientId=client)
    return body


def object_body(client: int, shape: str, size, mesh_path, position, quat_xyzw, mass_kg: float, rgba) -> int:
    """An object (box, cylinder, sphere or mesh, `planner.objects` conventions: cylinder axis
    = object z) as a pybullet body of ``mass_kg`` (0: static) at a world pose.

    Raises:
        SimulationError: unknown shape, or pybullet could not create it.
    """
    size = [float(s) for s in size]
    if shape == "box":
        col = dict(shapeType=p.GEOM_BOX, halfExtents=[s / 2 for s in size])
        vis = dict(col)
    elif shape == "cylinder":
        col = dict(shapeType=p.GEOM_CYLINDER, radius=size[0], height=size[1])
        vis = dict(shapeType=p.GEOM_CYLINDER, radius=size[0], length=size[1])
    elif shape == "sphere":
        col = dict(shapeType=p.GEOM_SPHERE, radius=size[0])
        vis = dict(col)
    elif shape == "mesh":
        col = dict(shapeType=p.GEOM_MESH, fileName=str(mesh_path), meshScale=size * 3 if len(size) == 1 else size)
        vis = dict(col)
    else:
        raise SimulationError(f"cannot build a pybullet shape for object shape {shape!r}")
    with quiet_native_output():  # a mesh's loader warns on the C stdout
        c = p.createCollisionShape(physicsClientId=client, **col)
        v = p.createVisualShape(rgbaColor=list(rgba), physicsClientId=client, **vis)
    if c < 0 or v < 0:
        raise SimulationError(f"pybullet could not create the {shape} object")
    return p.createMultiBody(baseMass=float(mass_kg), baseCollisionShapeIndex=c, baseVisualShapeIndex=v,
                             basePosition=[float(x) for x in position], baseOrientation=[float(x) for x in quat_xyzw],
                             physicsClientId=client)


def urdf_problem(urdf_path: str, joint_names) -> str | None:
    """Why pybullet cannot simulate a hand URDF with these joints (one line), or None."""
    cid = p.connect(p.DIRECT)
    try:
        body = hand_body(cid, urdf_path, visual=False)
        names = {p.getJointInfo(body, i, physicsClientId=cid)[1].decode() for i in range(p.getNumJoints(body, physicsClientId=cid))}
        missing = [j for j in joint_names if j not in names]
        return f"joints {missing[:4]} are not in the URDF pybullet loads" if missing else None
    except (p.error, SimulationError) as err:
        return f"cannot load {urdf_path}: {err}"
    finally:
        p.disconnect(physicsClientId=cid)
