"""Generate icub_right.urdf: an authored, simplified iCub-like right hand.

Run ``python robots/icub_right/make_urdf.py`` to rewrite the URDF next to this file.
The numbers come from /work/shared/reference/icub-hand-facts.md (published iCub
kinematics); the geometry is ours: cylinders with sphere end caps (capsules, radius
6.5 mm) for phalanges and a box palm.

Frames. The root link ``palm`` is the hand frame: fingers along +x, thumb on -y,
grasping face +z. Every finger link uses one local convention:
  x_local  along the phalanx (from its joint toward the fingertip),
  y_local  = -(flexion axis), so every flexion joint has axis (0, -1, 0),
  z_local  = x_local cross y_local = the palmar side (the pad faces +z_local).
With this choice a positive flexion angle moves the tip along (-y) x (+x) = +z_local:
the fingers curl toward the palm's grasping face (+z), as on the robot.

Thumb. The opposition joint thumb_0 has the fact-sheet axis a0 = (-0.87, -0.49, 0.07),
perpendicular to the straight thumb at q = 0 (from thumb_0 to the tip (18.5, -87, 0)),
so positive opposition swings the thumb out of the palm plane toward +z. The three
flexion joints turn about f = a0 x d (d = thumb direction at q = 0), i.e. about the
normal of the plane swept by opposition. Then the thumb's palmar side is
(f x d) = -a0 = (0.87, 0.49, -0.07): positive flexion curls the thumb toward the
fingers (in the palm plane at thumb_0 = 0; over the grasping face, opposing the
index and middle fingertips, at thumb_0 = 90 deg). That is the human thumb's
flexion/opposition split and lets the thumb pad meet the finger pads.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

MM = 1e-3
RADIUS = 6.5 * MM
DEG = math.pi / 180.0

# name: (joint_0 position or None, joint_0 axis or None, joint_0 limits deg,
#        joint_1 position, joint_1 (flexion) axis, tip at q=0, lengths prox/int/dist)
FINGERS = {
    "thumb": None,  # built separately below
    "index": ((1.8, -26.2, -10.7), (0, 0, 1), (-20, 0),
              (16.6, -25.5, -10.8), (-0.07, -0.99, 0.09), (81, -30, -10), (25.9, 22.0, 16.8)),
    "middle": (None, None, None,
               (17.8, -7.6, -11.6), (0, -1, 0), (84, -8, -12), (25.8, 24.0, 16.8)),
    "ring": ((1.6, 5.7, -11.0), (0.09, 0, 1.0), (0, 20),
             (16.1, 9.0, -12.3), (0.11, -0.99, 0), (80, 16, -18), (25.9, 22.0, 16.8)),
    "little": ((-0.4, 24.5, -10.0), (0.09, 0, 1.0), (0, 20),
               (14.5, 24.4, -11.3), (0.11, -0.99, 0), (72, 31, -16), (21.9, 19.0, 16.8)),
}
THUMB_0 = (-23.5, -12.0, -1.5)
THUMB_AXIS = (-0.87, -0.49, 0.07)
THUMB_TIP = (18.5, -87.0, 0.0)
THUMB_LENGTHS = (21.1, 26.0, 22.0, 16.8)  # base offset, proximal, intermediate, distal

MASS = {"proximal": 0.015, "intermediate": 0.012, "distal": 0.010, "base": 0.005}
EFFORT_NM = 0.5
VELOCITY = 3.0


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def finger_rotation(d, flex_axis):
    """Columns x = d, y = -flex axis (made orthogonal to d), z = x cross y."""
    x = unit(d)
    a = np.asarray(flex_axis, dtype=float)
    a = unit(a - a.dot(x) * x)
    y = -a
    return np.column_stack([x, y, np.cross(x, y)])


def rpy(R):
    """URDF rpy (fixed-axis XYZ, R = Rz(yaw) Ry(pitch) Rx(roll))."""
    pitch = math.asin(-max(-1.0, min(1.0, R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    yaw = math.atan2(R[1, 0], R[0, 0])
    return roll, pitch, yaw


def fmt(v):
    return " ".join(f"{x:.6g}" if abs(x) > 1e-12 else "0" for x in v)


def inertial(mass, length, radius):
    """Solid cylinder along local x from 0 to length."""
    ixx = 0.5 * mass * radius**2
    iyy = mass * (3 * radius**2 + length**2) / 12.0
    return (f'    <inertial>\n      <origin xyz="{fmt((length / 2, 0, 0))}" rpy="0 0 0"/>\n'
            f'      <mass value="{mass:.6g}"/>\n'
            f'      <inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{iyy:.6g}"/>\n'
            f'    </inertial>\n')


def capsule(length, radius):
    """Cylinder along local x from 0 to length plus two sphere caps (URDF has no capsule)."""
    out = []
    for tag in ("collision", "visual"):
        out.append(f'    <{tag}>\n      <origin xyz="{fmt((length / 2, 0, 0))}" rpy="0 1.5707963267949 0"/>\n'
                   f'      <geometry><cylinder radius="{radius:.6g}" length="{length:.6g}"/></geometry>\n'
                   f'    </{tag}>\n')
        for x in (0.0, length):
            out.append(f'    <{tag}>\n      <origin xyz="{fmt((x, 0, 0))}" rpy="0 0 0"/>\n'
                       f'      <geometry><sphere radius="{radius:.6g}"/></geometry>\n'
                       f'    </{tag}>\n')
    return "".join(out)


def link(name, mass, length, geometry=True):
    body = inertial(mass, max(length, 0.005), RADIUS)
    if geometry:
        body += capsule(length, RADIUS)
    return f'  <link name="{name}">\n{body}  </link>\n'


def joint(name, parent, child, xyz, rpy_, axis, lo, hi, kind="revolute"):
    s = (f'  <joint name="{name}" type="{kind}">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
         f'    <origin xyz="{fmt(xyz)}" rpy="{fmt(rpy_)}"/>\n')
    if kind == "revolute":
        s += (f'    <axis xyz="{fmt(axis)}"/>\n'
              f'    <limit lower="{lo:.6g}" upper="{hi:.6g}" effort="{EFFORT_NM}" velocity="{VELOCITY}"/>\n'
              f'    <dynamics damping="0.01" friction="0.0"/>\n')
    return s + "  </joint>\n"


def phalanges(parts, f, parent, xyz, R_rpy, first_joint_index, lengths):
    """Proximal, intermediate, distal links + flexion joints + fixed tip frame."""
    names = ("proximal", "intermediate", "distal")
    L = [x * MM for x in lengths]
    for k, (part, length) in enumerate(zip(names, L)):
        child = f"{f}_{part}"
        j = f"{f}_{first_joint_index + k}"
        if k == 0:
            parts.append(joint(j, parent, child, xyz, R_rpy, (0, -1, 0), 0.0, 90 * DEG))
        else:
            parts.append(joint(j, f"{f}_{names[k - 1]}", child, (L[k - 1], 0, 0), (0, 0, 0),
                               (0, -1, 0), 0.0, 90 * DEG))
        # the distal capsule's cap ends at the fingertip: its segment is shorter by a radius
        seg = length - RADIUS if part == "distal" else length
        parts.append(link(child, MASS[part], seg))
    tip = f"{f}_tip"
    # a massless link would get 1 kg in pybullet: give the tip frame a token 1 g point mass
    parts.append(f'  <link name="{tip}">\n    <inertial>\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n'
                 f'      <mass value="0.001"/>\n      <inertia ixx="1e-8" ixy="0" ixz="0" iyy="1e-8" iyz="0" izz="1e-8"/>\n'
                 f'    </inertial>\n  </link>\n')
    parts.append(joint(f"{f}_tip_joint", f"{f}_distal", tip, (L[2], 0, 0), (0, 0, 0), None, 0, 0, "fixed"))


def build() -> str:
    parts = ['<?xml version="1.0"?>\n',
             "<!-- Generated by make_urdf.py: simplified iCub-like right hand (authored, not copied).\n"
             "     Units: metres, radians, kilograms. Root link palm = hand frame. -->\n",
             '<robot name="icub_right_hand">\n']
    # palm box: x -72..+7 mm, y -35..+32, z -27..+3
    lo, hi = np.array([-72, -35, -27]) * MM, np.array([7, 32, 3]) * MM
    c, s = (lo + hi) / 2, hi - lo
    m = 0.15
    I = m / 12 * np.array([s[1] ** 2 + s[2] ** 2, s[0] ** 2 + s[2] ** 2, s[0] ** 2 + s[1] ** 2])
    geo = "".join(f'    <{t}>\n      <origin xyz="{fmt(c)}" rpy="0 0 0"/>\n'
                  f'      <geometry><box size="{fmt(s)}"/></geometry>\n    </{t}>\n'
                  for t in ("collision", "visual"))
    parts.append(f'  <link name="palm">\n    <inertial>\n      <origin xyz="{fmt(c)}" rpy="0 0 0"/>\n'
                 f'      <mass value="{m}"/>\n      <inertia ixx="{I[0]:.6g}" ixy="0" ixz="0" '
                 f'iyy="{I[1]:.6g}" iyz="0" izz="{I[2]:.6g}"/>\n    </inertial>\n{geo}  </link>\n')

    # thumb: opposition joint, base link along the thumb, then three flexion joints
    p0 = np.array(THUMB_0) * MM
    a0 = unit(THUMB_AXIS)
    d = unit(np.array(THUMB_TIP) * MM - p0)
    f_axis = unit(np.cross(a0, d))
    R = finger_rotation(d, f_axis)
    parts.append(joint("thumb_0", "palm", "thumb_base", p0, rpy(R), R.T @ a0, 0.0, 90 * DEG))
    parts.append(link("thumb_base", MASS["base"], THUMB_LENGTHS[0] * MM, geometry=False))
    phalanges(parts, "thumb", "thumb_base", (THUMB_LENGTHS[0] * MM, 0, 0), (0, 0, 0), 1, THUMB_LENGTHS[1:])

    for f, spec in FINGERS.items():
        if spec is None:
            continue
        j0, a0_, lim, j1, a1, tip, lengths = spec
        p1 = np.array(j1) * MM
        R = finger_rotation(np.array(tip) * MM - p1, a1)
        if j0 is None:
            phalanges(parts, f, "palm", p1, rpy(R), 1, lengths)
            continue
        p0 = np.array(j0) * MM
        parts.append(joint(f"{f}_0", "palm", f"{f}_base", p0, rpy(R), unit(R.T @ unit(a0_)),
                           lim[0] * DEG, lim[1] * DEG))
        parts.append(link(f"{f}_base", MASS["base"], 0.0148, geometry=False))
        phalanges(parts, f, f"{f}_base", R.T @ (p1 - p0), (0, 0, 0), 1, lengths)
    parts.append("</robot>\n")
    return "".join(parts)


if __name__ == "__main__":
    out = Path(__file__).with_name("icub_right.urdf")
    out.write_text(build())
    print(f"wrote {out}")
