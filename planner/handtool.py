"""Your own hand: ``regrasp hand init URDF`` writes a hand.yaml from a URDF, ``regrasp hand
check HAND`` says what in a hand a planner or a simulator cannot use, one line each.

`init_hand` reads the kinematic tree with pinocchio and infers, saying why for each guess:

- **palm**: the URDF's root link (the body fixed to the world);
- **fingers**: one serial chain per leaf of the tree (root to leaf, movable joints only),
  named from its link and joint names (thumb, index, middle/medium, ring, little/pinky),
  else ``finger_<k>``;
- **tip and pad**: the leaf link; the pad is the point of its collision geometry farthest
  along the phalanx, on its palmar side;
- **palm normal**: the direction in which the fingers' joints, moved from the zero posture
  toward the larger part of their range (flexion: a mirrored hand's fingers flex toward
  their lower limits), carry the fingertips (summed over the fingers other than the thumb),
  snapped to a palm-frame axis within 30 deg;
- **closing joints**: the joints whose motion carries the fingertip toward the palm normal
  (the thumb's: toward the grasp's centre in front of the palm), each with its direction:
  toward its upper limit, or toward its lower one (``close_toward: {joint: lower}``) when
  moving it up carries the tip away; joints that move the tip sideways do not close;
- **open posture**: every closing joint at the end of its range away from its closing end
  (its lower limit, the upper one for a joint closing toward its lower);
- **effort**: the URDF's, unless it is a placeholder (see `check_hand`);
- **couplings**: the URDF's ``<mimic>`` joints are read by the hand itself (`planner.hand`),
  listed; a follower opens with its driver (no ``open:`` angle of its own).

`check_hand` loads the hand in pinocchio, coal and pybullet and reports inertias a simulator
cannot use (and what the replay uses instead, `replay_inertia`), missing or placeholder
effort and limits, coupled joints (with the drivers' narrowed ranges), mesh collision links
(and how they are handled), a pad that does not face the palm, and fingers that collide at
rest.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from planner.errors import SpecError
from planner.urdf_check import MAX_NAME_CHARS, name_shown

#: Finger names recognised in link and joint names, in the order a hand.yaml lists them.
FINGER_WORDS = (("thumb", ("thumb",)), ("index", ("index", "first", "ff")), ("middle", ("middle", "medium", "mf")),
                ("ring", ("ring", "rf")), ("little", ("little", "pinky", "lf")))
#: A joint effort above this multiple of what presses the fingertip with 100 x the hand's
#: own weight is a placeholder (URDF exporters write 1e4-5e4 N m for "unknown").
PLACEHOLDER_FORCE_RATIO = 100.0
#: A link inertia whose largest principal moment exceeds this multiple of the largest any
#: body of its mass inside its collision box can have (all the mass at the box's corners:
#: m |size|^2 / 4) is a placeholder: the finger would move like a flywheel. The margin
#: allows visual shells and masses larger than the collision geometry.
INERTIA_RATIO_MAX = 10.0
#: A palm normal guess within this of a palm-frame axis is snapped to it, deg.
SNAP_DEG = 30.0
#: A finger, when looking for the hands inside a robot's URDF (`hand_candidates`): a serial
#: chain (no branch) of this many moving joints, from a link to a leaf. A leg or an arm has 6-7
#: joints (and an arm branches at its hand): neither is a finger.
FINGER_JOINTS = (2, 5)
#: A URDF whose only hand has at most this many moving joints outside its sub-tree (a wrist)
#: is taken whole, those joints locked (the bundled hands' URDFs); more is a robot.
MAX_WRIST_JOINTS = 3


@dataclass
class Finding:
    """One line of `check_hand` or `init_hand`: ``level`` ("error", "warning", "ok", "guess"),
    ``what`` (the key or link), ``text``."""

    level: str
    what: str
    text: str

    def line(self) -> str:
        return f"{self.level}: {self.what}: {self.text}"


@dataclass
class HandReport:
    findings: list[Finding] = field(default_factory=list)

    def add(self, level: str, what: str, text: str) -> None:
        self.findings.append(Finding(level, what, text))

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "error"]


# --------------------------------------------------------------------------- inertia


def box_inertia(mass_kg: float, size_m) -> np.ndarray:
    """Principal moments (3,) of a solid box of this mass and size (x, y, z)."""
    x, y, z = (float(v) for v in size_m)
    return mass_kg / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])


def joint_to_link(hand, link: str):
    """T_joint_link (pin.SE3): a link's frame in its parent joint's frame, where pinocchio
    places its collision geometry. Not the identity for a link fixed to its parent, which
    pinocchio merges into the parent's joint (the Allegro's fingertip spheres, 26.7 mm beyond
    the last joint): a pad or box stated on such a link is in its own frame."""
    import pinocchio as pin  # pinocchio: loaded only when a hand's model is read

    model = hand.model
    fid = model.getFrameId(link)
    return model.frames[fid].placement if fid < len(model.frames) else pin.SE3.Identity()


def link_boxes(hand) -> dict[str, np.ndarray]:
    """Link -> size (3,) of the box holding its collision geometry, in the link's frame."""
    out: dict[str, list] = {}
    for g in hand.collision.geometries:
        shape = g.shape
        shape.computeLocalAABB()
        lo, hi = np.asarray(shape.aabb_local.min_, float), np.asarray(shape.aabb_local.max_, float)
        P = joint_to_link(hand, g.link).actInv(g.placement)  # T_link_geom
        R, t = P.rotation, P.translation
        corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
        out.setdefault(g.link, []).append(corners @ R.T + t)
    return {l: np.ptp(np.vstack(c), axis=0) for l, c in out.items()}


def replay_inertia(hand) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """The links whose URDF inertia is a placeholder -> (mass, URDF principal moments, the
    moments the replay uses instead: a solid box of the link's mass and collision size)."""
    import pinocchio as pin  # pinocchio: loaded only when a hand's model is read

    boxes = link_boxes(hand)
    out = {}
    for f in hand.model.frames:
        if f.type != pin.FrameType.BODY or f.name not in boxes or f.name in hand.stated_inertia:
            continue  # (a link without inertia has its stated one: `planner.urdf_check.stated_inertias`)
        jid = f.parentJoint
        if jid == 0:
            continue
        inertia = hand.model.inertias[jid]
        mass = float(inertia.mass)
        if mass <= 0:
            continue
        moments = np.linalg.eigvalsh(np.asarray(inertia.inertia, float))
        size = np.maximum(boxes[f.name], 1e-3)
        box = box_inertia(mass, size)
        if moments.min() <= 0 or moments.max() > INERTIA_RATIO_MAX * mass * float(size @ size) / 4.0:
            out[f.name] = (mass, moments, box)
    return out


# --------------------------------------------------------------------------- geometry helpers


def _tip_point(hand, q, link: str, p_link) -> np.ndarray:
    T = hand.state(q).link_pose(link)
    return T[:3, :3] @ np.asarray(p_link, float) + T[:3, 3]


def _finger_name(words: str, used: set, k: int) -> str:
    low = words.lower()
    for name, keys in FINGER_WORDS:
        if name in used:
            continue
        for key in keys:
            if re.search(rf"(^|[^a-z]){key}([^a-z]|$)", low) or (len(key) > 3 and key in low):
                return name
    return f"finger_{k}"


# --------------------------------------------------------------------------- init


def hand_candidates(model) -> list[tuple[str, int, int]]:
    """The links of a (pinocchio) model below which there are at least 2 fingers (serial
    chains of `FINGER_JOINTS` moving joints starting on that link's body): (link, fingers,
    moving joints outside the link's sub-tree), in the model's order. A humanoid with hands
    gives both hands; a hand URDF its palm (the root, 0 joints outside)."""
    import pinocchio as pin  # pinocchio: loaded only when a URDF is read

    children: dict[int, list[int]] = {j: [] for j in range(model.njoints)}
    for j in range(1, model.njoints):
        children[model.parents[j]].append(j)

    def finger(j: int) -> bool:
        n = 1
        while children[j]:
            if len(children[j]) != 1:
                return False
            j, n = children[j][0], n + 1
        return FINGER_JOINTS[0] <= n <= FINGER_JOINTS[1]

    def below(j: int) -> int:
        return 1 + sum(below(c) for c in children[j])

    out = []
    for j in range(model.njoints):
        n = sum(finger(c) for c in children[j])
        if n >= 2:
            link = next((f.name for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint == j), "")
            out.append((link, n, (model.njoints - 1) - (below(j) - 1)))
    return out


def _candidates_text(cands) -> str:
    return ", ".join(f"{name_shown(l)} ({n} fingers)" for l, n, _ in cands)


def init_hand(urdf, package_dirs=(), root: str | None = None, cut_path=None, output=None) -> tuple[dict, HandReport]:
    """A hand.yaml (as data) for a URDF, and the guesses made with their reasons.

    ``root``: the hand is the sub-tree below that link: its URDF (`rewritten_urdf`, the
    sub-tree only, that link its root) is written to ``cut_path`` and the hand.yaml names
    it: pinocchio, coal, pybullet and the viewer all read that file, nothing above it.
    Without ``root``, a robot's URDF (hands with more than `MAX_WRIST_JOINTS` joints outside
    them, or several hands) is refused with the candidate hands (`hand_candidates`).
    ``output``: the hand.yaml to be written, refused (`OutputError`) when it is a file the URDF
    names (a mesh), before anything is written.

    Raises:
        SpecError: the URDF fails `planner.urdf_check`, cannot be loaded, has no finger
            (no movable chain) or is a robot's; the message names the URDF as given.
    """
    import pinocchio as pin  # pinocchio: loaded only when a URDF is read

    from planner.fileio import write_atomic
    from planner.hand import _share_dirs  # pinocchio and coal (see _provisional)
    from planner.urdf_check import check_urdf, library_message, rewritten_urdf

    urdf = Path(urdf)
    source = urdf
    for d in package_dirs:  # a typo was ignored (the hand.yaml then named a folder that is not there)
        if not str(d):  # (an empty variable: the current folder was recorded in the hand.yaml)
            raise SpecError("--package-dir", "", "an empty name; give the folder holding the ROS packages of "
                            "package:// mesh paths")
        if not Path(d).is_dir():
            raise SpecError(str(d), "", "--package-dir: not a folder (a folder holding the ROS packages of "
                                        "package:// mesh paths)")
    rep = HandReport()
    dirs = [*map(str, package_dirs), *_share_dirs()]
    # our checks before pinocchio's: it hangs on a FIFO, pybullet crashes on a link with two parents
    summary = check_urdf(urdf, [str(urdf.parent), *dirs])
    mimics = summary.mimics
    if output is not None:  # a mesh of the hand is an input too (it was overwritten by the hand.yaml)
        from planner.fileio import check_outputs

        check_outputs([(output, "-o")], [str(urdf), *summary.meshes])
    try:
        model = pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as err:
        raise SpecError(str(urdf), "", f"pinocchio cannot load it: {library_message(err)}") from None
    cands = hand_candidates(model)
    if root is None:
        depth = [0] * model.njoints  # moving joints from the root to each joint, itself included
        for j in range(1, model.njoints):
            depth[j] = depth[model.parents[j]] + 1
        robot = len(cands) > 1 or (len(cands) == 1 and cands[0][2] > MAX_WRIST_JOINTS) or (
            not cands and max(depth) > FINGER_JOINTS[1] + MAX_WRIST_JOINTS)  # an arm and more: no finger
        if robot:
            found = _candidates_text(cands) or (f"none (no link with 2 fingers of {FINGER_JOINTS[0]}-{FINGER_JOINTS[1]} "
                                                "moving joints; give a gripper's base link)")
            raise SpecError(str(urdf), "", f"a robot's URDF, not a hand's ({model.njoints - 1} moving joints): "
                                           f"give the hand's link with --root LINK; hands found: {found}")
    else:
        if cut_path is None:
            raise ValueError("init_hand: root needs cut_path (where the hand's URDF is written)")
        cut_path = Path(cut_path)
        if cut_path.resolve() == urdf.resolve():
            raise SpecError(str(cut_path), "", "would overwrite the robot's URDF: write the hand.yaml elsewhere")
        text = rewritten_urdf(urdf, [str(urdf.parent), *dirs], root=root, dest_dir=cut_path.parent,
                              comment=f"written by regrasp hand init (root {root}): the sub-tree below {root} of "
                                      f"{urdf.resolve()}")
        write_atomic(cut_path, text)
        source = urdf
        rep.add("ok", "root", f"the hand is the sub-tree below {root}, written to {cut_path} (the hand.yaml's urdf); "
                              "the robot above it is left out")
        urdf = cut_path
        try:
            model = pin.buildModelFromUrdf(str(urdf))
        except (RuntimeError, ValueError) as err:
            raise SpecError(str(urdf), "", f"pinocchio cannot load it: {library_message(err)}") from None
    root_link = root
    bodies = [f for f in model.frames if f.type == pin.FrameType.BODY]
    root = next((f.name for f in bodies if f.parentJoint == 0), None)
    if root is None:
        raise SpecError(str(urdf), "", "no link is fixed to the root: no palm")
    rep.add("guess", "palm_frame", f"{root} (the URDF's root link)")
    children = {j: [] for j in range(model.njoints)}
    for j in range(1, model.njoints):
        children[model.parents[j]].append(j)
    leaves = [j for j in range(1, model.njoints) if not children[j] and model.joints[j].nq == 1]
    if not leaves:
        raise SpecError(str(urdf), "", "no movable joint chain: not a hand")
    body_of = {}
    for f in bodies:
        body_of.setdefault(f.parentJoint, f.name)
    chains, owner = [], {}
    for leaf in leaves:
        chain, j = [], leaf
        while j != 0:
            if model.joints[j].nq == 1:
                chain.append(j)
            j = model.parents[j]
        chain = chain[::-1]
        mine = [j for j in chain if j not in owner]
        shared = [model.names[j] for j in chain if j in owner]
        for j in mine:
            owner[j] = leaf
        if shared:
            rep.add("warning", model.names[leaf], f"shares {', '.join(shared)} with another finger: kept in the first "
                                                 "finger only (a joint belongs to one finger)")
        if mine:
            chains.append((leaf, mine))
    # names
    used: set = set()
    named = []
    for k, (leaf, chain) in enumerate(chains):
        words = " ".join([model.names[j] for j in chain] + [body_of.get(j, "") for j in chain])
        name = _finger_name(words, used, k)
        used.add(name)
        named.append((name, leaf, chain))
    if len(named) >= 3 and all(n.startswith("finger_") for n, _, _ in named):
        named = _name_by_geometry(model, named, rep)
    order = [n for n, _ in FINGER_WORDS]
    named.sort(key=lambda t: (order.index(t[0]) if t[0] in order else len(order), t[0]))
    # a provisional hand, to use the planner's kinematics and geometry
    fingers = {}
    for name, leaf, chain in named:
        tip = body_of.get(leaf, model.frames[-1].name)
        fingers[name] = {"joints": [model.names[j] for j in chain], "tip_frame": tip}
    name = source.stem if source.stem != "model" else source.parent.name
    name = name if root_link is None else f"{name}_{root_link}"[:MAX_NAME_CHARS]
    name = name.replace("/", "_").replace("\\", "_")  # a link name may hold one; the name names files
    spec = {"schema_version": 1, "name": name,
            "urdf": str(urdf), "palm_frame": root, "fingers": fingers}
    if package_dirs:
        spec["package_dirs"] = [str(d) for d in package_dirs]
    couplings = _dangling_mimics(mimics, fingers, rep)
    if couplings:
        spec["couplings"] = couplings
    try:
        hand = _provisional(spec, urdf)
    except SpecError as err:
        if root_link is None or err.path != str(urdf):
            raise
        # the sub-tree's URDF is removed with the refusal (`planner.commands`): said of the
        # robot's URDF the user gave, by joint (its line numbers are the sub-tree file's)
        message = re.sub(r"^line \d+: ", "", err.message)
        raise SpecError(str(source), err.key, f"the hand below {root_link}: {message}") from None
    lo, hi = np.asarray(hand.lower), np.asarray(hand.upper)
    followers = {c.joint for c in hand.couplings}
    mimicked = [c for c in hand.couplings if c.source.startswith("URDF")]
    if mimicked:
        rep.add("guess", "couplings", "the URDF's <mimic>: " + "; ".join(
            f"{c.joint} = {c.multiplier:g} {c.follows} {'+' if c.offset >= 0 else '-'} {abs(c.offset):g}"
            for c in mimicked) + ": a plan commands the drivers; followers move by the coupling")
    q_mid = np.clip(np.zeros(len(lo)), lo, hi)
    boxes = link_boxes(hand)
    # palm normal: where the joints start carrying the tips from the zero posture (a URDF's
    # zero is the extended hand): flexion moves an extended fingertip toward the palm side
    tips, moves = _tip_moves(hand, q_mid, boxes)
    # each joint toward its flexion: the side of zero with the larger part of its range (a
    # finger flexes far and hardly hyper-extends; a mirrored hand's joints flex downward),
    # none for a symmetric range (abduction)
    flex = {j: float(np.sign((hi[i] - q_mid[i]) - (q_mid[i] - lo[i]))) for i, j in enumerate(hand.joint_names)}
    sweep = sum((flex[j] * v for name, ms in moves.items() if name != "thumb" for j, v in ms), np.zeros(3))
    if np.linalg.norm(sweep) < 1e-9:
        sweep = sum((flex[j] * v for ms in moves.values() for j, v in ms), np.zeros(3))
    if np.linalg.norm(sweep) < 1e-9:
        sweep = sum((v for ms in moves.values() for _, v in ms), np.zeros(3))
    n = sweep / max(np.linalg.norm(sweep), 1e-12)
    axis = int(np.argmax(np.abs(n)))
    if math.degrees(math.acos(min(1.0, abs(float(n[axis]))))) <= SNAP_DEG:
        n = np.eye(3)[axis] * math.copysign(1.0, n[axis]) + 0.0
        why = "snapped to the nearest palm-frame axis"
    else:
        why = "not near a palm-frame axis: check it"
    spec["palm_normal"] = [float(round(v, 6)) for v in n]
    rep.add("guess", "palm_normal", f"{spec['palm_normal']}: the direction in which the fingers' joints start "
                                    "moving the fingertips from the zero posture toward the larger part of their "
                                    f"ranges (flexion) ({why})")
    # closing joints: those moving the tip toward the grasp's centre, in front of the palm
    open_q = {}
    closing = {}  # finger -> the tip's velocity as its closing joints close together (palm frame)
    for name, (close, lower, notes) in _closing_guess(hand, tips, moves, n, boxes).items():
        closing[name] = sum(((-1.0 if j in lower else 1.0) * v for j, v in moves[name] if j in close), np.zeros(3))
        fingers[name]["close_joints"] = close
        if lower:
            fingers[name]["close_toward"] = {j: "lower" for j in lower}
        down = f"; {', '.join(lower)} close toward their lower limit (close_toward)" if lower else ""
        rep.add("guess", f"fingers.{name}", f"joints {fingers[name]['joints']}, closing {close} (toward the grasp's "
                "centre in front of the palm)" + down + (f"; {'; '.join(notes)}" if notes else ""))
        for j in close:  # open: the closing joints at the end of their range away from closing
            i = hand.joint_names.index(j)
            end = float(hi[i]) if j in lower else float(lo[i])
            if end != 0.0 and j not in followers:  # a follower opens with its driver
                open_q[j] = end
    if open_q:
        spec["open"] = open_q
    # contact links and pads
    for name, fg in hand.fingers.items():
        links = list(fg.links)
        if not links:
            rep.add("error", f"fingers.{name}", "no link of the finger has collision geometry: it cannot touch")
            continue
        fingers[name]["contact_links"] = links
        tip_link = links[-1]
        sphere = _sphere_pad(hand, tip_link, closing.get(name), q_mid)
        p, normal = sphere if sphere is not None else _pad(hand, tip_link, boxes, n, q_mid)
        fingers[name]["pad"] = {"link": tip_link, "point": [float(round(v, 6)) for v in p],
                                "normal": [float(round(v, 6)) for v in normal]}
        rep.add("guess", f"fingers.{name}.pad", f"on {tip_link}: " + (
            "the point of its collision sphere the tip moves toward as the finger closes" if sphere is not None else
            "the point of its collision box farthest along the phalanx, on the side facing the palm normal"))
    # effort
    effort = _placeholder_effort(hand, boxes)
    if effort is not None:
        spec["effort"] = effort
        rep.add("guess", "effort", f"{effort} N m for every joint: the URDF's efforts are placeholders "
                                   f"(up to {float(np.max(hand.effort)):g} N m); replace with your motors' stall torque")
    return spec, rep


#: Joint step (rad, or m) over which `_tip_moves` measures how a joint moves its fingertip.
TIP_STEP = 0.05


def _tip_moves(hand, q_mid, boxes) -> tuple[dict, dict]:
    """Each finger's tip point at ``q_mid`` (palm frame: the far end of its last link's
    collision box) and, per joint, the tip's velocity as the joint moves toward its upper
    limit (finite difference over `TIP_STEP`, taken downward at the upper limit):
    ({finger: (3,)}, {finger: [(joint, (3,)), ...]})."""
    lo, hi = np.asarray(hand.lower), np.asarray(hand.upper)
    tips, moves = {}, {}
    for name, fg in hand.fingers.items():
        tip_link = fg.links[-1] if fg.links else fg.tip_frame
        p_tip = _far_point(hand, tip_link, boxes)
        tips[name] = _tip_point(hand, q_mid, tip_link, p_tip)
        for j in fg.joints:
            i = hand.joint_names.index(j)
            qb = q_mid.copy()
            sign = 1.0 if q_mid[i] + TIP_STEP <= hi[i] else -1.0
            qb[i] = q_mid[i] + sign * TIP_STEP
            v = sign * (_tip_point(hand, qb, tip_link, p_tip) - tips[name]) / TIP_STEP  # toward the upper limit
            moves.setdefault(name, []).append((j, v))
    return tips, moves


def _closing_guess(hand, tips, moves, n, boxes) -> dict[str, tuple[list, list, list]]:
    """Per finger (closing joints, those of them closing toward their lower limit, notes):
    a joint closes when its motion carries the tip toward the palm's side ``n`` (the thumb:
    toward the grasp's centre in front of the palm, where it opposes the fingers), cos > 0.5
    with it, upward when moving it up does so, downward when moving it up carries the tip
    away (cos < -0.5); else it moves the tip sideways (abduction, opposition) and does not."""
    lengths = _finger_lengths(hand, boxes)
    centre = np.mean(list(tips.values()), axis=0) + 0.5 * float(np.mean(list(lengths.values()))) * n
    out = {}
    for name, ms in moves.items():
        close, lower, notes = [], [], []
        to_c = centre - tips[name] if name == "thumb" else np.array(n, dtype=float)
        to_c /= max(np.linalg.norm(to_c), 1e-12)
        for j, v in ms:
            size = float(np.linalg.norm(v))
            along = float(v @ to_c) / size if size > 1e-9 else 0.0
            if along > 0.5:
                close.append(j)
            elif along < -0.5:
                close.append(j)
                lower.append(j)
            else:
                notes.append(f"{j} moves the tip sideways (abduction or opposition)")
        if not close:
            close = [j for j, _ in ms]
            notes.append("no joint carries the tip toward the grasp's centre: every joint closes")
        close, lower = _one_way_per_driver(hand.fingers[name], close, lower, notes)
        out[name] = (close, lower, notes)
    return out


def _one_way_per_driver(finger, close: list, lower: list, notes: list) -> tuple[list, list]:
    """(closing joints, the joints the closing procedure moves toward their lower limit) for
    ``close`` and its joints found to close downward (``lower``): the procedure moves drivers
    (`planner.hand.Finger.driver_closing`), so a coupled follower's direction becomes its
    driver's (reversed by a negative multiplier); a follower that would move its closing
    driver the other way is dropped, with a note (the driver's direction wins)."""
    driver = {finger.joints[fl]: (finger.joints[d], m) for fl, d, m, _ in finger.coupled}
    sign = {j: (-1.0 if j in lower else 1.0) for j in close}
    moved: dict[str, float] = {j: sign[j] for j in close if j not in driver}
    kept = []
    for j in close:
        d, m = driver.get(j, (j, 1.0))
        s = sign[j] if m > 0 else -sign[j]
        if moved.setdefault(d, s) != s:
            notes.append(f"{j} follows {d} (x {m:g}), which closes the other way: not a closing joint")
            continue
        kept.append(j)
    return kept, [j for j in finger.joints if moved.get(j, 1.0) < 0]


def _name_by_geometry(model, named, rep: HandReport):
    """Names for fingers whose link and joint names say nothing (``joint_12.0``): the thumb is
    the finger whose base lies off the line the other bases (the knuckles) lie on (3x
    farther than the farthest of them, and 1 mm), the
    others index, middle, ring, little along the knuckle line from the end nearer the thumb."""
    import pinocchio as pin  # pinocchio: loaded only when a URDF is read

    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    base = {leaf: np.asarray(data.oMi[chain[0]].translation, float) for _, leaf, chain in named}
    fit = {}
    for _, leaf, _ in named:  # the other bases on a line (the knuckles), this one off it
        others = np.array([base[l] for _, l, _ in named if l != leaf])
        c = others.mean(axis=0)
        u = np.linalg.svd(others - c)[2][0]
        off = [float(np.linalg.norm((o - c) - ((o - c) @ u) * u)) for o in others]
        r = base[leaf] - c
        fit[leaf] = (max(off), float(np.linalg.norm(r - (r @ u) * u)))
    thumb = min(fit, key=lambda l: fit[l][0])
    if fit[thumb][1] < 3.0 * fit[thumb][0] + 1e-3:
        return named
    # along the knuckle line, from the end nearer the thumb
    others = np.array([base[l] for l in fit if l != thumb])
    c = others.mean(axis=0)
    u = np.linalg.svd(others - c)[2][0]
    if (base[thumb] - c) @ u < 0:
        u = -u
    rest = sorted((l for l in fit if l != thumb), key=lambda l: -float((base[l] - c) @ u))
    names = {thumb: "thumb", **{l: n for l, n in zip(rest, ("index", "middle", "ring", "little"))}}
    rep.add("guess", "finger names", "the link and joint names name no finger: thumb is the finger whose base lies "
            "off the line of the others' (the knuckles), then index, middle, ring, little along that line from the "
            "end nearer the thumb")
    return [(names.get(leaf, name), leaf, chain) for name, leaf, chain in named]


def _dangling_mimics(mimics, fingers: dict, rep: HandReport) -> list[dict]:
    """hand.yaml couplings for the URDF's ``<mimic>`` elements that name no joint of it (a
    published robot's ``joint="index_q1"`` for its ``Right_index_q1``): the follower's finger's
    one other joint whose name ends with that name, else the mimic is ignored with a warning."""
    finger_of = {j: name for name, f in fingers.items() for j in f["joints"]}
    out = []
    for m in mimics:
        if m.follows_type is not None or m.joint not in finger_of:
            continue
        same = [j for j in fingers[finger_of[m.joint]]["joints"] if j != m.joint and j.endswith(m.follows)]
        if len(same) != 1:
            rep.add("warning", "couplings", f"the URDF's <mimic> of {m.joint} (line {m.line}) follows "
                    f"{name_shown(m.follows)}, no joint of the URDF: ignored; state it in the hand.yaml's couplings:")
            continue
        out.append({"joint": m.joint, "follows": same[0], "multiplier": m.multiplier, "offset": m.offset})
        rep.add("guess", "couplings", f"{m.joint} = {m.multiplier:g} {same[0]} {'+' if m.offset >= 0 else '-'} "
                f"{abs(m.offset):g}: the URDF's <mimic> (line {m.line}) names {name_shown(m.follows)}, no joint of it; "
                f"{same[0]} is the finger's joint whose name ends so")
    return out


def _provisional(spec: dict, urdf: Path):
    """The hand `init_hand` is writing, loaded to use the planner's kinematics and geometry:
    `Hand` takes the spec as data (no file), its paths made absolute (the URDF's and the
    ``package_dirs``, given relative to the working directory). Its errors name the URDF as
    the user gave it (the hand.yaml is not written yet)."""
    from planner.hand import Hand  # pinocchio and coal: loaded only when a hand is built (`regrasp --help` imports this module)

    data = dict(spec)
    data["urdf"] = str(Path(spec["urdf"]).resolve())
    if spec.get("package_dirs"):
        data["package_dirs"] = [str(Path(d).resolve()) for d in spec["package_dirs"]]
    unwritten = Path(data["urdf"]).with_name("hand.yaml")
    try:
        return Hand(unwritten, data)
    except SpecError as err:
        if err.path != str(unwritten):
            raise
        # a URDF problem (key "urdf") is said as is; a guess the hand refuses names its key
        message = err.message.removeprefix(f"{data['urdf']}: ")
        raise SpecError(str(urdf), "" if err.key == "urdf" else f"guessed {err.key}", message) from None


def _far_point(hand, link: str, boxes) -> np.ndarray:
    """A point at the far end of a link's collision box along the link's longest axis (the
    phalanx direction; its sign away from the joint)."""
    size = boxes.get(link)
    if size is None:
        return np.zeros(3)
    centre = _box_centre(hand, link)
    T = joint_to_link(hand, link)
    away = T.rotation.T @ np.asarray(T.translation, float)  # from the joint to the link's origin, link frame
    sphere = _one_sphere(hand, link)
    if sphere is not None and float(np.linalg.norm(away)) > 1e-9:
        # a round tip fixed beyond its joint (a sphere: no longest axis): its far end along
        # the phalanx, the direction from the joint to it
        return centre + float(sphere.shape.radius) * away / float(np.linalg.norm(away))
    k = int(np.argmax(size))
    p = centre.copy()
    p[k] += math.copysign(size[k] / 2.0, centre[k] if abs(centre[k]) > 1e-9 else 1.0)
    return p


def _box_centre(hand, link: str) -> np.ndarray:
    """The mean of a link's collision shapes' bounding-sphere centres, in the link's frame."""
    pts = []
    for g in hand.collision.geometries:
        if g.link == link:
            pts.append(np.asarray(joint_to_link(hand, link).actInv(np.asarray(g.center, float)), float))
    return np.mean(pts, axis=0) if pts else np.zeros(3)


def _one_sphere(hand, link: str):
    """The link's collision geometry when it is one sphere (a round fingertip), else None."""
    import coal

    shapes = [g for g in hand.collision.geometries if g.link == link]
    return shapes[0] if len(shapes) == 1 and isinstance(shapes[0].shape, coal.Sphere) else None


def _sphere_pad(hand, link: str, closing, q) -> tuple[np.ndarray, np.ndarray] | None:
    """Pad point and outward normal (link frame) of a distal link whose collision geometry is
    one sphere (a round fingertip: the Allegro's), else None: the point of the sphere the tip
    moves toward as the finger closes (``closing``, palm frame, at ``q``), the normal snapped
    to the nearest link axis within `SNAP_DEG`. A box's rule (`_pad`: 3/4 along its longest
    axis) has no longest axis on a sphere: it put the Allegro's pads on the sphere's side."""
    g = _one_sphere(hand, link)
    if g is None or closing is None or float(np.linalg.norm(closing)) < 1e-9:
        return None
    R = hand.state(q).link_pose(link)[:3, :3]
    d = R.T @ (np.asarray(closing, float) / float(np.linalg.norm(closing)))
    axis = int(np.argmax(np.abs(d)))
    if math.degrees(math.acos(min(1.0, abs(float(d[axis]))))) <= SNAP_DEG:
        d = np.eye(3)[axis] * math.copysign(1.0, d[axis])
    centre = np.asarray(joint_to_link(hand, link).actInv(g.placement).translation, float)  # T_link_geom origin
    return centre + float(g.shape.radius) * d, d


def _pad(hand, link: str, boxes, palm_normal, q) -> tuple[np.ndarray, np.ndarray]:
    """Pad point and outward normal (link frame) of a distal link: 3/4 of the way along its
    box's longest axis, on the box face whose outward normal points most along the palm
    normal's opposite... i.e. toward the object held in front of the palm."""
    size = boxes[link]
    centre = _box_centre(hand, link)
    k = int(np.argmax(size))
    T = hand.state(q).link_pose(link)
    R = T[:3, :3]
    # the object sits on the palm-normal side of the palm; a closed finger's pad faces back
    # toward the palm: at the open posture the pad faces the palm normal's side
    best, face = -np.inf, None
    for ax in range(3):
        if ax == k:
            continue
        for s in (-1.0, 1.0):
            nrm = np.zeros(3)
            nrm[ax] = s
            score = float((R @ nrm) @ palm_normal)
            if score > best:
                best, face = score, (ax, s)
    ax, s = face
    p = centre.copy()
    p[k] += math.copysign(0.25 * size[k], centre[k] if abs(centre[k]) > 1e-9 else 1.0)
    p[ax] += s * size[ax] / 2.0
    normal = np.zeros(3)
    normal[ax] = s
    return p, normal


def _finger_lengths(hand, boxes) -> dict[str, float]:
    return {name: float(sum(np.max(boxes[l]) for l in fg.links if l in boxes)) or 0.05
            for name, fg in hand.fingers.items()}


def _hand_weight_n(hand) -> float:
    return 9.81 * float(sum(hand.model.inertias[j].mass for j in range(hand.model.njoints)))


def _placeholder_effort(hand, boxes) -> float | None:
    """A joint torque (N m) when every URDF effort is a placeholder, else None: a finger
    whose efforts press its tip with more than `PLACEHOLDER_FORCE_RATIO` x the hand's weight.
    The replacement presses each fingertip with the hand's weight... at least 0.1 N m."""
    eff = np.asarray(hand.effort, float)
    if not np.all(np.isfinite(eff)):
        return _suggested_effort(hand, boxes)
    lengths = _finger_lengths(hand, boxes)
    w = max(_hand_weight_n(hand), 0.1)
    ratio = max(float(np.max(eff)) / lengths[f] / w for f in hand.fingers)
    return _suggested_effort(hand, boxes) if ratio > PLACEHOLDER_FORCE_RATIO else None


def _suggested_effort(hand, boxes) -> float:
    """Torque pressing the longest finger's tip with 5 N (a human fingertip's comfortable
    pinch): an order of magnitude to start from, not a motor's rating."""
    L = max(_finger_lengths(hand, boxes).values())
    return float(round(max(0.1, 5.0 * L), 2))


# --------------------------------------------------------------------------- check


def _check_couplings(hand, rep: HandReport) -> None:
    """The coupled joints (`planner.hand.Coupling`): each with its source, the drivers whose
    range the coupling narrows, the followers whose own effort limit is not used."""
    if not hand.couplings:
        return
    ix = hand.joint_names.index
    rep.add("ok", "couplings", f"{len(hand.couplings)} coupled joint(s): "
            + "; ".join(f"{c.joint} = {c.multiplier:g} {c.follows} {'+' if c.offset >= 0 else '-'} {abs(c.offset):g} "
                        f"({c.source})" for c in hand.couplings)
            + ": a plan commands the drivers; followers move by the coupling")
    for c in hand.couplings:
        d = ix(c.follows)
        if hand.upper[d] - hand.lower[d] <= 1e-9:  # as a URDF joint whose limits are equal: it cannot move
            f = ix(c.joint)
            rep.add("error", f"joint {c.follows}",
                    f"range [{hand.lower[d] + 0.0:.4g}, {hand.upper[d] + 0.0:.4g}]: {c.joint} = {c.multiplier:g} "
                    f"{c.follows} {'+' if c.offset >= 0 else '-'} {abs(c.offset):g} ({c.source}) is within its own "
                    f"limits [{hand.urdf_lower[f]:.4g}, {hand.urdf_upper[f]:.4g}] at one angle of {c.follows} only: "
                    "check the coupling's multiplier and offset")
        elif hand.lower[d] > hand.urdf_lower[d] + 1e-12 or hand.upper[d] < hand.urdf_upper[d] - 1e-12:
            rep.add("ok", f"joint {c.follows}", f"range [{hand.lower[d]:.4g}, {hand.upper[d]:.4g}] (URDF "
                    f"[{hand.urdf_lower[d]:.4g}, {hand.urdf_upper[d]:.4g}]): where {c.joint} stays within its limits")
    unused = [c.joint for c in hand.couplings if hand.effort_source[ix(c.joint)] != "none"]
    if unused:
        rep.add("ok", "effort", f"{', '.join(unused)}: effort limit not used (a follower has no actuator): a "
                                "follower's torque loads its driver's actuator, tau_driver + multiplier x tau_follower "
                                "within the driver's limit")


def _check_closing(hand, boxes, rep: HandReport) -> None:
    """A closing joint whose ``close_toward`` (default upper) is the other end than the one
    `hand init` would guess from the geometry (`_closing_guess`, with the hand's palm normal):
    one warning each, with the fix. A finger for which the geometry decides nothing (no joint
    carries its tip toward the palm's side) is not judged."""
    lo, hi = np.asarray(hand.lower), np.asarray(hand.upper)
    tips, moves = _tip_moves(hand, np.clip(np.zeros(len(lo)), lo, hi), boxes)
    for name, (close, lower, notes) in _closing_guess(hand, tips, moves, np.asarray(hand.palm_normal), boxes).items():
        if any("every joint closes" in t for t in notes):
            continue
        fg = hand.fingers[name]
        for j in fg.close_joints:
            want = "lower" if j in lower else "upper"
            if j in close and fg.closes_toward(j) != want:
                where = "the grasp's centre" if name == "thumb" else "the palm's side"
                rep.add("warning", f"fingers.{name}.close_toward",
                        f"{j} closes toward its {fg.closes_toward(j)} limit, but moving it toward its {want} limit "
                        f"carries the fingertip toward {where}: give close_toward: {{{j}: {want}}} and its open angle "
                        f"at the {fg.closes_toward(j)} end (hand init writes both)")


def check_hand(ref) -> HandReport:
    """What a planner or a simulator cannot use in a hand (see the module's docstring)."""
    from planner.hand import Hand  # pinocchio and coal: loaded only when a hand is built (`regrasp --help` imports this module)

    rep = HandReport()
    hand = Hand.load(ref)
    rep.add("ok", "pinocchio", f"{hand.urdf_path}: {len(hand.joint_names)} joints, fingers {', '.join(hand.fingers)}")
    boxes = link_boxes(hand)
    # limits and efforts
    for j, lo, hi, src in zip(hand.joint_names, hand.urdf_lower, hand.urdf_upper, hand.effort_source):
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi - lo <= 1e-9:
            rep.add("error", f"joint {j}", f"limits [{lo:g}, {hi:g}]: give the URDF joint a <limit lower upper>")
        if src == "none":
            rep.add("warning", f"joint {j}", "no effort limit (URDF <limit effort> 0 or absent): the grip model "
                                             "cannot bound its torque; add `effort:` to the hand.yaml")
    _check_couplings(hand, rep)
    eff = _placeholder_effort(hand, boxes)
    if eff is not None and any(s == "urdf" for s in hand.effort_source):
        rep.add("warning", "effort", f"the URDF's efforts (up to {float(np.nanmax(np.where(np.isfinite(hand.effort), hand.effort, np.nan))):g} "
                                     f"N m) press a fingertip with over {PLACEHOLDER_FORCE_RATIO:g}x the hand's weight: "
                                     f"placeholders; add `effort: {eff}` (your motors' stall torque) to the hand.yaml")
    # inertias
    for link, (mass, moments, box) in sorted(replay_inertia(hand).items()):
        rep.add("warning", f"link {link}", f"inertia {moments.max():.3g} kg m^2 for {mass:.3g} kg (a solid box of its "
                                           f"collision size: {box.max():.3g}): a placeholder; the replay uses the box's "
                                           f"[{', '.join(f'{v:.3g}' for v in box)}] kg m^2")
    # links without inertia
    if hand.stated_inertia:
        from planner.urdf_check import MIN_STATED_MASS_KG, STATED_DENSITY_KG_M3

        given = ", ".join(f"{l} {m * 1000:.3g} g" for l, (m, _) in sorted(hand.stated_inertia.items()))
        rep.add("warning", "inertia", f"{len(hand.stated_inertia)} link(s) without <inertial> (or of mass 0): {given}: "
                                      f"every command gives each the mass of its collision shapes at "
                                      f"{STATED_DENSITY_KG_M3:g} kg/m^3 (at least {MIN_STATED_MASS_KG * 1000:g} g) at "
                                      "its origin, a solid box's inertia of its collision size (pybullet alone would "
                                      "give each 1 kg); add an <inertial> to the URDF to say otherwise")
    # meshes
    meshes = sorted({g.link for g in hand.collision.geometries if type(g.shape).__name__.startswith("Convex")})
    if meshes:
        rep.add("ok", "collision", f"{len(meshes)} mesh link(s) ({', '.join(meshes[:6])}{'...' if len(meshes) > 6 else ''})"
                                   ": planned with their convex hulls (coal), simulated with pybullet's hulls")
    _check_closing(hand, boxes, rep)
    # pads facing the palm normal's side at the open posture
    n = np.asarray(hand.palm_normal, float)
    q_open = np.asarray(hand.q_open, float)
    for name, fg in hand.fingers.items():
        if not fg.contact_links:  # as hand init says: such a finger never touches the object
            rep.add("error", f"fingers.{name}", "no link of the finger has collision geometry: it cannot touch; give "
                                                "its links <collision> shapes in the URDF")
        if fg.pad_n_link is None:
            rep.add("warning", f"fingers.{name}.pad", "no normal: IK places the tip without orienting the pad; "
                                                      "give pad: {link, point, normal}")
            continue
        R = hand.state(q_open).link_pose(fg.pad_link)[:3, :3]
        c = float((R @ np.asarray(fg.pad_n_link)) @ n)
        if c < 0.0 and name != "thumb":
            rep.add("warning", f"fingers.{name}.pad", f"its normal points away from the palm's side at the open posture "
                                                      f"(cos {c:+.2f} with palm_normal): check pad.normal")
    # collisions at rest
    for a, b, depth in hand.state(q_open).self_collisions():
        rep.add("warning", "open posture", f"links {a} and {b} overlap by {depth * 1000:.1f} mm: move the open "
                                           "posture or add the pair to disabled_collisions")
    # the replay's engine (pybullet when installed, else MuJoCo) loads the URDF
    from planner.sim.engine import default_engine

    engine = default_engine()
    problem = _pybullet_problem(hand) if engine == "pybullet" else _mujoco_problem(hand)
    if problem:
        rep.add("error", engine, problem)
    else:
        rep.add("ok", engine, "loads the URDF with every joint")
    return rep


def _pybullet_problem(hand) -> str | None:
    """Why pybullet cannot simulate the hand (one line), or None."""
    from planner.sim.scene import urdf_problem  # pybullet: loaded only for this check

    return urdf_problem(str(hand.urdf_path), hand.joint_names)


def _mujoco_problem(hand) -> str | None:
    """Why MuJoCo cannot simulate the hand (one line), or None: the replay's scene built
    around a small sphere (any object: only the hand's compile and joints are checked)."""
    from planner.errors import SimulationError
    from planner.model import Friction
    from planner.objects import make_object
    from planner.sim.mujoco_model import build  # MuJoCo: loaded only for this check

    try:
        model = build(hand, make_object("sphere", (0.01,)), Friction(0.5, 0.0), dt_s=1e-3).model
    except SimulationError as err:
        return str(err)
    missing = []
    for j in hand.joint_names:
        try:
            model.joint(j)
        except KeyError:
            missing.append(j)
    return f"joints {missing[:4]} are not in the URDF MuJoCo loads" if missing else None
