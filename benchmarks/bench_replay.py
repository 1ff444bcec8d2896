"""Replay speed: simulated seconds per wall-clock second, with and without GIF rendering.

A simple held-object scene: the iCub hand holds a 3 cm box in a thumb-opposing
three-finger grasp (palm down, gravity on) and lifts the index finger. Each setting
is replayed several times and the median is reported. The baseline, measured in the same
run, is pybullet alone: the same hand and box loaded and stepped for the same simulated
time with no controller, no measurement and no set-up beyond loading (the box floats free of
the fingers: no contact); and pybullet alone stepping the replay's scene itself (the hand at
the grasp, held by pybullet's position motors, the box in it under gravity: the contacts
cost a step most of its time). The ratios say how much of the replay's time the controller,
the measurements and the set-up take.

Last, the demo plan's replay in 7 gravity directions, one after the other and in one
process per core (`planner.sim.verify.replay_directions`): wall times, their ratio, and a
check that the verdicts and drifts are the same.

Run: ``.venv/bin/python benchmarks/bench_replay.py [--repeats N]``
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from planner.model import Friction
from planner.closure import grasp_closure
from planner.contacts import contact_patches
from planner.hand import Hand
from planner.objects import make_object
from planner.sim.replay import replay_plan

BOX_SIZE = (0.03, 0.03, 0.03)
BOX_POS = (0.02, -0.02, 0.025)
FRICTION = Friction(mu=0.8, gamma=0.002, edges=5)


def held_box_plan(hold_s_extra: int = 0) -> dict:
    """Plan data: three-finger grasp of a box, then a lift of the index finger."""
    hand = Hand.load("icub_right")
    names = list(hand.joint_names)
    T = np.eye(4)
    T[:3, 3] = BOX_POS
    obj = make_object("box", BOX_SIZE, T, mass_kg=0.03)
    q = hand.q_open.copy()
    q[names.index("thumb_0")] = 1.2
    for f in ("thumb", "index", "middle"):
        q = hand.close_finger(f, q, obj)
    q1 = q.copy()
    for j in hand.fingers["index"].close_joints:
        q1[names.index(j)] = max(0.0, q1[names.index(j)] - 0.35)

    def state(qv, fingers):
        patches = {f: v for f, v in contact_patches(hand, qv, obj).items() if f in fingers}
        c = grasp_closure(patches, FRICTION)
        return {"patches": {f: {"points": p.tolist(), "normals": n.tolist()} for f, (p, n) in patches.items()},
                "closure": {"is_force_closure": bool(c.is_force_closure), "metric": float(c.metric)},
                "removable": [], "q": dict(zip(names, map(float, qv)))}

    joints = list(hand.fingers["index"].joints)
    idx = [names.index(j) for j in joints]
    return {
        "schema_version": 1, "kind": "regrasp-plan",
        "hand": {"name": "icub_right", "spec": "robots/icub_right/hand.yaml"},
        "object": {"shape": "box", "size": list(BOX_SIZE), "position": list(BOX_POS), "quat_xyzw": [0, 0, 0, 1],
                   "mesh": None, "mass_kg": 0.03},
        "friction": {"mu": FRICTION.mu, "gamma": FRICTION.gamma, "edges": FRICTION.edges},
        "joints": names,
        "states": [state(q, {"thumb", "index", "middle"}), state(q1, {"thumb", "middle"})],
        "steps": [{"finger": "index", "action": "lift", "from_state": 0, "to_state": 1, "joints": joints,
                   "path": [[float(v) for v in qq[idx]] for qq in (q, q1)]}],
    }


def measure(plan: dict, repeats: int, **kwargs) -> tuple[float, float, float]:
    """(median sim-s per wall-s, median wall s, sim s) over `repeats` replays."""
    rates, walls, sim_s = [], [], 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        report = replay_plan(plan, **kwargs)
        wall = time.perf_counter() - t0
        assert report.passed, report.verdict
        rates.append(report.sim_time_s / wall)
        walls.append(wall)
        sim_s = report.sim_time_s
    return statistics.median(rates), statistics.median(walls), sim_s


def physics_only(sim_s: float, repeats: int) -> float:
    """Median sim-s per wall-s of pybullet alone: connect, load the hand and a box, step."""
    import pybullet as p

    from planner.hand import Hand

    urdf = str(Hand.load("icub_right").urdf_path)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cid = p.connect(p.DIRECT)
        p.setPhysicsEngineParameter(fixedTimeStep=1 / 240, numSolverIterations=150, physicsClientId=cid)
        p.loadURDF(urdf, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE | p.URDF_IGNORE_VISUAL_SHAPES,
                   physicsClientId=cid)
        box = p.createCollisionShape(p.GEOM_BOX, halfExtents=[s / 2 for s in BOX_SIZE], physicsClientId=cid)
        p.createMultiBody(0.03, box, basePosition=BOX_POS, physicsClientId=cid)
        for _ in range(round(sim_s * 240)):
            p.stepSimulation(physicsClientId=cid)
        p.disconnect(physicsClientId=cid)
        rates.append(sim_s / (time.perf_counter() - t0))
    return statistics.median(rates)


def physics_holding(plan: dict, sim_s: float, repeats: int) -> tuple[float, int]:
    """Median sim-s per wall-s of pybullet alone stepping the replay's scene itself: the hand
    posed at the plan's first state where the replay puts it, held there by pybullet's own
    position motors (capped at the joints' efforts), the box in the grasp with the replay's
    friction, gravity palm down, the replay's time step and solver iterations, connect and
    load included. Also the contact points at the end (the scene must touch: contacts are
    most of a step's cost)."""
    import pybullet as p
    from scipy.spatial.transform import Rotation

    from planner.sim.inputs import T_palm_root

    hand = Hand.load("icub_right")
    T = T_palm_root(hand)
    q0 = plan["states"][0]["q"]
    g = 9.81 * np.asarray(hand.palm_normal, float)
    rates, touching = [], 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        cid = p.connect(p.DIRECT)
        p.setPhysicsEngineParameter(fixedTimeStep=1 / 240, numSolverIterations=150, numSubSteps=0,
                                    deterministicOverlappingPairs=1, physicsClientId=cid)
        p.setGravity(*g.tolist(), physicsClientId=cid)
        body = p.loadURDF(str(hand.urdf_path), T[:3, 3].tolist(), Rotation.from_matrix(T[:3, :3]).as_quat().tolist(),
                          useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE | p.URDF_IGNORE_VISUAL_SHAPES,
                          physicsClientId=cid)
        idx, targets, forces = [], [], []
        for i in range(p.getNumJoints(body, physicsClientId=cid)):
            name = p.getJointInfo(body, i, physicsClientId=cid)[1].decode()
            if name in q0:
                p.resetJointState(body, i, q0[name], physicsClientId=cid)
                idx.append(i)
                targets.append(q0[name])
                forces.append(float(hand.effort[hand.joint_names.index(name)]))
        p.setJointMotorControlArray(body, idx, p.POSITION_CONTROL, targetPositions=targets, forces=forces,
                                    physicsClientId=cid)
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[s / 2 for s in BOX_SIZE], physicsClientId=cid)
        box = p.createMultiBody(0.03, shape, basePosition=BOX_POS, physicsClientId=cid)
        p.changeDynamics(box, -1, lateralFriction=FRICTION.mu, spinningFriction=FRICTION.gamma, physicsClientId=cid)
        for _ in range(round(sim_s * 240)):
            p.stepSimulation(physicsClientId=cid)
        touching = len(p.getContactPoints(body, box, physicsClientId=cid))
        p.disconnect(physicsClientId=cid)
        rates.append(sim_s / (time.perf_counter() - t0))
    return statistics.median(rates), touching


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    from planner.sim.engine import engine_installed

    if not engine_installed("pybullet"):  # its baseline is pybullet alone (Python >= 3.12 has no wheel)
        print("bench_replay: skipped, pybullet is not installed (benchmarks/bench_engines.py times the MuJoCo replay)")
        return
    plan = held_box_plan()
    with tempfile.TemporaryDirectory() as tmp:
        rows = [
            ("no rendering", {}),
            ("GIF 640x480, every 8 steps", {"gif": Path(tmp) / "a.gif", "gif_every": 8}),
            ("GIF 640x480, every step", {"gif": Path(tmp) / "b.gif", "gif_every": 1}),
        ]
        print(f"{'setting':<30} {'sim s / wall s':>15} {'wall s':>8} {'sim s':>7} {'vs physics':>11}   "
              f"(median of {args.repeats})")
        results = [(name, *measure(plan, args.repeats, **kw)) for name, kw in rows]
        base = physics_only(results[0][3], args.repeats)
        held, touching = physics_holding(plan, results[0][3], args.repeats)
        print(f"{'pybullet alone (baseline)':<30} {base:>15.2f} {results[0][3] / base:>8.3f} {results[0][3]:>7.2f} "
              f"{1.0:>10.2f}x   (no contact)")
        print(f"{'pybullet alone, holding':<30} {held:>15.2f} {results[0][3] / held:>8.3f} {results[0][3]:>7.2f} "
              f"{held / base:>10.2f}x   ({touching} contact points at the end)")
        for name, rate, wall, sim_s in results:
            print(f"{name:<30} {rate:>15.2f} {wall:>8.3f} {sim_s:>7.2f} {rate / base:>10.2f}x   "
                  f"{rate / held:.2f}x of the scene held by pybullet alone")
    print()
    directions(max(1, min(args.repeats, 3)))


def directions(repeats: int) -> None:
    """The demo's 7-direction replay (the cylinder pair planned with --execution, unverified)
    one direction after the other against one process per core; the verdicts must agree."""
    from planner.grasp import load_grasp
    from planner.gravity import gravity_directions
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.resources import bundled_grasp
    from planner.sim.verify import as_written, default_workers, replay_directions

    a, b = (realize(load_grasp(bundled_grasp(f"icub/cylinder_{n}.yaml"))) for n in ("parallel_extension", "ir2m"))
    plan = as_written(plan_regrasp(a, b, PlanOptions.for_execution(verify=False)).plan)
    dirs = gravity_directions(a.hand.palm_normal, 7)
    print(f"{'demo plan, 7 directions':<30} {'wall s':>8} {'ratio':>7}   (median of {repeats}, {default_workers()} cores)")
    base, verdicts = None, None
    for name, workers in (("one after the other", 1), ("one process per core", None)):
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            reports = replay_directions(plan, a.hand, dirs, workers=workers)
            walls.append(time.perf_counter() - t0)
        now = [(r.passed, r.max_drift_mm) for r in reports]
        assert verdicts is None or now == verdicts, "parallel replays differ from the serial ones"
        verdicts = now
        med = statistics.median(walls)
        base = base or med
        print(f"{name:<30} {med:>8.2f} {base / med:>6.2f}x")


if __name__ == "__main__":
    main()
