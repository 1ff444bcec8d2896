"""Exp. 7 - execution benchmark: plans replayed in pybullet under every gravity direction.

Grasp pairs of both hands (icub_right, allegro_right) on spheres, boxes, cylinders, a thin
rod (4-6 mm radius) and mesh objects, in several sizes: the library pairs and size
variations of them (`experiments.common.scaled_spec`, as exp4 "points": contact points
keep their tangential position on the new surface, posture fingers are re-closed; the
object's palm-side extreme stays where it was, along the hand's ``palm_normal``). Mesh
pairs are every ``grasps/<hand>/mesh_*.yaml`` group sharing hand, object and pose.
A variant whose grasps are not force closure with one mean contact per finger (or cannot be
realized) is "invalid input", counted apart from planning failures.

Every valid pair is planned with finger paths (`planner.regrasp.plan_regrasp`): in
execution mode when the planner has it (``PlanOptions.for_execution``: link contacts by default, grip
ranking, gravity set 6), otherwise with the mean contact model and gravity palm down; the
``mode`` column says which. Each plan is replayed (`planner.sim.replay`) under the seven
directions of `planner.gravity.gravity_directions(palm_normal, 7)`: palm down, palm up,
four sideways (side_1..side_4: iCub palm +x, -x, +y, -y; Allegro +y, -y, +z, -z), off.
The CSV has one row per pair and direction (a pair not planned has one
row, direction empty): planned and plan time, passed (the replay's verdict), drift, closure
agreement (states where the simulator's closure agrees / states reached) and time.

``--engine pybullet|mujoco|both`` replays in that physics engine (`planner.sim.engine`;
default: `planner.sim.engine.default_engine`); with ``both`` every plan is replayed in each
engine, the CSV has an ``engine`` column, and the summary gives each engine's pass share
and lists every (pair, direction) on which they disagree with both verdicts.
``--replay-plans DIR`` plans nothing: it replays the plans a ``--save-plans`` run wrote
(each file's pair and variant from its name) in the engine(s), the way to compare engines
on the same plans.

``--turned`` adds held-out poses (`TURNS`), ``--heavy`` heavier objects (`HEAVY_FACTORS`).

``--contact-model link|mean`` sets execution mode's contact model (default: its own, "link":
one contact per touching link, the palm included; "mean": one per finger at its patch mean,
the model before issue 34); the validity check of the input stays "mean" either way, so both
runs plan the same pairs. ``--save-plans DIR`` writes every plan.

    python experiments/exp7_execution.py [--quick] [--max-pairs N] [--directions 1|2|6|7] [--turned] [--heavy]
        [--contact-model link|mean] [--save-plans DIR] [--engine pybullet|mujoco|both]
    python experiments/exp7_execution.py --replay-plans DIR --engine both [--max-pairs N]
    python experiments/exp7_execution.py --from-csv experiments/results/exp7_execution.csv  # re-plot
"""

from __future__ import annotations

import sys
import time
from dataclasses import fields, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import GRASPS, REPLAY_FINGER_FORCE_N, REPO, load_spec, parser, print_summary, pyplot, replot, run_tasks, save, scaled_spec, write_csv  # noqa: E402
from experiments.exp4_shape_robustness import MODES, factors  # noqa: E402

#: Library pairs (hand dir, object key) -> (initial, final) file names under grasps/<hand dir>/.
LIBRARY = {
    "icub/box": ("box_parallel_extension.yaml", "box_ir2m.yaml"),
    "icub/cylinder": ("cylinder_parallel_extension.yaml", "cylinder_ir2m.yaml"),
    "icub/sphere": ("sphere_four_finger.yaml", "sphere_ir2m.yaml"),
    "icub/pen": ("pen_palmar_pinch.yaml", "pen_writing_tripod.yaml"),
    "allegro/box": ("box_four_finger.yaml", "box_tripod.yaml"),
    "allegro/sphere": ("sphere_four_finger.yaml", "sphere_tripod.yaml"),
    "allegro/cylinder": ("cylinder_four_finger.yaml", "cylinder_tripod.yaml"),
}
#: Size variations per pair: (mode of exp4's MODES, or "uniform" for meshes; scale).
VARIANTS = {
    "icub/box": [("uniform", s) for s in (0.9, 1.0, 1.1, 1.2)] + [("x", 0.9), ("x", 1.1), ("y", 0.8), ("y", 1.2)],
    "icub/cylinder": [("uniform", s) for s in (0.9, 1.0, 1.1, 1.2)] + [("length", 0.8), ("length", 1.2)],
    "icub/sphere": [("radius", s) for s in (0.8, 0.9, 1.0, 1.1, 1.2)],
    # the pen is the thin rod: 4, 5 and 6 mm radius, 0.9 / 1.1 uniformly (4.5 / 5.5 mm)
    "icub/pen": [("radius", s) for s in (0.8, 1.0, 1.2)] + [("uniform", 0.9), ("uniform", 1.1)],
    "allegro/box": [("uniform", s) for s in (0.9, 1.0, 1.1, 1.2)] + [("y", 0.9), ("y", 1.1)],
    "allegro/sphere": [("radius", s) for s in (0.8, 0.9, 1.0, 1.1, 1.2)],
    "allegro/cylinder": [("radius", s) for s in (0.8, 1.0, 1.2)] + [("length", 0.8), ("uniform", 0.9)],
}
MESH_SCALES = (0.9, 1.0, 1.1)
#: Held-out poses (--turned): every library pair at its nominal size with the object turned
#: about its centre, (axis, degrees): "palm" is the hand's palm_normal, "tilt_1" / "tilt_2"
#: the palm-plane axes n x e_x (or n x e_y when n is along e_x) and n x tilt_1. The contact
#: points stay where they are on the object, so the fingers reach them in new postures.
TURNS = (("palm", -12.0), ("palm", 12.0), ("tilt_1", 10.0), ("tilt_2", -10.0))
#: Heavy objects (--heavy): every library pair at its nominal size and pose with the object's
#: mass times each of these, planned with no force given: the hand's joint torque limits
#: decide (10-60 g objects become 25-600 g).
HEAVY_FACTORS = (2.5, 4.0, 10.0)
#: --quick: the nominal pairs of these (3-4 replays' worth of pairs).
QUICK = ("icub/cylinder", "icub/sphere", "allegro/sphere", "icub/pen")
#: A cylinder this thin or thinner is the "rod" family.
ROD_MAX_RADIUS_M = 0.0065
INITIAL_HINTS = ("parallel_extension", "four_finger", "pinch", "power")
#: Where the plot puts replays that dropped the object (drift axis, deg).
DROPPED_DEG = 180.0


# ------------------------------------------------------------------ pairs


def mesh_pairs() -> list[tuple[str, str, str]]:
    """(key, initial, final) for every group of two ``grasps/<hand>/mesh_*.yaml`` files with
    the same hand, object and pose (initial: the name with a power-grasp hint, else the first)."""
    groups: dict[tuple, list[str]] = {}
    for path in sorted(GRASPS.glob("*/mesh_*.yaml")):
        rel = str(path.relative_to(REPO))
        try:
            s = load_spec(rel)
        except Exception:  # noqa: BLE001 - a broken file in progress elsewhere: not a pair
            continue
        o = s.object
        groups.setdefault((s.hand_ref, o.shape, o.size, o.position, o.quat_xyzw, o.mesh_path), []).append(rel)
    out = []
    for files in groups.values():
        if len(files) != 2:
            continue
        files.sort(key=lambda f: (not any(h in Path(f).stem for h in INITIAL_HINTS), f))
        hand_dir, stem = Path(files[0]).parent.name, Path(files[0]).stem
        obj = stem.split("_parallel_extension")[0].split("_four_finger")[0]
        out.append((f"{hand_dir}/{obj}", files[0], files[1]))
    return out


def pair_tasks(quick: bool, turned: bool = False, heavy: bool = False) -> list[dict]:
    tasks = []
    for key, (a, b) in LIBRARY.items():
        hand_dir = key.split("/")[0]
        ini, fin = f"grasps/{hand_dir}/{a}", f"grasps/{hand_dir}/{b}"
        if not (REPO / ini).exists() or not (REPO / fin).exists():
            continue
        variants = [("uniform" if load_spec(ini).object.shape != "sphere" else "radius", 1.0)] if quick else VARIANTS[key]
        if quick and key not in QUICK:
            continue
        for mode, s in variants:
            tasks.append({"pair": key, "initial": ini, "final": fin, "mode": mode, "scale": s})
        for axis, deg in (TURNS if turned else ()):
            tasks.append({"pair": key, "initial": ini, "final": fin, "mode": f"turn {axis}", "scale": deg})
        for k in (HEAVY_FACTORS if heavy else ()):
            tasks.append({"pair": key, "initial": ini, "final": fin, "mode": "mass", "scale": k})
    for key, ini, fin in ([] if quick else mesh_pairs()):  # meshes are not part of the quick sweep
        for s in MESH_SCALES:
            tasks.append({"pair": key, "initial": ini, "final": fin, "mode": "uniform", "scale": s})
    return tasks


def _support(obj_spec, size, direction) -> float:
    """Largest extent of the object (centred at its origin) along a palm-frame direction."""
    R = obj_spec.T_palm_obj[:3, :3]
    d = R.T @ np.asarray(direction, float)  # the direction in the object frame
    if obj_spec.shape == "box":
        return float(np.abs(d) @ (np.asarray(size) / 2.0))
    if obj_spec.shape == "cylinder":
        r, L = size
        return float(abs(d[2]) * L / 2 + r * np.sqrt(max(0.0, 1 - d[2] ** 2)))
    if obj_spec.shape == "sphere":
        return float(size[0])
    from planner.objects import load_mesh

    s = tuple(size) * 3 if len(size) == 1 else tuple(size)
    V, _ = load_mesh(obj_spec.mesh_path, s)
    return float(np.max(V @ d))


def scaled(spec, mode: str, scale: float, palm_normal):
    """The spec on the object scaled by ``scale`` in ``mode``, its palm-side extreme (along
    -``palm_normal``) kept in place; meshes: uniform scale, contact points scaled with it."""
    obj = spec.object
    if obj.shape == "mesh":
        f = (scale,) * len(obj.size)
        new = replace(spec, object=obj.replaced(size=tuple(s * scale for s in obj.size)),
                      fingers=tuple(replace(fs, point_obj=tuple(float(v) * scale for v in fs.point_obj))
                                    if fs.kind == "contact" and fs.point_obj is not None else fs for fs in spec.fingers),
                      name=f"{spec.name}_x{scale:.2f}")
    else:
        f = factors(MODES[obj.shape][mode], scale)
        new = scaled_spec(spec, f)
    n = np.asarray(palm_normal, float)
    shift = n * (_support(obj, new.object.size, -n) - _support(obj, obj.size, -n))
    return replace(new, object=new.object.replaced(position=tuple(float(v) for v in np.asarray(obj.position, float) + shift)))


def heavier(spec, factor: float):
    """The spec with its object's ``mass_kg`` (every library grasp gives it) times ``factor``."""
    obj = spec.object
    if not obj.mass_given:
        raise ValueError(f"{spec.name}: --heavy needs object.mass_kg in the grasp file")
    return replace(spec, object=obj.replaced(mass_kg=float(obj.mass_kg) * factor), name=f"{spec.name}_m{factor:g}")


def turn_axis(name: str, palm_normal) -> np.ndarray:
    """Unit axis of a `TURNS` entry in the palm frame."""
    n = np.asarray(palm_normal, float)
    n = n / np.linalg.norm(n)
    t1 = np.cross(n, (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0))
    t1 /= np.linalg.norm(t1)
    return {"palm": n, "tilt_1": t1, "tilt_2": np.cross(n, t1)}[name]


def turned(spec, axis_name: str, deg: float, palm_normal):
    """The spec with its object turned by ``deg`` about ``axis_name`` (`turn_axis`) through
    the object's centre; contact points keep their object-frame coordinates."""
    from scipy.spatial.transform import Rotation

    obj = spec.object
    R = Rotation.from_rotvec(np.radians(deg) * turn_axis(axis_name, palm_normal)) * Rotation.from_quat(obj.quat_xyzw)
    return replace(spec, object=obj.replaced(quat_xyzw=tuple(float(v) for v in R.as_quat())),
                   name=f"{spec.name}_{axis_name}{deg:+.0f}")


def family(obj) -> str:
    if obj.shape == "cylinder" and obj.size[0] <= ROD_MAX_RADIUS_M + 1e-12:
        return "rod"
    return obj.shape


def generic_direction(name: str, names: list[str]) -> str:
    """A direction name common to both hands: palm_down, palm_up, off, or side_1..side_4 in
    the order of `planner.gravity.gravity_directions` (iCub: +x, -x, +y, -y; Allegro: +y,
    -y, +z, -z of the palm frame; the hand-specific name is in the ``gravity_name`` column)."""
    if not name.startswith("side_"):
        return name
    sides = [n for n in names if n.startswith("side_")]
    return f"side_{sides.index(name) + 1}"


# ------------------------------------------------------------------ planning and replay


def plan_options(palm_normal, contact_model: str | None = None):
    """(PlanOptions, mode label, planned-for direction names): execution mode when the
    planner has it (``contact_model``: its contact model, None = execution mode's default),
    else mean contacts with gravity palm down."""
    from planner.gravity import gravity_directions
    from planner.options import PlanOptions

    if hasattr(PlanOptions, "for_execution") and "execution" in {f.name for f in fields(PlanOptions)}:
        opts = PlanOptions.for_execution(**({"contact_model": contact_model} if contact_model else {}))
        n = getattr(opts, "gravity_set", None)
        if n:
            names = [name for name, _ in gravity_directions(palm_normal, n)]
        else:
            names = ["palm_down"]
        return (opts, f"execution (gravity set {n}, rank {getattr(opts, 'rank', '?')}, contacts {opts.contact_model})",
                names)
    if contact_model not in (None, "mean"):
        raise ValueError(f"this planner has no execution mode: only --contact-model mean, got {contact_model!r}")
    down = gravity_directions(palm_normal, 1)[0][1]
    return (PlanOptions(contact_model="mean", gravity=down, max_finger_force_n=REPLAY_FINGER_FORCE_N),
            "mean + gravity palm down", ["palm_down"])


def engines_of(engine: str | None) -> tuple[str, ...]:
    """The engines of ``--engine`` (None: the default engine; "both": pybullet then mujoco)."""
    from planner.sim.verify import engines_of as verify_engines

    return verify_engines(engine)


def replay_all(plan: dict, hand, n: int, engine: str = "pybullet") -> list[tuple[str, object, float]]:
    """(direction name, ReplayReport, wall s) per direction in one engine: `replay_gravity_set`
    when the replay has it, else `replay_plan` per direction of `gravity_directions(palm_normal, n)`."""
    from planner.sim import replay as rp
    from planner.sim import verify as rv

    if hasattr(rv, "replay_gravity_set"):
        rep = rv.replay_gravity_set(plan, n, hand=hand, engine=engine)
        return [(name, r, r.wall_time_s) for name, _, r in rep.directions]
    from planner.gravity import gravity_directions

    out = []
    for name, g in gravity_directions(hand.palm_normal, n):
        t0 = time.perf_counter()
        r = rp.replay_plan(plan, hand=hand, gravity=g)
        out.append((name, r, time.perf_counter() - t0))
    return out


def plan_path(folder, pair: str, variant: str) -> Path:
    """Where ``--save-plans`` writes the plan of a pair and variant (e.g. icub_box_uniform_1.00.json)."""
    return Path(folder) / f"{pair.replace('/', '_')}_{variant.replace(' ', '_')}.json"


def task(t: dict) -> list[dict]:
    from planner.closure import apply_contact_model, grasp_closure
    from planner.grasp import load_hand
    from planner.realization import realize
    from planner.regrasp import plan_regrasp

    t0 = time.perf_counter()
    base_i, base_f = load_spec(t["initial"]), load_spec(t["final"])
    hand = load_hand(base_i.hand_ref)
    if t["mode"].startswith("turn "):
        si, sf = (turned(b, t["mode"].split()[1], t["scale"], hand.palm_normal) for b in (base_i, base_f))
    elif t["mode"] == "mass":
        si, sf = (heavier(b, t["scale"]) for b in (base_i, base_f))
    else:
        si = scaled(base_i, t["mode"], t["scale"], hand.palm_normal)
        sf = scaled(base_f, t["mode"], t["scale"], hand.palm_normal)
    row = {"pair": t["pair"], "hand": hand.name, "family": family(si.object), "shape": si.object.shape,
           "variant": f"{t['mode']} {t['scale']:.2f}", "size": " ".join(f"{v:.4f}" for v in si.object.size),
           "initial": Path(t["initial"]).name, "final": Path(t["final"]).name}
    opts, mode, planned_for = plan_options(hand.palm_normal, t.get("contact_model"))
    opts = replace(opts, workers=1)  # the sweep's own workers use the cores
    row["mode"] = mode
    row["contact_model"] = opts.contact_model
    try:
        gi, gf = realize(si, hand), realize(sf, hand)
        mi = grasp_closure(apply_contact_model(gi.patches, "mean"), gi.friction)
        mf = grasp_closure(apply_contact_model(gf.patches, "mean"), gf.friction)
        row.update(initial_metric=mi.metric, final_metric=mf.metric, missing=" ".join(gi.missing + gf.missing))
        valid = mi.is_force_closure and mf.is_force_closure
        reason = "" if valid else "not force closure with mean contacts: " + ", ".join(
            n for n, c in (("initial", mi), ("final", mf)) if not c.is_force_closure)
    except Exception as err:  # noqa: BLE001 - PlannerError, or a back end refusing the scaled object
        valid, reason = False, f"realize: {type(err).__name__}: {str(err).split(': ', 1)[-1]}"
    row["valid_input"] = valid
    if not valid:
        row.update(planned=False, reason=reason[:200], pair_time_s=time.perf_counter() - t0)
        return [row]
    tp = time.perf_counter()
    try:
        res = plan_regrasp(gi, gf, opts)
    except Exception as err:  # noqa: BLE001 - a crash (e.g. coal on meshes) is a failed plan, reported
        row.update(planned=False, plan_time_s=time.perf_counter() - tp,
                   reason=f"{type(err).__name__}: {err}".replace("\n", " ")[:200], pair_time_s=time.perf_counter() - t0)
        return [row]
    row.update(planned=True, plan_time_s=time.perf_counter() - tp, gait_steps=res.sequence.gait_steps,
               bottleneck=res.sequence.bottleneck, states=len(res.plan.states), planned_for=" ".join(planned_for))
    if t.get("save_plans"):
        from planner.plan_data import write_plan

        row["plan_file"] = str(write_plan(res.plan, plan_path(t["save_plans"], t["pair"], row["variant"])))
    return replay_rows(row, res.plan.to_dict(), hand, planned_for, t, t0)


def replay_rows(row: dict, plan, hand, planned_for, t: dict, t0: float) -> list[dict]:
    """One row per engine (``t["engines"]``) and direction of a planned pair (``row``)."""
    rows = []
    for engine in t.get("engines") or ("pybullet",):
        rows += _engine_rows(dict(row, engine=engine), plan, hand, planned_for, t, engine)
    for r in rows:
        r["pair_time_s"] = time.perf_counter() - t0
    return rows


def _engine_rows(row: dict, plan, hand, planned_for, t: dict, engine: str) -> list[dict]:
    rows = []
    try:
        reports = replay_all(plan, hand, t["directions"], engine)
    except Exception as err:  # noqa: BLE001 - the replay itself failed: reported per pair
        row.update(reason=f"replay: {type(err).__name__}: {err}".replace("\n", " ")[:200])
        return [row]
    for name, rep, wall in reports:
        agree, reached = rep.closure_agreement
        r = dict(row)
        r.update(direction=generic_direction(name, [n for n, _, _ in reports]), gravity_name=name,
                 planned_for_direction=name in planned_for, passed=bool(rep.passed),
                 dropped=bool(rep.dropped), max_drift_mm=rep.max_drift_mm, max_drift_deg=rep.max_drift_deg,
                 closure_agree=agree, closure_reached=reached,
                 closure_all_agree=bool(reached == len(rep.states) and agree == reached),
                 passed_and_agree=bool(rep.passed and reached == len(rep.states) and agree == reached),
                 sim_time_s=rep.sim_time_s, replay_time_s=wall, verdict=rep.verdict.replace("\n", " ")[:300])
        rows.append(r)
    return rows


def saved_plan_tasks(folder: Path) -> list[dict]:
    """One task per plan file a ``--save-plans`` run wrote (`plan_path`'s names), sorted."""
    tasks = []
    for path in sorted(Path(folder).glob("*.json")):
        hand_dir, rest = path.stem.split("_", 1)
        parts = rest.split("_")
        # <object>_<mode>_<scale>: the mode is one word, or "turn <axis>" (axis: palm, tilt_1, tilt_2)
        k = next(i for i, w in enumerate(parts) if w in MODE_WORDS)
        mode = f"turn {'_'.join(parts[k + 1:-1])}" if parts[k] == "turn" else parts[k]
        tasks.append({"plan_file": str(path), "pair": f"{hand_dir}/{'_'.join(parts[:k])}",
                      "variant": f"{mode} {parts[-1]}"})
    return tasks


#: The variant words of `plan_path`'s names (exp4's modes, "uniform", "turn", "mass").
MODE_WORDS = ("uniform", "x", "y", "z", "radius", "length", "turn", "mass")


def replay_task(t: dict) -> list[dict]:
    """Replay a saved plan (`saved_plan_tasks`) in the engines: rows as `task`'s."""
    from planner.plan import read_plan
    from planner.sim.inputs import plan_hand

    t0 = time.perf_counter()
    plan = read_plan(t["plan_file"])
    hand = plan_hand(plan)
    obj = plan.object
    row = {"pair": t["pair"], "hand": hand.name, "family": family(obj), "shape": obj.shape, "variant": t["variant"],
           "size": " ".join(f"{v:.4f}" for v in obj.size), "mode": "saved plan", "valid_input": True, "planned": True,
           "states": len(plan.states), "plan_file": t["plan_file"], "plan_time_s": float("nan")}
    names = [d["name"] for d in (plan.parameters.get("gravity_directions") or [])]
    row["planned_for"] = " ".join(names)
    return replay_rows(row, plan, hand, names, t, t0)


def engine_comparison(rows: list[dict]) -> dict:
    """Each engine's share of plans passing every direction, and every (pair, variant,
    direction) on which two engines' verdicts differ, with both verdicts."""
    engines = list(dict.fromkeys(r["engine"] for r in rows if r.get("engine")))
    out: dict = {}
    verdicts: dict[tuple, dict] = {}
    for r in rows:
        if r.get("direction"):
            verdicts.setdefault((r["pair"], r["variant"], r["direction"]), {})[r["engine"]] = r
    plans = sorted({(p, v) for p, v, _ in verdicts})
    for e in engines:
        ok = sum(all(rs[e]["passed"] for (p, v, _), rs in verdicts.items() if (p, v) == key and e in rs)
                 for key in plans)
        out[f"engine {e}: pass every direction"] = f"{ok}/{len(plans)} ({100 * ok / max(1, len(plans)):.1f} %)"
        out[f"engine {e}: replay wall s per direction (median)"] = (
            f"{np.median([rs[e]['replay_time_s'] for rs in verdicts.values() if e in rs]):.2f}")
    if len(engines) > 1:
        differ = [(k, rs) for k, rs in sorted(verdicts.items()) if len({bool(rs[e]["passed"]) for e in engines if e in rs}) > 1]
        out["disagreements (pair variant direction)"] = len(differ)
        for (p, v, d), rs in differ:
            out[f"  {p} {v} {d}"] = "; ".join(f"{e} {'PASS' if rs[e]['passed'] else rs[e]['verdict']}"
                                              for e in engines if e in rs)
    return out


# ------------------------------------------------------------------ summary


def summarize(rows: list[dict]) -> dict:
    """Per pair (grouped by pair + variant) and per direction pass figures."""
    pairs: dict[tuple, list[dict]] = {}
    for r in rows:
        pairs.setdefault((r["pair"], r["variant"]), []).append(r)
    n_pairs = len(pairs)
    invalid = [k for k, rs in pairs.items() if not rs[0]["valid_input"]]
    planned = {k: rs for k, rs in pairs.items() if rs[0].get("planned") and rs[0].get("direction")}
    directions = list(dict.fromkeys(r["direction"] for rs in planned.values() for r in rs))
    s = {"pairs": n_pairs, "invalid input": len(invalid), "valid": n_pairs - len(invalid),
         "planned": f"{len(planned)}/{n_pairs - len(invalid)}",
         "mode": ", ".join(sorted({r['mode'] for r in rows}))}
    if planned:
        all_dir = sum(all(r["passed"] for r in rs) for rs in planned.values())
        all_strict = sum(all(r["passed_and_agree"] for r in rs) for rs in planned.values())
        planned_for = sum(all(r["passed"] for r in rs if r["planned_for_direction"]) for rs in planned.values())
        six = sum(all(r["passed"] for r in rs if r["direction"] != "off") for rs in planned.values())
        s["pass every direction"] = f"{all_dir}/{len(planned)} ({100 * all_dir / len(planned):.1f} %)"
        s["pass every direction except off"] = f"{six}/{len(planned)} ({100 * six / len(planned):.1f} %)"
        s["pass every planned-for direction"] = f"{planned_for}/{len(planned)} ({100 * planned_for / len(planned):.1f} %)"
        s["pass + closure agrees, every direction"] = f"{all_strict}/{len(planned)} ({100 * all_strict / len(planned):.1f} %)"
        for d in directions:
            sub = [r for rs in planned.values() for r in rs if r["direction"] == d]
            ok = sum(r["passed"] for r in sub)
            agree = sum(r["closure_all_agree"] for r in sub)
            s[f"{d}"] = f"{ok}/{len(sub)} pass ({100 * ok / len(sub):.1f} %), closure agrees at every state {agree}/{len(sub)}"
        fams = sorted({rs[0]["family"] for rs in pairs.values()})
        for fam in fams:
            fp = [rs for k, rs in pairs.items() if rs[0]["family"] == fam]
            fv = [rs for rs in fp if rs[0]["valid_input"]]
            fpl = [rs for rs in fv if rs[0].get("planned") and rs[0].get("direction")]
            fa = sum(all(r["passed"] for r in rs) for rs in fpl)
            s[f"family {fam}"] = f"{len(fp)} pairs, {len(fp) - len(fv)} invalid, {len(fpl)} planned, {fa} pass every direction"
        for prefix, label in (("mass ", "heavy objects (--heavy)"), ("turn ", "held-out poses (--turned)")):
            sub = [rs for k, rs in planned.items() if str(k[1]).startswith(prefix)]
            if sub:
                s[label] = (f"{len(sub)} planned of {sum(str(k[1]).startswith(prefix) for k in pairs)}, "
                            f"{sum(all(r['passed'] for r in rs) for rs in sub)} pass every direction")
        for h in sorted({rs[0]["hand"] for rs in pairs.values()}):
            hp = [rs for rs in planned.values() if rs[0]["hand"] == h]
            ha = sum(all(r["passed"] for r in rs) for rs in hp)
            s[f"hand {h}"] = f"{len(hp)} planned, {ha} pass every direction"
        s["plan time s (median / max)"] = (f"{np.median([rs[0]['plan_time_s'] for rs in planned.values()]):.2f} / "
                                           f"{max(rs[0]['plan_time_s'] for rs in planned.values()):.2f}")
        s["replay wall s per direction (median)"] = f"{np.median([r['replay_time_s'] for rs in planned.values() for r in rs]):.2f}"
    failed_plans = [f"{k[0]} {k[1]}: {rs[0].get('reason', '')[:90]}" for k, rs in pairs.items()
                    if rs[0]["valid_input"] and not (rs[0].get("planned") and rs[0].get("direction"))]
    if failed_plans:
        s["not planned"] = "; ".join(failed_plans)
    if invalid:
        s["invalid pairs"] = ", ".join(f"{p} {v}" for p, v in invalid)
    return s


def plot(rows: list[dict], path: Path) -> None:
    plt = pyplot()
    planned = [r for r in rows if r.get("direction")]
    fams = sorted({r["family"] for r in rows})  # a family with nothing planned shows no bars
    directions = list(dict.fromkeys(r["direction"] for r in planned))
    fig, ax = plt.subplots(1, 2, figsize=(15, 4.5), gridspec_kw={"width_ratios": [3, 2]})
    w = 0.8 / max(1, len(directions))
    for j, d in enumerate(directions):
        rates, ns = [], []
        for fam in fams:
            sub = [r for r in planned if r["family"] == fam and r["direction"] == d]
            rates.append(100.0 * sum(r["passed"] for r in sub) / len(sub) if sub else np.nan)
            ns.append(len(sub))
        ax[0].bar(np.arange(len(fams)) + (j - (len(directions) - 1) / 2) * w, rates, w, label=d)
    ax[0].set_xticks(range(len(fams)))
    pairs_per_fam = {fam: len({(r["pair"], r["variant"]) for r in planned if r["family"] == fam}) for fam in fams}
    ax[0].set_xticklabels([f"{fam}\n({pairs_per_fam[fam]} planned pairs)" for fam in fams])
    ax[0].set_ylabel("replay pass rate (%)")
    ax[0].set_ylim(0, 118)
    ax[0].set_yticks(range(0, 101, 20))
    ax[0].set_title("pass rate per object family and gravity direction")
    ax[0].legend(fontsize=7, ncol=max(1, len(directions)), loc="upper center")
    for i, d in enumerate(directions):
        sub = [r for r in planned if r["direction"] == d]
        x = np.full(len(sub), i) + np.random.default_rng(i).uniform(-0.25, 0.25, len(sub))
        y = np.array([DROPPED_DEG if r["dropped"] or not np.isfinite(r["max_drift_deg"])
                      else min(max(r["max_drift_deg"], 0.1), DROPPED_DEG) for r in sub])
        ok = np.array([bool(r["passed"]) for r in sub], dtype=bool)
        drop = np.array([bool(r["dropped"]) for r in sub], dtype=bool)
        ax[1].scatter(x[ok], y[ok], c="tab:green", s=12, label="pass" if i == 0 else None)
        ax[1].scatter(x[~ok & ~drop], y[~ok & ~drop], c="tab:red", s=12, label="fail" if i == 0 else None)
        ax[1].scatter(x[drop], y[drop], c="tab:red", marker="v", s=14, label="dropped" if i == 0 else None)
    ax[1].axhline(5.0, color="k", ls="--", lw=0.8)
    ax[1].set_yscale("log")
    ax[1].set_xticks(range(len(directions)))
    ax[1].set_xticklabels(directions, rotation=30, fontsize=8)
    ax[1].set_ylabel(f"max rotation drift (deg; dropped at {DROPPED_DEG:.0f})")
    ax[1].legend(fontsize=7)
    ax[1].set_title("drift per direction (limit 5 deg)")
    save(fig, path)


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.set_defaults(workers=1)  # one pybullet replay at a time unless asked for more
    ap.add_argument("--max-pairs", type=int, default=None, help="only the first N pairs (tests)")
    ap.add_argument("--directions", type=int, default=7, choices=(1, 2, 6, 7),
                    help="gravity set size of the replays (planner.gravity; default 7: with gravity off)")
    ap.add_argument("--name", default="exp7_execution", help="CSV / PNG file stem in --out")
    ap.add_argument("--turned", action="store_true",
                    help="also the held-out poses: every library pair with its object turned (TURNS)")
    ap.add_argument("--heavy", action="store_true",
                    help="also every library pair with its object's mass times "
                         + " and ".join(f"{k:g}" for k in HEAVY_FACTORS))
    ap.add_argument("--contact-model", default=None, choices=("link", "mean"),
                    help="execution mode's contact model (PlanOptions.for_execution; default: its own, "
                         "'link' = one contact per touching link, 'mean' = one per finger at its patch mean)")
    ap.add_argument("--save-plans", type=Path, default=None, metavar="DIR",
                    help="write each plan to DIR/<hand>_<object>_<variant>.json (replayable with regrasp replay)")
    ap.add_argument("--engine", default=None, choices=("pybullet", "mujoco", "both"),
                    help="physics engine of the replays (default: pybullet when installed, else mujoco); "
                         "both: each plan in each, the disagreements listed")
    ap.add_argument("--replay-plans", type=Path, default=None, metavar="DIR",
                    help="plan nothing: replay the plans a --save-plans run wrote to DIR")
    ap.add_argument("--from-csv", type=Path, default=None,
                    help="no run: summary and plot of an existing exp7 CSV (PNG into --out/--name)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.from_csv is not None:
        return replot(args.from_csv, args.out / f"{args.name}.png", "exp7 execution", plot, summarize)
    engines = engines_of(args.engine)
    if args.replay_plans is not None:
        tasks, fn = saved_plan_tasks(args.replay_plans)[: args.max_pairs], replay_task
    else:
        tasks, fn = pair_tasks(args.quick, args.turned, args.heavy)[: args.max_pairs], task
    if args.save_plans is not None:
        args.save_plans.mkdir(parents=True, exist_ok=True)
    for t in tasks:
        t.update(directions=args.directions, contact_model=args.contact_model, engines=engines,
                 save_plans=str(args.save_plans) if args.save_plans is not None else None)
    per_pair = run_tasks(fn, tasks, args, desc="exp7 execution")
    rows = [r for rs in per_pair for r in rs]
    write_csv(args.out / f"{args.name}.csv", rows)
    first = [r for r in rows if r.get("engine", engines[0]) == engines[0]]  # the plot and summary: one engine
    plot(first, args.out / f"{args.name}.png")
    summary = summarize(first)
    if len(engines) > 1 or args.replay_plans is not None:
        summary.update(engine_comparison(rows))
    summary["mesh pairs found"] = len(mesh_pairs())
    summary["wall_s"] = time.perf_counter() - t0
    print_summary("exp7 execution", summary)
    return summary


if __name__ == "__main__":
    main()
