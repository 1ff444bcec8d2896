"""Writes coupled_hand.urdf: a small two-finger test hand with coupled joints.

A 60 x 40 x 20 mm palm (top face at z = 0, the grasping face +z) and two fingers that
point up (+z) from its ends at x = -/+25 mm and flex toward each other: proximal 40 mm,
middle 30 mm, distal 25 mm, capsules of radius 7 mm (cylinder + 2 spheres: the planner
merges them into one capsule). Joints ``<finger>_0 .. _2`` flex about y (left) and -y
(right), 0 .. 90 deg. The left finger's distal joint follows its middle joint by a URDF
``<mimic>`` (``left_2 = 1.0 left_1``); the right finger has none (a hand.yaml may add one).
Run: python make_urdf.py [--no-mimic] > coupled_hand.urdf
"""

import sys

LINKS = (("proximal", 0.040), ("middle", 0.030), ("distal", 0.025))
R = 0.007


def capsule(length: float) -> str:
    half = length / 2
    return (f'<collision><origin xyz="0 0 {half:g}"/><geometry><cylinder radius="{R}" length="{length:g}"/>'
            f'</geometry></collision>'
            f'<collision><origin xyz="0 0 0"/><geometry><sphere radius="{R}"/></geometry></collision>'
            f'<collision><origin xyz="0 0 {length:g}"/><geometry><sphere radius="{R}"/></geometry></collision>')


def inertial(mass: float, length: float) -> str:
    i = mass * length ** 2 / 12 + 1e-7
    return (f'<inertial><origin xyz="0 0 {length / 2:g}"/><mass value="{mass:g}"/>'
            f'<inertia ixx="{i:g}" iyy="{i:g}" izz="1e-7" ixy="0" ixz="0" iyz="0"/></inertial>')


def finger(name: str, x: float, axis: str, mimic: bool) -> str:
    out = []
    parent, z = "palm", 0.0
    for k, (part, length) in enumerate(LINKS):
        link = f"{name}_{part}"
        out.append(f'<link name="{link}">{inertial(0.01, length)}{capsule(length)}</link>')
        origin = f"{x:g} 0 0.007" if k == 0 else f"0 0 {LINKS[k - 1][1]:g}"
        m = f'<mimic joint="{name}_1" multiplier="1.0" offset="0.0"/>' if mimic and k == 2 else ""
        out.append(f'<joint name="{name}_{k}" type="revolute"><parent link="{parent}"/><child link="{link}"/>'
                   f'<origin xyz="{origin}"/><axis xyz="{axis}"/>'
                   f'<limit lower="0" upper="1.5708" effort="0.5" velocity="1"/>{m}</joint>')
        parent = link
    tip = f"{name}_tip"
    out.append(f'<link name="{tip}"/>')
    out.append(f'<joint name="{tip}_joint" type="fixed"><parent link="{parent}"/><child link="{tip}"/>'
               f'<origin xyz="0 0 {LINKS[-1][1]:g}"/></joint>')
    return "\n".join(out)


def main() -> None:
    mimic = "--no-mimic" not in sys.argv
    palm = ('<link name="palm"><inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" '
            'ixz="0" iyz="0"/></inertial><collision><origin xyz="0 0 -0.01"/><geometry><box size="0.06 0.04 0.02"/>'
            '</geometry></collision></link>')
    print('<?xml version="1.0"?>\n<robot name="coupled_hand">\n' + palm + "\n"
          + finger("left", -0.025, "0 1 0", mimic) + "\n" + finger("right", 0.025, "0 -1 0", False) + "\n</robot>")


if __name__ == "__main__":
    main()
