"""Exp. 8 - the planner's coverage: random pairs of synthesized grasps, planned three ways.

Issue 14's regrasp benchmark. For both hands (icub_right, allegro_right) and objects of
several shapes and sizes (spheres of 15-30 mm radius, boxes, cylinders, a 5 mm rod), the
object gets ONE pose per hand (so any two grasps of it form a regrasp pair): the pose of the
first grasp `planner.synth` finds with the object pose sampled (largest finger set first).
Every grasp is synthesized **execution-ready** (`execution_ready`): force closure with one mean
contact per finger too, and holding the object's weight in the six gravity directions of
execution mode within the hand's joint torque limits and 3/4 of the friction (twice the
weight, `planner.grip`), with the object at least the replay's drift limit (5 mm) from the
palm, so that a pair's failure in execution mode is the planner's, not a grasp execution
mode refuses outright.
With that pose fixed, `planner.synth` (seeded) writes up to ``GRASPS_PER_SET`` grasps for
each finger set of the hand (e.g. thumb-index-middle, thumb-index-middle-ring, all fingers);
the grasp that gave the pose joins its set as rank 0 (a near-duplicate of it may too).
Pairs (initial, final) of distinct grasps of the same object are drawn, seeded, preferring
different finger sets; each pair is planned (`planner.regrasp.plan_regrasp`, finger paths on):

- **default**: `PlanOptions()` - the anytime planner: intermediate contacts in rounds within
  its default time limit;
- **graph**: `PlanOptions(intermediate=0, time_limit_s=0)` - the thesis's graph of the two
  grasps' contacts only, no intermediate contacts;
- **execution**: `PlanOptions.for_execution(gravity_set=N)` (mean contacts, grip ranking,
  friction reserve; ``--execution-set N``: 6 by default, 1 plans for palm down only, 2 for
  palm down and up), and that plan replayed in pybullet under the 7 gravity directions of
  `planner.gravity` (`experiments.exp7_execution.replay_all`). The grasps are synthesized
  execution-ready for set 6 whatever N, so runs with different N plan the same pairs.

The CSV has one row per pair: solved and time per mode, gait steps, intermediate contacts
added, execution pass per direction (palm down, palm up, side_1..4, off; generic names as in
exp7), and ``reason``: one line saying why the pair fell short (the first of: default not
solved, execution not planned, replay failed in a direction), empty when everything passed.
Also: ``execution_set`` (N), ``planned_for`` (the generic names of the N directions the
execution plan was made for), ``exec_planned_for`` (the replay passed in every one of them
that was replayed; gravity off is ``exec_off``, never planned for), ``planned_for_fail`` (the
first failing verdict among them), ``verdict_<direction>`` (each replay's verdict line) and,
with ``--save-plans DIR``, ``plan_file``: the execution plan written (`planner.plan_data.write_plan`,
JSON, replayable with ``regrasp replay``) to DIR/<hand>_<object>_<pair>.json, the object label
with ``_`` for spaces and the pair numbered from 1 per hand and object as in the ``pair`` column.

``--save-grasps FILE`` writes the poses and grasps synthesized (JSON); ``--grasps-from FILE``
plans the pairs of such a file instead of synthesizing (the same pairs under another commit's
planner: the pairs are drawn from the grasps with ``--seed`` as always).

``--quick`` (tests, seconds): the Allegro on the 30 mm-radius ball, two finger sets, one pair, straight
joint-space finger paths instead of OMPL (``--no-motion``).

    python experiments/exp8_random_pairs.py [--quick] [--workers N] [--pairs-per-object K] [--directions 1|2|6|7] [--no-motion]
        [--execution-set 1|2|6] [--save-plans DIR] [--save-grasps FILE | --grasps-from FILE]
    python experiments/exp8_random_pairs.py --from-csv experiments/results/exp8_random_pairs.csv   # re-plot
"""

from __future__ import annotations

import inspect
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import parser, print_summary, pyplot, replot, run_tasks, save, write_csv  # noqa: E402
from experiments.exp7_execution import family, generic_direction, replay_all  # noqa: E402

#: Finger sets per hand, the largest first (the pose is taken from the first that yields a grasp).
FINGER_SETS = {
    "icub_right": ("thumb,index,middle,ring,little", "thumb,index,middle,ring", "thumb,index,middle"),
    "allegro_right": ("thumb,index,middle,ring", "thumb,index,middle", "thumb,middle,ring"),
}
#: (label, object block without pose); masses 10-60 g (the library's balls weigh 50 g).
OBJECTS = (
    ("sphere r15", {"shape": "sphere", "size": [0.015], "mass_kg": 0.02}),
    ("sphere r22", {"shape": "sphere", "size": [0.022], "mass_kg": 0.03}),
    ("sphere r30", {"shape": "sphere", "size": [0.03], "mass_kg": 0.05}),
    ("box 30x40x50", {"shape": "box", "size": [0.03, 0.04, 0.05], "mass_kg": 0.03}),
    ("box 45x45x60", {"shape": "box", "size": [0.045, 0.045, 0.06], "mass_kg": 0.06}),
    ("cylinder r15 l80", {"shape": "cylinder", "size": [0.015, 0.08], "mass_kg": 0.03}),
    ("cylinder r25 l100", {"shape": "cylinder", "size": [0.025, 0.1], "mass_kg": 0.06}),
    ("rod r5 l120", {"shape": "cylinder", "size": [0.005, 0.12], "mass_kg": 0.01}),
)
#: ``--objects heavy``: 0.05-0.5 kg, the sweep of objects heavier than the library's; no force
#: is given to the planner: the hands' joint torque limits decide.
OBJECTS_HEAVY = (
    ("sphere r20 50g", {"shape": "sphere", "size": [0.02], "mass_kg": 0.05}),
    ("sphere r28 200g", {"shape": "sphere", "size": [0.028], "mass_kg": 0.2}),
    ("box 35x45x55 150g", {"shape": "box", "size": [0.035, 0.045, 0.055], "mass_kg": 0.15}),
    ("box 45x45x60 400g", {"shape": "box", "size": [0.045, 0.045, 0.06], "mass_kg": 0.4}),
    ("cylinder r18 l90 300g", {"shape": "cylinder", "size": [0.018, 0.09], "mass_kg": 0.3}),
    ("cylinder r25 l100 500g", {"shape": "cylinder", "size": [0.025, 0.1], "mass_kg": 0.5}),
)
OBJECT_SETS = {"light": OBJECTS, "heavy": OBJECTS_HEAVY, "all": OBJECTS + OBJECTS_HEAVY}
#: --quick: one hand, one object, two finger sets, one pair.
QUICK = {"hands": ("allegro_right",), "objects": ("sphere r30",), "sets": 2, "pairs": 1}
GRASPS_PER_SET = 3
PAIRS_PER_OBJECT = 3
#: Attempts of the pose search (per finger set) and of each fixed-pose synthesis.
POSE_ATTEMPTS = 200
SYNTH_ATTEMPTS = 150
MODES = ("default", "graph", "execution")
#: ``--execution-set`` choices: the gravity set sizes execution mode can plan for (7 adds
#: gravity off, which holds nothing).
EXECUTION_SETS = (1, 2, 6)


# ------------------------------------------------------------------ synthesis


def synth_task(t: dict) -> dict:
    """One hand and object: the fixed pose and every finger set's grasps (plain data). A
    synthesis that crashes finds nothing for its finger set; the error is kept in ``errors``
    (the sweep goes on, and the summary names it)."""
    t0 = time.perf_counter()
    block = dict(t["block"])
    out = {"hand": t["hand"], "object": t["object"], "pose_from": "", "grasps": [], "synth": [], "errors": []}
    kw = execution_ready(t["hand"])
    for fs in t["sets"]:  # the pose: the first grasp found with the pose sampled, largest set first
        r = _synthesize(out, f"pose {fs}", t["hand"], block, fs.split(","), 1, fixed=False, seed=t["seed"],
                        max_attempts=POSE_ATTEMPTS, **kw)
        if r is not None and r.grasps:
            o = r.grasps[0].data["object"]
            block.update(position=o["position"], quat_xyzw=o["quat_xyzw"])
            out["pose_from"] = fs
            pose_grasp = {"fingers": fs, "rank": 0, "metric": float(r.grasps[0].grasp.metric), "data": r.grasps[0].data}
            break
    if not out["pose_from"]:
        out["synth_s"] = time.perf_counter() - t0
        return out
    out["pose"] = [block["position"], block["quat_xyzw"]]
    for k, fs in enumerate(t["sets"]):
        r = _synthesize(out, fs, t["hand"], block, fs.split(","), t["per_set"], fixed=True, seed=t["seed"] + 1 + k,
                        max_attempts=SYNTH_ATTEMPTS, **kw)
        out["synth"].append({"fingers": fs, "found": len(r.grasps), "attempts": r.attempts, "seconds": r.seconds}
                            if r is not None else {"fingers": fs, "found": 0, "error": out["errors"][-1]})
        if fs == out["pose_from"]:  # the grasp that gave the pose is one of them (rank 0)
            out["grasps"].append(pose_grasp)
        for rank, g in enumerate(r.grasps if r is not None else (), start=1):
            out["grasps"].append({"fingers": fs, "rank": rank, "metric": float(g.grasp.metric), "data": g.data})
    out["synth_s"] = time.perf_counter() - t0
    return out


def _synthesize(out: dict, what: str, *args, **kw):
    """`planner.synthesis.synthesize`, or None when it raised: the error is appended to
    ``out["errors"]`` as one line naming ``what`` (the finger set, or the pose search)."""
    from planner.synthesis import synthesize

    try:
        return synthesize(*args, **kw)
    except Exception as err:  # noqa: BLE001 - a synthesis crash loses one finger set, not the sweep
        out["errors"].append(f"{what}: {type(err).__name__}: {err}".replace("\n", " ")[:300])
        return None


def execution_ready(hand_ref: str) -> dict:
    """`planner.synthesis.synthesize` keywords for grasps that execution mode can plan with: force
    closure with one mean contact per finger, and the weight held in the 6 gravity directions
    of ``PlanOptions.for_execution()`` within its force budget, with its friction reserve."""
    from planner.grasp import load_hand
    from planner.gravity import gravity_directions
    from planner.options import PlanOptions

    o = PlanOptions.for_execution()
    dirs = [g for _, g in gravity_directions(load_hand(hand_ref).palm_normal, o.gravity_set)]
    from planner.sim.replay import replay_plan

    # the object keeps the replay's drift limit from the palm: closer, it can settle onto the
    # palm within the limits, and a grasp the palm carries is not the plan's
    drift_mm = inspect.signature(replay_plan).parameters["drift_mm_max"].default
    return {"gravity": dirs, "max_finger_force_n": o.max_finger_force_n, "contact_model": o.contact_model,
            "friction_margin": o.friction_margin, "palm_clearance_m": drift_mm / 1000.0}


def _plain_json(v):
    """JSON for the numpy scalars and arrays a grasp's data may hold."""
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (tuple, set)):
        return list(v)
    raise TypeError(f"not JSON: {type(v).__name__}")


def draw_pairs(grasps: list[dict], k: int, seed: int) -> list[tuple[int, int]]:
    """Up to k (initial, final) index pairs of distinct grasps, seeded: pairs across finger
    sets first (in random order), then within a set; no pair twice, either way round."""
    rng = np.random.default_rng(seed)
    n = len(grasps)
    cands = [(i, j) for i in range(n) for j in range(n) if i != j]
    order = rng.permutation(len(cands))
    across = [cands[c] for c in order if grasps[cands[c][0]]["fingers"] != grasps[cands[c][1]]["fingers"]]
    within = [cands[c] for c in order if grasps[cands[c][0]]["fingers"] == grasps[cands[c][1]]["fingers"]]
    out: list[tuple[int, int]] = []
    for i, j in across + within:
        if len(out) >= k:
            break
        if (i, j) not in out and (j, i) not in out:
            out.append((i, j))
    return out


# ------------------------------------------------------------------ planning


def _why(err: Exception) -> str:
    """A short reason for a failed plan: the NoSequenceError's report in words."""
    import re

    msg = str(err).replace("\n", " ")
    rep = getattr(err, "report", None) or {}
    m = re.match(r"the (initial|final) grasp .* is not force closure( with the 'mean' contact model)?", msg)
    if m and not rep:
        return f"{m.group(1)} grasp not force closure{' with mean contacts' if m.group(2) else ''}"
    parts = []
    if rep.get("never_removable"):
        parts.append("never removable: " + ", ".join(rep["never_removable"]))
    if rep.get("landing_blocked"):
        parts.append("cannot land: " + ", ".join(rep["landing_blocked"]))
    if not parts and rep.get("stuck"):
        parts.append("stuck: " + ", ".join(f"{s['finger']} {s['action']}" for s in rep["stuck"]))
    if "time limit" in msg:
        parts.append("time limit reached")
    if "could not be planned" in msg or "impossible moves" in msg:
        parts.append("finger path not planned")
    return "; ".join(parts) if parts else msg.removeprefix("no finger-gaiting sequence: ")[:120]


def _plan(gi, gf, opts):
    """(PlanResult or None, seconds, reason)."""
    from planner.errors import PlannerError
    from planner.regrasp import plan_regrasp

    t0 = time.perf_counter()
    try:
        res = plan_regrasp(gi, gf, opts)
    except PlannerError as err:
        return None, time.perf_counter() - t0, _why(err)
    except Exception as err:  # noqa: BLE001 - a planner crash is a failed pair, reported as such
        return None, time.perf_counter() - t0, f"crash: {type(err).__name__}: {err}".replace("\n", " ")[:120]
    return res, time.perf_counter() - t0, ""


def options(mode: str, seed: int, motion: bool = True, gravity_set: int = 6):
    """The PlanOptions of a mode (`MODES`); ``motion`` False: straight joint-space finger paths;
    ``gravity_set``: the directions execution mode plans for (`EXECUTION_SETS`); its
    verification replays run in this process (the sweep's own workers use the cores)."""
    from planner.options import PlanOptions

    if mode == "default":
        return PlanOptions(seed=seed, motion=motion)
    if mode == "graph":
        return PlanOptions(seed=seed, motion=motion, intermediate=0, time_limit_s=0)
    return PlanOptions.for_execution(seed=seed, motion=motion, gravity_set=gravity_set, workers=1)


def planned_for(hand, gravity_set: int) -> list[str]:
    """Names (`planner.gravity`, hand-specific) of the directions execution mode plans for."""
    from planner.gravity import gravity_directions

    return [name for name, _ in gravity_directions(hand.palm_normal, gravity_set)]


def plan_path(folder: Path, hand: str, obj: str, n: int) -> Path:
    """Where ``--save-plans`` writes pair n (from 1) of a hand and object label."""
    return Path(folder) / f"{hand}_{obj.replace(' ', '_')}_{n}.json"


def pair_task(t: dict) -> dict:
    from planner.grasp import load_hand, parse_grasp
    from planner.realization import realize

    t0 = time.perf_counter()
    a, b = t["initial"], t["final"]
    row = {"hand": t["hand"], "object": t["object"], "pair": t["pair"],
           "initial": f"{a['fingers']} #{a['rank']}", "final": f"{b['fingers']} #{b['rank']}"}
    hand = load_hand(t["hand"])
    gi = realize(parse_grasp(a["data"], Path(f"{t['hand']}_initial.yaml")), hand)
    gf = realize(parse_grasp(b["data"], Path(f"{t['hand']}_final.yaml")), hand)
    row["family"] = family(gi.spec.object)
    row["mean_fc"] = bool(gi.closure_under("mean").is_force_closure and gf.closure_under("mean").is_force_closure)
    n_set = t.get("execution_set", 6)
    names = planned_for(hand, n_set)
    row["execution_set"] = n_set
    row["planned_for"] = " ".join(generic_direction(n, names) for n in names)
    reasons = {}
    if t.get("coverage"):
        row["grasps_hold"] = grasps_hold(gi, gf, n_set)
    for mode in t.get("modes", MODES):
        res, s, why = _plan(gi, gf, options(mode, t["seed"], t.get("motion", True), n_set))
        row[f"{mode}_solved"] = res is not None
        row[f"{mode}_time_s"] = s
        if res is None:
            row[f"{mode}_why"] = why
            reasons[mode] = why
            continue
        row[f"{mode}_steps"] = res.sequence.gait_steps
        row[f"{mode}_intermediate"] = sum((res.plan.summary.get("search") or {}).get("intermediate_added", {}).values())
        if mode == "execution":
            check = res.plan.summary.get("verification") or {}
            row["verify_attempts"] = check.get("attempts")
            row["verify_s"] = res.verify_s
            if t.get("save_plans"):
                from planner.plan_data import write_plan

                row["plan_file"] = str(write_plan(res.plan, plan_path(t["save_plans"], t["hand"], t["object"], t["index"])))
            if t.get("coverage"):
                row.update(fresh_replay(res.plan, n_set, row.get("plan_file")))
            else:
                row.update(replay_row(res.plan.to_dict(), hand, t["directions"], names))
    row["reason"] = reason(row, reasons)
    row["pair_time_s"] = time.perf_counter() - t0
    return row


def grasps_hold(gi, gf, n_set: int) -> bool:
    """Both grasps of a pair hold the object in the simulator in the planned-for directions:
    each as a one-state plan (the grasp alone), verified as execution mode verifies plans."""
    from planner.errors import NoSequenceError
    from planner.options import PlanOptions
    from planner.regrasp import plan_regrasp

    for g in (gi, gf):
        try:
            plan_regrasp(g, g, PlanOptions.for_execution(motion=False, gravity_set=n_set, workers=1))
        except NoSequenceError:
            return False
    return True


def fresh_replay(plan, n_set: int, plan_file: str | None = None) -> dict:
    """Soundness: the plan, as written to a file, replayed by ``regrasp replay --gravity-set N``
    in a new process (``fresh_pass``: exit 0; ``fresh_verdict``: its last line)."""
    import subprocess
    import tempfile

    from planner.plan_data import write_plan

    with tempfile.TemporaryDirectory() as tmp:
        path = plan_file or str(write_plan(plan, Path(tmp) / "plan.json"))
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-m", "planner", "replay", path, "--gravity-set", str(n_set),
                              "--workers", "1"], capture_output=True, text=True, timeout=1800)
    lines = out.stdout.strip().splitlines()
    return {"fresh_pass": out.returncode == 0, "fresh_verdict": (lines[-1] if lines else out.stderr.strip())[:400],
            "fresh_replay_s": time.perf_counter() - t0}


def replay_row(plan: dict, hand, n: int, planned: list[str] = ()) -> dict:
    """The execution plan replayed under n gravity directions (exp7's `replay_all`): pass,
    drift and verdict per generic direction, all-directions pass, the first failing verdict;
    with ``planned`` (hand-specific names, `planned_for`): the pass over those of them that
    were replayed (``exec_planned_for``) and their first failing verdict."""
    reports = replay_all(plan, hand, n)
    names = [name for name, _, _ in reports]
    out, first_fail, planned_fail = {}, "", ""
    for name, rep, wall in reports:
        d = generic_direction(name, names)
        out[f"exec_{d}"] = bool(rep.passed)
        out[f"drift_deg_{d}"] = rep.max_drift_deg
        out[f"verdict_{d}"] = rep.verdict.replace("\n", " ")[:400]
        if not rep.passed and not first_fail:
            first_fail = f"replay {d}: {rep.verdict}".replace("\n", " ")[:160]
        if not rep.passed and name in planned and not planned_fail:
            planned_fail = f"replay {d}: {rep.verdict}".replace("\n", " ")[:400]
    out["exec_all"] = all(out[f"exec_{generic_direction(n_, names)}"] for n_ in names)
    sides = [v for k, v in out.items() if k.startswith("exec_side_")]
    if sides:
        out["exec_sideways"] = all(sides)
    if planned:
        out["exec_planned_for"] = all(out[f"exec_{generic_direction(n_, names)}"] for n_ in names if n_ in planned)
        out["planned_for_fail"] = planned_fail
    out["replay_s"] = sum(w for _, _, w in reports)
    out["replay_fail"] = first_fail
    return out


def reason(row: dict, reasons: dict) -> str:
    """One line per pair: why it fell short (empty when default and execution both succeeded
    and the replay passed everywhere)."""
    if "default" in reasons:
        return f"default: {reasons['default']}"
    if "execution" in reasons:
        return f"execution: {reasons['execution']}"
    if row.get("fresh_pass") is False:
        return f"fresh replay: {row.get('fresh_verdict', '')}"
    return row.get("replay_fail", "")


# ------------------------------------------------------------------ summary and plot


def _frac(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.1f} %)" if n else "0/0"


def summarize(rows: list[dict], synth: list[dict] | None = None) -> dict:
    n = len(rows)
    s: dict = {"pairs": n}
    if synth is not None:
        s["objects with a pose"] = f"{sum(1 for o in synth if o['pose_from'])}/{len(synth)}"
        s["grasps synthesized"] = sum(len(o["grasps"]) for o in synth)
        no_pairs = [f"{o['hand']} {o['object']}" for o in synth if len(o["grasps"]) < 2]
        if no_pairs:
            s["objects without a pair"] = ", ".join(no_pairs)
        crashed = [f"{o['hand']} {o['object']} {e}" for o in synth for e in o.get("errors", ())]
        if crashed:
            s["synthesis crashes (finger set lost)"] = " | ".join(crashed)
    if not n:
        return s
    if any("grasps_hold" in r for r in rows):
        held = [r for r in rows if r.get("grasps_hold") is True]
        planned = [r for r in held if r.get("execution_solved") is True]
        s["coverage: execution plan / pairs whose grasps both hold in the simulator"] = _frac(len(planned), len(held))
        s["pairs whose grasps both hold"] = _frac(len(held), n)
        ex = [r for r in rows if r.get("execution_solved") is True]
        s["soundness: execution plans passing a fresh-process replay"] = _frac(
            sum(r.get("fresh_pass") is True for r in ex), len(ex))
        att = [r["verify_attempts"] for r in ex if isinstance(r.get("verify_attempts"), (int, float))]
        if att:
            s["verification: sequences replayed per plan (median / max)"] = f"{np.median(att):g} / {max(att):g}"
    for mode in [m for m in MODES if any(f"{m}_solved" in r for r in rows)]:
        ok = [r for r in rows if r[f"{mode}_solved"]]
        times = [r[f"{mode}_time_s"] for r in ok]
        s[f"{mode} solved"] = _frac(len(ok), n)
        if times:
            s[f"{mode} plan time s (median / max, solved)"] = f"{np.median(times):.2f} / {max(times):.2f}"
    mean_fc = sum(bool(r["mean_fc"]) for r in rows)
    s["both grasps force closure with mean contacts (execution can plan)"] = _frac(mean_fc, n)
    if not all("default_solved" in r for r in rows):
        return s
    s["execution solved, of those"] = _frac(sum(bool(r["execution_solved"]) for r in rows if r["mean_fc"]), mean_fc)
    sets = sorted({str(r["execution_set"]) for r in rows if r.get("execution_set") not in (None, "")})
    if sets:
        s["execution gravity set"] = ", ".join(sets) + " (" + "; ".join(sorted({str(r.get("planned_for")) for r in rows})) + ")"
    ex = [r for r in rows if r["execution_solved"] and "exec_all" in r]
    if ex:
        pf = [r for r in ex if _bool(r.get("exec_planned_for")) is not None]
        if pf:
            s["execution: pass every planned-for direction"] = _frac(sum(bool(r["exec_planned_for"]) for r in pf), len(pf))
        s["execution: pass all directions"] = _frac(sum(bool(r["exec_all"]) for r in ex), len(ex))
        for d, key in (("palm_down", "exec_palm_down"), ("palm_up", "exec_palm_up"), ("all 4 sideways", "exec_sideways"),
                       ("off", "exec_off")):
            replayed = [r for r in ex if r.get(key) not in (None, "") and r.get(key) == r.get(key)]  # not NaN
            if replayed:
                s[f"execution: pass {d}"] = _frac(sum(bool(r[key]) for r in replayed), len(replayed))
        s["execution: pass all directions, of all pairs"] = _frac(sum(bool(r["exec_all"]) for r in ex), n)
    for key, label in (("hand", "hand"), ("family", "family")):
        for v in sorted({r[key] for r in rows}):
            s[f"{label} {v}"] = _group(rows, key, v)
    failed = [r for r in ex if _bool(r.get("exec_planned_for")) is False]
    if failed:
        s["execution replay failures in planned-for directions"] = " | ".join(
            f"{r['pair']}: {r['planned_for_fail']}" + (f" [{r['plan_file']}]" if r.get("plan_file") else "") for r in failed)
    why = Counter(_category(r["reason"]) for r in rows if r.get("reason"))
    if why:
        s["reasons"] = "; ".join(f"{k} x{v}" for k, v in why.most_common())
    return s


def _bool(v):
    """A pass column's value as True / False, None when absent (empty or NaN read back)."""
    return v if isinstance(v, bool) else None


def _group(rows: list[dict], key: str, value) -> str:
    """One summary line for the rows of a hand or family: solved per mode, replay passes."""
    g = [r for r in rows if r[key] == value]
    line = (f"{len(g)} pairs: default {sum(bool(r['default_solved']) for r in g)}, graph "
            f"{sum(bool(r['graph_solved']) for r in g)}, execution {sum(bool(r['execution_solved']) for r in g)}, "
            f"pass all directions {sum(bool(r.get('exec_all')) for r in g)}")
    if any(_bool(r.get("exec_planned_for")) is not None for r in g):
        line += (f", pass planned-for {sum(_bool(r.get('exec_planned_for')) is True for r in g)}, "
                 f"palm down {sum(_bool(r.get('exec_palm_down')) is True for r in g)}, "
                 f"off {sum(_bool(r.get('exec_off')) is True for r in g)}")
    return line


def _category(reason: str) -> str:
    """The reason without its details (finger names, numbers): for counting."""
    head = reason.split(":")[0]
    for key in ("not force closure", "need over", "never removable", "cannot land", "time limit", "finger path",
                "stuck", "crash", "collide", "dropped", "drift", "closure disagree"):
        if key in reason:
            return f"{head}: {key}"
    return head


def plot(rows: list[dict], path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(13, 4.5), gridspec_kw={"width_ratios": [3, 2]})
    groups = [(h, fam) for h in sorted({r["hand"] for r in rows}) for fam in sorted({r["family"] for r in rows})
              if any(r["hand"] == h and r["family"] == fam for r in rows)]
    bars = [("default", "default_solved"), ("graph only", "graph_solved"), ("execution", "execution_solved"),
            ("executes in all 7", "exec_all")]
    if any(_bool(r.get("exec_planned_for")) is not None for r in rows):
        bars.insert(3, ("executes planned-for", "exec_planned_for"))
    w = 0.8 / len(bars)
    for j, (label, key) in enumerate(bars):
        rates = []
        for h, fam in groups:
            sub = [r for r in rows if r["hand"] == h and r["family"] == fam]
            rates.append(100.0 * sum(bool(r.get(key)) for r in sub) / len(sub))
        ax[0].bar(np.arange(len(groups)) + (j - (len(bars) - 1) / 2) * w, rates, w, label=label)
    ax[0].set_xticks(range(len(groups)))
    ax[0].set_xticklabels([f"{h.split('_')[0]}\n{fam}\n({sum(r['hand'] == h and r['family'] == fam for r in rows)})"
                           for h, fam in groups], fontsize=8)
    ax[0].set_ylabel("pairs (%)")
    ax[0].set_ylim(0, 118)
    ax[0].set_yticks(range(0, 101, 20))
    ax[0].legend(fontsize=8, ncol=len(bars), loc="upper center")
    ax[0].set_title("synthesized pairs solved per hand and object family (pairs)")
    for j, (mode, marker) in enumerate((("default", "o"), ("graph", "s"), ("execution", "^"))):
        t = np.array([r[f"{mode}_time_s"] for r in rows], float)
        ok = np.array([bool(r[f"{mode}_solved"]) for r in rows])
        x = np.full(len(rows), j) + np.random.default_rng(j).uniform(-0.25, 0.25, len(rows))
        ax[1].scatter(x[ok], t[ok], c="tab:green", marker=marker, s=14, label="solved" if j == 0 else None)
        ax[1].scatter(x[~ok], t[~ok], c="tab:red", marker=marker, s=14, label="not solved" if j == 0 else None)
    ax[1].set_yscale("log")
    ax[1].set_xticks(range(3))
    ax[1].set_xticklabels(["default (anytime)", "graph only", "execution"])
    ax[1].set_ylabel("plan time incl. finger paths (s)")
    ax[1].legend(fontsize=8)
    ax[1].set_title("plan time per pair")
    save(fig, path)


# ------------------------------------------------------------------ main


def object_tasks(quick: bool, seed: int, objects: str = "light") -> list[dict]:
    tasks = []
    for h, sets in FINGER_SETS.items():
        if quick and h not in QUICK["hands"]:
            continue
        for k, (label, block) in enumerate(OBJECT_SETS[objects]):
            if quick and label not in QUICK["objects"]:
                continue
            use = sets[-QUICK["sets"]:] if quick else sets
            tasks.append({"hand": h, "object": label, "block": block, "sets": list(use),
                          "per_set": 1 if quick else GRASPS_PER_SET, "seed": seed + 1000 * k})
    return tasks


def pair_tasks(synth: list[dict], k: int, seed: int, directions: int, motion: bool = True, execution_set: int = 6,
               save_plans: Path | None = None, coverage: bool = False) -> list[dict]:
    tasks = []
    for o in synth:
        for n, (i, j) in enumerate(draw_pairs(o["grasps"], k, seed)):
            tasks.append({"hand": o["hand"], "object": o["object"], "pair": f"{o['hand']} {o['object']} {n + 1}",
                          "index": n + 1, "initial": o["grasps"][i], "final": o["grasps"][j], "seed": seed,
                          "directions": directions, "motion": motion, "execution_set": execution_set,
                          "save_plans": str(save_plans) if save_plans is not None else None,
                          **({"coverage": True, "modes": ("execution",)} if coverage else {})})
    return tasks


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--pairs-per-object", type=int, default=None, help=f"pairs per hand and object (default {PAIRS_PER_OBJECT})")
    ap.add_argument("--directions", type=int, default=7, choices=(1, 2, 6, 7),
                    help="gravity set size of the execution replays (default 7: with gravity off)")
    ap.add_argument("--no-motion", action="store_true",
                    help="straight joint-space finger paths instead of OMPL (implied by --quick)")
    ap.add_argument("--execution-set", type=int, default=6, choices=EXECUTION_SETS,
                    help="gravity set execution mode plans for (planner.gravity; default 6; 1: palm down only)")
    ap.add_argument("--save-plans", type=Path, default=None, metavar="DIR",
                    help="write each execution-mode plan to DIR/<hand>_<object>_<pair>.json")
    ap.add_argument("--objects", default="light", choices=sorted(OBJECT_SETS),
                    help="object set: light (10-60 g, default), heavy (0.05-0.5 kg) or all")
    ap.add_argument("--coverage", action="store_true",
                    help="execution mode only: coverage (plans / pairs whose grasps both hold in the simulator) "
                         "and soundness (plans passing a replay of the written file in a fresh process)")
    ap.add_argument("--save-grasps", type=Path, default=None, metavar="FILE",
                    help="write the synthesized poses and grasps (JSON) to FILE, for --grasps-from")
    ap.add_argument("--grasps-from", type=Path, default=None, metavar="FILE",
                    help="no synthesis: plan the pairs of the grasps an earlier run saved with --save-grasps "
                         "(e.g. another commit's grasps, to compare planners on the same pairs)")
    ap.add_argument("--name", default="exp8_random_pairs", help="CSV / PNG file stem in --out")
    ap.add_argument("--from-csv", type=Path, default=None, help="no run: summary and plot of an existing exp8 CSV")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.from_csv is not None:
        return replot(args.from_csv, args.out / f"{args.name}.png", "exp8 random pairs", plot, summarize)
    if args.save_plans is not None:
        if args.save_plans.exists() and not args.save_plans.is_dir():
            ap.error(f"--save-plans {args.save_plans}: exists and is not a directory")
        args.save_plans.mkdir(parents=True, exist_ok=True)
    if args.grasps_from is not None:  # the grasps of an earlier run (--save-grasps): no synthesis
        import json

        synth = json.loads(args.grasps_from.read_text())
    else:
        synth = run_tasks(synth_task, object_tasks(args.quick, args.seed, args.objects), args, desc="exp8 synth")
    if args.save_grasps is not None:
        import json

        args.save_grasps.parent.mkdir(parents=True, exist_ok=True)
        args.save_grasps.write_text(json.dumps(synth, default=_plain_json))
    t_synth = time.perf_counter() - t0
    k = args.pairs_per_object or (QUICK["pairs"] if args.quick else PAIRS_PER_OBJECT)
    motion = not (args.quick or args.no_motion)
    rows = run_tasks(pair_task, pair_tasks(synth, k, args.seed, args.directions, motion, args.execution_set,
                                           args.save_plans, args.coverage), args, desc="exp8 pairs")
    write_csv(args.out / f"{args.name}.csv", rows)
    write_csv(args.out / f"{args.name}_synth.csv",
              [{"hand": o["hand"], "object": o["object"], "pose_from": o["pose_from"],
                "pose": " ".join(f"{v:.4f}" for v in sum(o.get("pose", []), [])), **s, "object_synth_s": o["synth_s"]}
               for o in synth for s in (o["synth"] or [{"error": " | ".join(o.get("errors", ()))}])])
    if rows and not args.coverage:
        plot(rows, args.out / f"{args.name}.png")
    summary = summarize(rows, synth)
    summary["finger paths"] = "OMPL" if motion else "straight joint-space segments (--quick / --no-motion)"
    summary["synthesis wall s"] = t_synth
    summary["wall s"] = time.perf_counter() - t0
    print_summary("exp8 random pairs", summary)
    return summary


if __name__ == "__main__":
    main()
