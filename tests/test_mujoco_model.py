"""The MuJoCo scene builder (`planner.sim.mujoco_model`), re-checked independently: against
pinocchio's model of the same hand (joints, limits, masses, forward kinematics), against
pybullet's object inertias, and against analytic mechanics (free fall, a resting object's
weight, the hold weld's sag, sliding on a tilted palm)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from planner.hand import Hand  # noqa: E402
from planner.model import Friction  # noqa: E402
from planner.objects import make_object  # noqa: E402
from planner.resources import bundled_hands  # noqa: E402
from planner.sim import mujoco_model as mm  # noqa: E402

DT = 1.0 / 240.0
G = 9.81
FRICTION = Friction(0.5, 0.002)


def _T(p):
    T = np.eye(4)
    T[:3, 3] = p
    return T


def _far_sphere(mass=0.1):
    return make_object("sphere", [0.02], _T([1.0, 1.0, 1.0]), mass_kg=mass)


@pytest.fixture(scope="module")
def icub():
    return Hand.load("icub_right")


@pytest.fixture(scope="module", params=sorted(bundled_hands()))
def hand(request):
    return Hand.load(request.param)


def _on_palm(scene, xy):
    """Put the object on the iCub palm's grasping face (+z) at (x, y), just touching."""
    scene.set_object_pose([xy[0], xy[1], 0.2], [0, 0, 0, 1])
    d = next(c for c in scene.closest_points(1.0) if c.link == "palm").distance_m
    scene.set_object_pose([xy[0], xy[1], 0.2 - d], [0, 0, 0, 1])


# --------------------------------------------------------------------------- the hand


def test_every_bundled_hand_builds_with_its_joints_limits_and_efforts(hand):
    scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT)
    assert scene.joint_names == hand.joint_names
    assert scene.model.nu == len(hand.joint_names)  # one motor per movable joint
    limits = scene.joint_limits()
    effort = scene.effort_limits()
    for i, j in enumerate(hand.joint_names):
        assert limits[j] == pytest.approx((hand.lower[i], hand.upper[i]), abs=1e-12)
        assert effort[j] == pytest.approx(hand.effort[i])
    # every link pinocchio knows as a body is a MuJoCo body of the same name (fusestatic off)
    import pinocchio as pin

    bodies = {f.name for f in hand.model.frames if f.type == pin.FrameType.BODY}
    assert bodies <= set(scene.link_names)
    # the tree by URDF names: the root first, every other link hangs from its URDF joint
    parents = scene.link_parents()
    assert scene.link_names[0] == hand.model.frames[1].name and scene.link_names[0] not in parents
    assert set(parents) == set(scene.link_names[1:])
    for jid in range(1, hand.model.njoints):
        child = next(f.name for f in hand.model.frames if f.type == pin.FrameType.BODY and f.parentJoint == jid
                     and f.parentFrame == hand.model.getFrameId(hand.model.names[jid]))
        assert parents[child][0] == hand.model.names[jid]
    # the hand starts at its open posture
    assert np.allclose(scene.q(), hand.q_open)
    # no joint damping, friction loss or armature (the pybullet replay has none)
    m = scene.model
    hand_dofs = [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)] for j in hand.joint_names]
    assert not np.any(m.dof_damping[hand_dofs]) and not np.any(m.dof_frictionloss[hand_dofs])
    assert not np.any(m.dof_armature[hand_dofs])


def _moving_groups(scene):
    """Joint name -> the links rigidly moved by it (MuJoCo bodies whose nearest jointed
    ancestor body is that joint's)."""
    m = scene.model
    out = {}
    for link, b in scene._body.items():
        k = b
        while k > 0 and m.body_jntnum[k] == 0:
            k = m.body_parentid[k]
        if k > 0:
            out.setdefault(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.body_jntadr[k]), []).append(link)
    return out


def test_link_masses_and_centres_of_mass_match_pinocchio(hand):
    """pinocchio lumps the links a joint moves rigidly into one inertia: the MuJoCo bodies
    of that group have its mass and, at a random posture, its centre of mass."""
    import pinocchio as pin

    scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT)
    rng = np.random.default_rng(3)
    q = rng.uniform(hand.lower, hand.upper)
    scene.set_joint_positions(dict(zip(hand.joint_names, q)))
    data = hand.model.createData()
    pin.forwardKinematics(hand.model, data, q)
    # pinocchio's world is the URDF root's frame; the scene's world is the palm frame
    root = hand.model.frames[1].name
    T_palm_root = hand.state(q).link_pose(root)
    groups = _moving_groups(scene)
    masses = scene.link_masses()
    for jid in range(1, hand.model.njoints):
        name = hand.model.names[jid]
        inertia = hand.model.inertias[jid]
        links = groups[name]
        mass = sum(masses[l] for l in links)
        assert mass == pytest.approx(inertia.mass, rel=1e-9), name
        com = sum(masses[l] * scene.data.xipos[scene._body[l]] for l in links) / mass
        com_pin = T_palm_root[:3, :3] @ data.oMi[jid].act(inertia.lever) + T_palm_root[:3, 3]
        assert np.linalg.norm(com - com_pin) < 1e-9, name


def test_forward_kinematics_matches_pinocchio_at_random_postures(hand):
    scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT)
    rng = np.random.default_rng(7)
    import pinocchio as pin

    links = sorted({f.name for f in hand.model.frames if f.type == pin.FrameType.BODY})
    for _ in range(5):
        q = rng.uniform(hand.lower, hand.upper)
        scene.set_joint_positions(dict(zip(hand.joint_names, q)))
        assert np.allclose(scene.q(), q)
        state = hand.state(q)
        for link in links:
            T_pin, T_mj = state.link_pose(link), scene.link_pose(link)
            assert np.linalg.norm(T_pin[:3, 3] - T_mj[:3, 3]) < 1e-6, link
            assert np.abs(T_pin[:3, :3] - T_mj[:3, :3]).max() < 1e-6, link
    assert np.allclose(scene.link_pose(hand.palm_frame), np.eye(4), atol=1e-12)  # world = palm


def test_joint_accelerations_under_torques_match_pinocchios_dynamics(icub):
    """No gravity, no contact, random posture and torques: MuJoCo's joint accelerations equal
    pinocchio's articulated-body algorithm on the Hand's model (masses, centres of mass,
    rotational inertias, joint axes all at once)."""
    import pinocchio as pin

    scene = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT)
    rng = np.random.default_rng(2)
    q = icub.lower + (icub.upper - icub.lower) * rng.uniform(0.2, 0.8, len(icub.lower))  # off the limits
    tau = 1e-3 * rng.uniform(-1.0, 1.0, len(q))
    scene.set_joint_positions(dict(zip(icub.joint_names, q)))
    scene.apply_joint_torques(dict(zip(icub.joint_names, tau)))
    mujoco.mj_forward(scene.model, scene.data)
    assert scene.data.nefc == 0
    model = icub.model.copy()
    model.gravity.linear[:] = 0.0
    expected = pin.aba(model, model.createData(), q, np.zeros(model.nv), tau)
    assert np.allclose(scene.data.qacc[scene._dadr], expected, rtol=1e-9, atol=1e-9)


def test_a_mesh_hand_builds_with_convex_hull_links(tmp_path):
    from test_mesh_hand import mesh_hand  # the suite's mesh copy of the iCub hand

    hand = Hand.load(mesh_hand(tmp_path))
    scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT)
    m = scene.model
    assert m.nmesh > 0
    mesh_links = {scene._geom_link[g] for g in scene._geom_link if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH}
    assert "index_distal" in mesh_links
    q = np.random.default_rng(1).uniform(hand.lower, hand.upper)
    scene.set_joint_positions(dict(zip(hand.joint_names, q)))
    T_pin, T_mj = hand.state(q).link_pose("index_distal"), scene.link_pose("index_distal")
    assert np.linalg.norm(T_pin[:3, 3] - T_mj[:3, 3]) < 1e-6


def _edited_icub(tmp_path, edit):
    src = Hand.load("icub_right")
    urdf = open(src.urdf_path).read()
    (tmp_path / "icub_edit.urdf").write_text(edit(urdf))
    spec = open(src.spec_path).read().replace("urdf: icub_right.urdf", "urdf: icub_edit.urdf")
    (tmp_path / "hand.yaml").write_text(spec)
    return Hand.load(tmp_path / "hand.yaml")


def test_missing_and_placeholder_inertias_are_replaced_as_the_pybullet_replay_does(tmp_path):
    from planner.handtool import replay_inertia

    def edit(urdf):
        # index_distal without <inertial>; index_intermediate with a 0.01 kg m^2 placeholder
        urdf = re.sub(r'(<link name="index_distal">)\s*<inertial>.*?</inertial>', r"\1", urdf, flags=re.S)
        return re.sub(r'(<link name="index_intermediate">\s*<inertial>.*?)<inertia [^>]*/>',
                      r'\1<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>', urdf, flags=re.S)

    hand = _edited_icub(tmp_path, edit)
    assert "index_distal" in hand.stated_inertia
    replaced = replay_inertia(hand)
    assert "index_intermediate" in replaced
    scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT)
    mass, moments = hand.stated_inertia["index_distal"]
    m, c, I = scene.link_inertia("index_distal")
    assert m == pytest.approx(mass) and np.allclose(c, 0.0) and np.allclose(I, np.diag(moments))
    m, _, I = scene.link_inertia("index_intermediate")
    assert m == pytest.approx(replaced["index_intermediate"][0])
    assert np.allclose(I, np.diag(replaced["index_intermediate"][2]), rtol=1e-9, atol=0)


def test_an_inertia_mujoco_refuses_is_balanced_and_named(tmp_path):
    def edit(urdf):  # principal moments 1, 1, 3 (x 1e-7): 1 + 1 < 3
        return re.sub(r'(<link name="index_distal">\s*<inertial>.*?)<inertia [^>]*/>',
                      r'\1<inertia ixx="1e-7" ixy="0" ixz="0" iyy="1e-7" iyz="0" izz="3e-7"/>', urdf, flags=re.S)

    scene = mm.build(_edited_icub(tmp_path, edit), _far_sphere(), FRICTION, dt_s=DT)
    assert scene.balanced_links == ("index_distal",)
    moments = np.sort(scene.model.body_inertia[scene._body["index_distal"]])
    assert moments[0] + moments[1] >= moments[2]
    # the least change: the largest moment and the axes kept, the two smaller raised alike
    _, _, I = scene.link_inertia("index_distal")
    assert np.allclose(I, np.diag([1.5e-7, 1.5e-7, 3e-7]), rtol=1e-5, atol=1e-15)


# --------------------------------------------------------------------------- the object


@pytest.mark.parametrize("shape,size", [("box", [0.02, 0.04, 0.06]), ("cylinder", [0.02, 0.08]),
                                        ("sphere", [0.03]), ("mesh", [1.0]), ("mesh", [2.0, 1.0, 1.5])])
def test_object_mass_and_inertia_are_pybullets(icub, tmp_path, shape, size):
    pytest.importorskip("pybullet")
    from test_mesh_hand import cylinder_obj, write_obj

    from planner.sim.scene import object_body, p

    mesh = None
    if shape == "mesh":
        mesh = tmp_path / "cyl.obj"
        write_obj(mesh, *cylinder_obj(0.02, 0.08))
    obj = make_object(shape, size, _T([1.0, 1.0, 1.0]), mesh_path=mesh)  # no mass_kg: 500 kg/m^3
    scene = mm.build(icub, obj, FRICTION, dt_s=DT, density_kg_m3=700.0)
    assert mm.build(icub, obj, FRICTION, dt_s=DT, object_mass_kg=0.3).model.body_mass[scene._obj_body] == 0.3
    b = scene._obj_body
    mass = 700.0 * obj.volume_m3  # the replay's rule for an object without mass_kg
    assert scene.model.body_mass[b] == pytest.approx(mass) and scene.object_mass_kg == pytest.approx(mass)
    cid = p.connect(p.DIRECT)
    try:
        body = object_body(cid, shape, size, mesh, [0, 0, 0], [0, 0, 0, 1], mass, (1, 1, 1, 1))
        bullet = np.array(p.getDynamicsInfo(body, -1, physicsClientId=cid)[2])
    finally:
        p.disconnect(cid)
    assert np.allclose(scene.model.body_inertia[b], bullet, rtol=1e-6)  # (pybullet stores floats)
    assert np.allclose(scene.model.body_ipos[b], 0.0)  # centre of mass at the object's origin
    if shape == "mesh":
        assert scene.model.geom_type[scene._obj_geom] == mujoco.mjtGeom.mjGEOM_MESH


def test_object_pose_round_trips_in_xyzw(icub):
    scene = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT)
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        pos = rng.uniform(-0.5, 0.5, 3) + 1.0
        scene.set_object_pose(pos, q)
        got_p, got_q = scene.object_pose()
        assert np.allclose(got_p, pos)
        assert abs(abs(np.dot(got_q, q)) - 1.0) < 1e-12
        # the body's rotation MuJoCo computed is the quaternion's (x, y, z, w order)
        from scipy.spatial.transform import Rotation

        R = scene.data.xmat[scene._obj_body].reshape(3, 3)
        assert np.allclose(R, Rotation.from_quat(q).as_matrix(), atol=1e-12)
        assert np.allclose(scene.object_velocity()[0], 0.0)


def test_object_falls_with_g_and_the_weld_holds_it(icub):
    scene = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT, gravity=(0, 0, -G))
    z0 = scene.object_pose()[0][2]
    scene.step(240)
    t = 240 * DT
    fall = z0 - scene.object_pose()[0][2]
    assert fall == pytest.approx(G * t * t / 2, rel=0.01)
    # held: the weld is a soft constraint; at rest it sags by MuJoCo's steady state
    # r = (1 - d) dmax^2 tc^2 a0 / d^2 (a0 = g, d = dmin at a small violation)
    scene.set_object_pose([1.0, 1.0, 1.0], [0, 0, 0, 1])
    scene.hold_object()
    assert scene.holding
    scene.step(240)
    tc, _ = mm.contact_solref(DT)
    dmin, dmax = mm.HOLD_SOLIMP[:2]
    sag = (1 - dmin) * dmax ** 2 * tc ** 2 * G / dmin ** 2
    pos, quat = scene.object_pose()
    assert np.linalg.norm(pos - [1.0, 1.0, 1.0 - sag]) < 0.1 * sag
    assert abs(quat[3]) > 1 - 1e-9
    scene.release_object()
    assert not scene.holding
    scene.hold_object([1.0, 1.0, 1.5], [0, 0, 0.6, 0.8])  # at a pose: welded there
    scene.step(24)
    pos2, quat2 = scene.object_pose()
    assert np.linalg.norm(pos2 - [1.0, 1.0, 1.5 - sag]) < 0.1 * sag and abs(quat2[2] * 0.6 + quat2[3] * 0.8) > 1 - 1e-9
    scene.release_object()
    scene.step(24)
    assert pos2[2] - scene.object_pose()[0][2] > 0.9 * G * (24 * DT) ** 2 / 2


# --------------------------------------------------------------------------- contacts


def test_friction_reaches_every_hand_object_contact_as_mu_and_gamma(icub):
    obj = make_object("sphere", [0.02], _T([0, 0, 0.2]), mass_kg=0.1)
    scene = mm.build(icub, obj, Friction(0.7, 0.004), dt_s=DT)
    _on_palm(scene, (-0.0325, 0.0))
    scene.set_gravity([0, 0, -G])
    scene.step(5)
    assert scene.data.ncon >= 1
    for i in range(scene.data.ncon):
        c = scene.data.contact[i]
        assert c.dim == 4
        assert np.allclose(c.friction[:3], [0.7, 0.7, 0.004])  # (rolling: unused at condim 4)
    scene = mm.build(icub, obj, Friction(0.7, 0.0), dt_s=DT)
    assert scene.settings.condim == 3


def test_an_object_resting_on_the_palm_reports_its_weight_pushing_into_it(icub):
    """Palm up, gravity -z: every palm contact's normal points INTO the object (+z) and the
    normal forces carry its weight."""
    mass = 0.1
    obj = make_object("sphere", [0.02], _T([0, 0, 0.2]), mass_kg=mass)
    scene = mm.build(icub, obj, FRICTION, dt_s=DT)
    _on_palm(scene, (-0.0325, 0.0))
    start = scene.object_pose()[0]
    scene.set_gravity([0, 0, -G])
    scene.step(120)
    contacts = scene.contacts()
    assert contacts and all(c.link == "palm" for c in contacts)
    for c in contacts:
        assert c.normal @ [0, 0, 1] > 1 - 1e-9
        assert c.normal_force_n > 0 and c.distance_m < 0
    assert sum(c.normal_force_n for c in contacts) == pytest.approx(mass * G, rel=1e-3)
    assert np.linalg.norm(scene.object_pose()[0] - start) < 1e-4


def test_a_pressing_finger_reports_a_normal_into_the_object_and_a_positive_force(icub):
    """The index pad pressed into a held sphere: the contact's normal is the pad's outward
    normal (into the object), its force positive, and the closest-point query agrees."""
    q = np.array(icub.q_open, dtype=float)
    finger = icub.fingers["index"]
    T = icub.state(q).link_pose(finger.pad_link)
    pad = T[:3, :3] @ np.asarray(finger.pad_p_link) + T[:3, 3]
    n = T[:3, :3] @ np.asarray(finger.pad_n_link)
    r = 0.015
    obj = make_object("sphere", [r], _T(pad + n * (r + 0.002)), mass_kg=0.05)  # 2 mm off the pad
    scene = mm.build(icub, obj, FRICTION, dt_s=DT, hold=True)
    near = {c.link: c for c in scene.closest_points(0.005)}
    assert near[finger.pad_link].distance_m == pytest.approx(0.002, abs=1e-4)
    assert near[finger.pad_link].normal @ n > 0.99
    assert not [c for c in scene.contacts() if c.link == finger.pad_link]
    scene.set_object_pose(pad + n * (r - 0.0005), [0, 0, 0, 1])  # 0.5 mm into the pad
    # a geared motor's reflected inertia on the finger (the replay's armature floor): a bare
    # 1e-7 kg m^2 phalanx under 0.02 N m leaks 5 % of 2e5 rad/s^2 through its soft contact
    for link in finger.links:
        scene.raise_link_inertia(link, 1e-4)
    assert np.all(scene.model.body_inertia[scene._body[finger.pad_link]] >= 1e-4)
    scene.apply_joint_torques({j: 0.02 for j in finger.close_joints})  # closing: toward the pad normal
    scene.step(24)
    pressed = [c for c in scene.contacts() if c.link == finger.pad_link]
    assert pressed
    for c in pressed:
        assert c.normal @ n > 0.95 and c.normal_force_n > 0 and c.distance_m < 0
    # the object pushes back on the distal joint with about the commanded torque (the other
    # joints also lean on their limits; friction carries the rest)
    state = icub.state(scene.q())
    T_l = state.link_pose(finger.pad_link)
    back = 0.0
    for c in pressed:
        J = state.frame_jacobian(finger.pad_link, T_l[:3, :3].T @ (c.point_m - T_l[:3, 3]))[:3]
        back += float(J[:, icub.joint_names.index(finger.joints[-1])] @ (-c.normal * c.normal_force_n))
    assert -1.5 * 0.02 < back < -0.5 * 0.02
    near = {c.link: c for c in scene.closest_points(0.0)}
    assert near[finger.pad_link].distance_m < 0 and near[finger.pad_link].normal @ n > 0.95
    assert scene.applied_torques()[finger.close_joints[0]] == pytest.approx(0.02)


def test_torques_beyond_the_effort_limit_are_clipped(icub):
    scene = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT)
    j = icub.joint_names[1]
    scene.apply_joint_torques({j: 100.0})
    scene.step(1)
    assert scene.applied_torques()[j] == pytest.approx(float(icub.effort[1]))


@pytest.mark.parametrize("cone", ["elliptic", "pyramidal"])
def test_a_block_sticks_below_mu_and_slides_above_it_at_coulombs_rate(icub, cone):
    """A cube on the palm, gravity tilted by theta: it stays for tan(theta) = 0.8 mu; for
    1.4 mu it slides with acceleration g (sin theta - mu cos theta) (position fit over 0.2 s)."""
    mu = FRICTION.mu
    cube = make_object("box", [0.02, 0.02, 0.02], _T([0, 0, 0.2]), mass_kg=0.05)
    for ratio in (0.8, 1.4):
        scene = mm.build(icub, cube, FRICTION, dt_s=DT, cone=cone)
        _on_palm(scene, (-0.0325, -0.025))
        scene.set_gravity([0, 0, -G])
        scene.step(24)
        theta = math.atan(ratio * mu)
        scene.set_gravity([0, G * math.sin(theta), -G * math.cos(theta)])
        ys = []
        for _ in range(48):
            scene.step(1)
            ys.append(scene.object_pose()[0][1])
        t = DT * np.arange(1, 49)
        free = G * math.sin(theta) * t[-1] ** 2 / 2  # how far it would go without friction
        if ratio < 1:
            assert abs(ys[-1] - ys[0]) < 0.01 * free
        else:
            a = 2 * np.polyfit(t, ys, 2)[0]
            assert a == pytest.approx(G * (math.sin(theta) - mu * math.cos(theta)), rel=0.03)


def test_bad_arguments_are_one_line_errors(icub):
    from planner.errors import InputError, UnknownNameError

    with pytest.raises(InputError, match="dt_s"):
        mm.build(icub, _far_sphere(), FRICTION, dt_s=0.0)
    with pytest.raises(UnknownNameError, match="elliptic"):
        mm.build(icub, _far_sphere(), FRICTION, dt_s=DT, cone="round")
    scene = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT)
    with pytest.raises(UnknownNameError, match="index_1"):
        scene.set_joint_positions({"wrist": 0.1})
    with pytest.raises(UnknownNameError):
        scene.link_pose("nope")
    with pytest.raises(InputError, match="gravity"):
        scene.set_gravity([0, 0])


def test_visual_geoms_are_kept_on_request_and_never_collide(icub):
    bare = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT)
    seen = mm.build(icub, _far_sphere(), FRICTION, dt_s=DT, visual=True)
    m = seen.model
    extra = m.ngeom - bare.model.ngeom
    assert extra > 0
    visual = [g for g in range(m.ngeom) if not (m.geom_contype[g] or m.geom_conaffinity[g])]
    assert len(visual) == extra and not set(visual) & set(seen._geom_link)
    assert sorted(seen._geom_link.values()) == sorted(bare._geom_link.values())


def test_a_urdf_mimic_couples_its_joints_unless_dropped(tmp_path):
    """index_3 follows index_2 x 0.5 (a URDF <mimic>): MuJoCo keeps it as a stiff joint
    equality; ``couplings=False`` frees it, as pybullet (whose URDF loader ignores <mimic>)."""
    def edit(urdf):
        return re.sub(r'(<joint name="index_3" type="revolute">.*?)(</joint>)',
                      r'\1<mimic joint="index_2" multiplier="0.5" offset="0.0"/>\2', urdf, count=1, flags=re.S)

    hand = _edited_icub(tmp_path, edit)
    moved = {}
    for couplings in (True, False):
        scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT, couplings=couplings)
        for link in hand.fingers["index"].links:
            scene.raise_link_inertia(link, 1e-5)
        scene.apply_joint_torques({"index_2": 0.002})
        scene.step(60)
        moved[couplings] = scene.joint_positions(["index_2", "index_3"])
    assert moved[True]["index_2"] > 0.1
    assert moved[True]["index_3"] == pytest.approx(0.5 * moved[True]["index_2"], rel=0.01)
    assert abs(moved[False]["index_3"]) < 0.25 * moved[False]["index_2"]


def test_a_root_above_the_palm_is_placed_so_that_the_world_is_the_palm_frame(tmp_path):
    """A URDF whose root is a base link carrying the palm on a fixed, rotated joint: the
    base sits at T_palm_root and every link where pinocchio puts it in the palm frame."""
    def edit(urdf):
        extra = ('<link name="base"/><joint name="base_palm" type="fixed"><parent link="base"/>'
                 '<child link="palm"/><origin xyz="0.1 0.02 -0.03" rpy="0.3 -0.2 0.5"/></joint>')
        return urdf.replace("</robot>", extra + "</robot>")

    hand = _edited_icub(tmp_path, edit)
    assert hand.model.frames[1].name == "base"
    scene = mm.build(hand, _far_sphere(), FRICTION, dt_s=DT)
    assert np.allclose(scene.link_pose("palm"), np.eye(4), atol=1e-9)
    q = np.random.default_rng(11).uniform(hand.lower, hand.upper)
    scene.set_joint_positions(dict(zip(hand.joint_names, q)))
    state = hand.state(q)
    for link in ("base", "index_distal", "thumb_distal"):
        assert np.abs(state.link_pose(link) - scene.link_pose(link)).max() < 1e-6, link


def test_the_planned_contacts_of_a_plan_touch_in_mujoco_with_the_planned_normals():
    """Every state of the suite's iCub cylinder plan, its hand posed at the state's q: each
    planned contact has a link of its finger within the planner's touch tolerance of the
    object in MuJoCo, with the planned normal (object frame, into the object) within 18 deg
    (a line contact: MuJoCo's closest point may lie a few mm along the line, 8 deg round the
    19 mm cylinder). Exact touches (|d| < 0.1 um) exercise the normal from the distance's
    gradient."""
    from planner.contacts import TOUCH_TOL_M
    from planner.plan_data import plan_hand
    from planner.sim.inputs import typed_plan

    plan = typed_plan(str(Path(__file__).parent / "data/plans/schema2_cylinder_execution.json"))
    hand = plan_hand(plan)
    scene = mm.build(hand, plan.object, plan.friction, dt_s=DT)
    T = plan.object.T_palm_obj
    checked = 0
    for state in plan.states:
        scene.set_joint_positions(dict(zip(plan.joints, state.q)))
        near = scene.closest_points(TOUCH_TOL_M)
        for owner, (points, normals) in state.patches.items():
            links = hand.fingers[owner].links if owner in hand.fingers else (hand.palm_frame,)
            for p_obj, n_obj in zip(points, normals):
                p = T[:3, :3] @ p_obj + T[:3, 3]
                mine = [c for c in near if c.link in links]
                assert mine, (owner, "no link of the finger within the touch tolerance")
                c = min(mine, key=lambda c: np.linalg.norm(c.point_m - p))
                assert abs(c.distance_m) <= TOUCH_TOL_M
                assert c.normal @ (T[:3, :3] @ n_obj) > math.cos(math.radians(18))
                checked += 1
    assert checked >= 2 * len(plan.states)


def test_the_objects_angular_velocity_is_in_the_world_frame(icub):
    """A box spinning about one of its principal axes (constant spin, no gravity): one step
    turns it by exp(omega dt) applied in the world frame, omega as `object_velocity` reads it."""
    from scipy.spatial.transform import Rotation

    scene = mm.build(icub, make_object("box", [0.02, 0.03, 0.04], _T([1.0, 1.0, 1.0]), mass_kg=0.1), FRICTION,
                     dt_s=DT)
    q0 = Rotation.from_rotvec([0.3, -0.5, 0.9])
    scene.set_object_pose([1.0, 1.0, 1.0], q0.as_quat())
    scene.data.qvel[scene._obj_v + 3:scene._obj_v + 6] = [2.0, 0.0, 0.0]  # MuJoCo's: body frame
    omega = scene.object_velocity()[1]
    assert np.allclose(omega, q0.apply([2.0, 0.0, 0.0]))
    scene.step(1)
    turned = (Rotation.from_quat(scene.object_pose()[1]) * q0.inv()).as_rotvec()
    assert np.allclose(turned, omega * DT, atol=1e-9)
