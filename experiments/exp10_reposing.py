"""Exp. 10 - reposing: regrasps between grasps whose object poses differ.

Issue acceptance: a benchmark, generated before any tuning, of grasp pairs whose object pose
differs by 5-30 mm and 5-45 deg, on both bundled hands (icub_right, allegro_right) and four
object families (sphere, box, cylinder across the fingers, mesh ellipsoid): ``plan
--execution`` plans at least 50 %, every returned plan passes a fresh ``replay --gravity-set
6``, and the same pairs with equal poses still plan as before.

Generation (``--generate``, deterministic for a ``--seed``; one cell per hand, family and
pose-offset class, each cell drawing attempts from ``numpy.random.default_rng([seed, hand,
family, class, attempt])``); the helpers are exp9's (`experiments.exp9_whole_hand`):

1. Pose A: the object (exp9's sizes and orientation per family) centred among the fingers
   (exp9's `PLACEMENT`) and ``gap`` (`GAP_M`, a few mm) off the palm: not against it. An
   object penetrating the open hand is re-drawn (next attempt).
2. Grasp A: the non-thumb fingers close on it by ``posture:`` (exp9's `choose_fingers`, at
   least two must touch), the thumb by ``contact: {point}`` (seeded surface points not facing
   the palm, reachable by IK); the first thumb point whose grasp passes ``check --execution``
   (in process: `planner.realization.execution_verdict`) is kept.
3. Pose B = pose A moved by a translation of the class's length (`CLASSES`, uniform) along a
   uniformly random direction and a rotation of the class's angle about a uniformly random
   axis through the object's centre. A pose B penetrating the open hand or within
   `MIN_PALM_GAP_B_M` of the palm is re-drawn (at most `POSE_B_TRIES` per attempt).
4. Grasp B at pose B built the same way (fingers re-closed by posture at B, thumb contact).
5. The same-pose control: grasp A2, another valid grasp at pose A with grasp A's fingers
   whose thumb contact is at least `CONTROL_THUMB_MOVE_M` from A's (the pair (A, A2) has equal
   poses: it checks that such pairs still plan).
   Anything that fails re-draws the attempt (at most `MAX_ATTEMPTS`), logged on stderr.
6. The written files are confirmed by ``python -m planner check FILE --execution --json``
   (exit codes in the manifest; should all be 0).

Files: ``<pairs-dir>/<hand>_<family>_<class>_{initial,final,same}.yaml`` (default
``experiments/results/exp10_pairs/``), ``meshes/ellipsoid.obj`` and ``manifest.csv``.

Run (``--run --label L``): every pair (``pose``: initial -> final) and every control
(``same``: initial -> same) planned by a fresh ``python -m planner plan INIT FINAL --execution
-o plan.yaml`` (`PLAN_TIMEOUT_S` cap; ``--no-verify`` passed through when given), every
returned plan replayed by a fresh ``python -m planner replay plan.yaml --gravity-set 6
--workers 1 --report r.json``. One subprocess at a time pinned to one CPU (exp9's `run_sub`).
CSV: ``experiments/results/exp10_<label>.csv``.

    python experiments/exp10_reposing.py --generate [--seed 0]
    python experiments/exp10_reposing.py --generate-v2 [--seed 0]   # v2: synthesized grasps (exp10_v2.py)
    python experiments/exp10_reposing.py --run --label L [--kinds pose,same] [--no-verify]
    python experiments/exp10_reposing.py --summary experiments/results/exp10_L.csv
    python experiments/exp10_reposing.py --reach --label L [--only REGEX]

Reach (``--reach``, in process, no simulator): for every pose pair, how far each end grasp's
reposing move (`planner.repose.repose`, execution mode's options: the contacts fixed on the
object) carries the object along the straight path toward the other grasp's pose, as the
fraction of the path's waypoints it passes, and why it stops, grouped (`reach_cause`): a finger
that cannot keep its contact with a joint at its limit, one that cannot keep it with its joints
free (fewer free coordinates than its contact point needs: a coupled finger), a link going into
the object (a contact that would have to roll), the grasp no valid state at a waypoint (closure
or load), or another motion error. Pairs whose two fractions add up to 1 or more have a pose on
the path both grasps reach. The same for the fingers' own path (`experiments.repose_drive`: the
object's motion chosen among those the holding fingers can follow; its reach is 1 minus the
distance left over the distance, in straight-path waypoints), and whether the two grasps, driven
toward each other's pose in turn, meet (`experiments.repose_drive.meeting`). Per finger, alone
(`finger_reach`): how far each holding finger follows the straight path and why it stops (its
contact or a link into the object), the two thumbs' reaches added (a pose on the path both
thumbs reach needs 1 or more), and how far apart the two grasps' thumb contacts are on the object
(`thumb_contacts_apart_mm`: with sticking contacts only a thumb gait, at some pose, changes it).
CSV: ``experiments/results/exp10_reach_<label>.csv``.
"""

from __future__ import annotations

import argparse
import math
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

# The repository root appended, not prepended: ``planner`` stays whatever this interpreter
# imports first (PYTHONPATH, then the editable install), as in exp9.
sys.path.append(str(Path(__file__).resolve().parents[1]))

from experiments.exp9_whole_hand import (  # noqa: E402
    FAMILIES, HANDS, MESH_NAME, PLACEMENT, SIZES, THUMB, THUMB_SAMPLES, _first_line, _rot_about,
    _thumb_contact, _thumb_reachable, _valid, choose_fingers, cli_check, grasp_doc, hand_axes,
    object_block, open_hand_penetration, palm_gap, pinned_cpu, planner_cmd, print_summary, read_csv,
    read_manifest, realize_thumb, refusal_group, replay_passed, run_sub, write_csv, write_yaml, MAX_YAW_DEG)

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
DEFAULT_PAIRS = RESULTS / "exp10_pairs"

#: Pose-offset classes: (translation mm range, rotation deg range), each drawn uniformly.
CLASSES = {"small": ((5.0, 10.0), (5.0, 15.0)),
           "medium": ((10.0, 20.0), (15.0, 30.0)),
           "large": ((20.0, 30.0), (30.0, 45.0))}
MASS_KG = 0.1
#: Pose A's gap to the palm's collision geometry, m: a few mm off it (not against it).
GAP_M = (0.002, 0.005)
#: Pose B must stay at least this far from the palm (the object is moved, not pushed into it).
MIN_PALM_GAP_B_M = 0.001
POSE_B_TRIES = 20
CONTROL_THUMB_MOVE_M = 0.005
THUMB_TRIES = 16
MAX_ATTEMPTS = 40
PLAN_TIMEOUT_S = 600.0
REPLAY_TIMEOUT_S = 900.0
GRAVITY_SET = 6


# ====================================================================== generation


def _np():
    import numpy as np

    return np


def sample_pose_a(hand, family, rng, mesh_abs):
    """(block without mass, GraspObject, gap measured): exp9's object, a few mm off the palm."""
    np = _np()
    n, a, c, base = hand_axes(hand)
    size = [float(rng.uniform(lo, hi)) for lo, hi in SIZES[hand.name][family]]
    yaw = 0.0 if family == "sphere" else math.radians(float(rng.uniform(-MAX_YAW_DEG, MAX_YAW_DEG)))
    R0 = {"cylinder": np.column_stack([n, a, c]), "sphere": np.eye(3)}.get(family, np.column_stack([a, c, n]))
    R = _rot_about(n, yaw) @ R0
    pl = PLACEMENT[hand.name]
    tangential = base + a * float(rng.uniform(*pl["along"])) + c * float(rng.uniform(*pl["across"]))
    tangential = tangential - (tangential @ n) * n
    gap = float(rng.uniform(*GAP_M))
    block, obj, measured = object_block(hand, family, size, R, tangential, gap, mesh_abs)
    return block, obj, measured


def _unit(rng):
    np = _np()
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def moved_block(block, shift, axis, angle_rad, mesh_abs):
    """Pose A's block moved: position + shift, orientation turned by ``angle_rad`` about
    ``axis`` (palm frame, through the object's centre); (block, GraspObject)."""
    np = _np()
    from planner.objects import GraspObject
    from scipy.spatial.transform import Rotation

    from experiments.exp9_whole_hand import _quat_xyzw

    R_a = Rotation.from_quat(block["quat_xyzw"]).as_matrix()
    out = dict(block, position=[float(round(v, 6)) for v in np.asarray(block["position"]) + shift],
               quat_xyzw=_quat_xyzw(_rot_about(axis, angle_rad) @ R_a))
    data = dict(out)
    if out["shape"] == "mesh":
        data["mesh"] = str(mesh_abs)
    return out, GraspObject.from_data(data)


def thumb_grasps(hand, obj, block, fingers, rng, path, want=1, away_from=None):
    """Up to ``want`` valid grasps (``check --execution``): (file point, grasp, thumb point,
    thumb normal), thumb points from seeded surface samples; with ``away_from`` (a thumb point)
    only those at least `CONTROL_THUMB_MOVE_M` from it. Returns (list, thumb points tried)."""
    np = _np()
    pts, nrm = obj.sample_surface(THUMB_SAMPLES, rng)
    T = np.asarray(obj.T_palm_obj)
    n_palm, *_ = hand_axes(hand)
    facing = (nrm @ T[:3, :3].T) @ n_palm
    out, tried = [], 0
    for i in rng.permutation(len(pts)):
        if tried >= THUMB_TRIES or len(out) >= want:
            break
        if facing[i] <= -0.3 or not _thumb_reachable(hand, obj, pts[i], nrm[i]):
            continue
        tried += 1
        res = realize_thumb(hand, block, MASS_KG, fingers, [float(round(v, 5)) for v in pts[i]], path)
        if res is None or not _valid(res[1], validity="execution"):
            continue
        tp, tn = _thumb_contact(res[1])
        if away_from is not None and float(np.linalg.norm(tp - away_from)) < CONTROL_THUMB_MOVE_M:
            continue
        out.append((res[0], res[1], tp, tn))
    return out, tried


def generate_cell(hand, family, cls, seed, out_dir: Path, mesh_path: Path, log=print):
    """(manifest row, {initial, final, same: doc}) or None after `MAX_ATTEMPTS`."""
    np = _np()
    from planner.repose import pose_distance

    hi, fi, ci = HANDS.index(hand.name), FAMILIES.index(family), list(CLASSES).index(cls)
    (t_lo, t_hi), (r_lo, r_hi) = CLASSES[cls]
    stem = f"{hand.name}_{family}_{cls}"
    probe = out_dir / f"{stem}_probe.yaml"  # anchors the relative mesh path; never written
    redraws: list[str] = []

    def fail(attempt, why):
        redraws.append(f"{attempt}: {why}")
        log(f"  {stem} attempt {attempt}: {why}")

    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([seed, hi, fi, ci, attempt])
        block_a, obj_a, gap_a = sample_pose_a(hand, family, rng, mesh_path)
        if open_hand_penetration(hand, obj_a) > 0.0:
            fail(attempt, "pose A penetrates the open hand")
            continue
        fingers_a = choose_fingers(hand, block_a, MASS_KG, rng, probe)
        if sum(v != "free" for v in fingers_a.values()) < 2:
            fail(attempt, "fewer than 2 fingers close at pose A")
            continue
        ga, _ = thumb_grasps(hand, obj_a, block_a, fingers_a, rng, probe)
        if not ga:
            fail(attempt, "no valid thumb contact at pose A")
            continue
        # pose B
        for b_try in range(POSE_B_TRIES):
            dist_m = float(rng.uniform(t_lo, t_hi)) * 1e-3
            angle = math.radians(float(rng.uniform(r_lo, r_hi)))
            shift, axis = _unit(rng) * dist_m, _unit(rng)
            block_b, obj_b = moved_block(block_a, shift, axis, angle, mesh_path)
            gap_b = palm_gap(hand, obj_b)
            if gap_b >= MIN_PALM_GAP_B_M and open_hand_penetration(hand, obj_b) <= 0.0:
                break
        else:
            fail(attempt, f"no pose B clear of the palm and the open hand in {POSE_B_TRIES} draws")
            continue
        fingers_b = choose_fingers(hand, block_b, MASS_KG, rng, probe)
        if sum(v != "free" for v in fingers_b.values()) < 2:
            fail(attempt, "fewer than 2 fingers close at pose B")
            continue
        gb, _ = thumb_grasps(hand, obj_b, block_b, fingers_b, rng, probe)
        if not gb:
            fail(attempt, "no valid thumb contact at pose B")
            continue
        ctrl, _ = thumb_grasps(hand, obj_a, block_a, fingers_a, rng, probe, away_from=ga[0][2])
        if not ctrl:
            fail(attempt, f"no second valid thumb contact at pose A >= {CONTROL_THUMB_MOVE_M * 1e3:g} mm away")
            continue
        mm, deg = pose_distance(obj_a.T_palm_obj, obj_b.T_palm_obj)
        desc = (f"exp10 reposing pair {stem} (seed {seed}, attempt {attempt}): ")
        docs = {
            "initial": grasp_doc(hand, block_a, MASS_KG, {THUMB: {"contact": {"point": ga[0][0]}}, **fingers_a},
                                 f"{stem}_initial", desc + f"pose A, {gap_a * 1e3:.1f} mm off the palm"),
            "final": grasp_doc(hand, block_b, MASS_KG, {THUMB: {"contact": {"point": gb[0][0]}}, **fingers_b},
                               f"{stem}_final", desc + f"pose B: pose A moved {mm:.1f} mm and turned {deg:.1f} deg"),
            "same": grasp_doc(hand, block_a, MASS_KG, {THUMB: {"contact": {"point": ctrl[0][0]}}, **fingers_a},
                              f"{stem}_same", desc + "pose A, another thumb contact (the equal-pose control)"),
        }
        row = {"pair": stem, "hand": hand.name, "family": family, "offset_class": cls, "mass_kg": MASS_KG,
               "size": " ".join(f"{s:g}" for s in block_a["size"]), "seed": seed, "attempt": attempt,
               "pose_b_draw": b_try, "redraws": len(redraws),
               "pose_mm": round(mm, 3), "pose_deg": round(deg, 3),
               "position_a": " ".join(f"{v:g}" for v in block_a["position"]),
               "quat_a": " ".join(f"{v:g}" for v in block_a["quat_xyzw"]),
               "position_b": " ".join(f"{v:g}" for v in block_b["position"]),
               "quat_b": " ".join(f"{v:g}" for v in block_b["quat_xyzw"]),
               "palm_gap_a_mm": round(gap_a * 1e3, 3), "palm_gap_b_mm": round(gap_b * 1e3, 3),
               "fingers_a": " ".join(k for k, v in fingers_a.items() if v != "free"),
               "fingers_b": " ".join(k for k, v in fingers_b.items() if v != "free"),
               "thumb_initial": " ".join(f"{v:g}" for v in ga[0][0]),
               "thumb_final": " ".join(f"{v:g}" for v in gb[0][0]),
               "thumb_same": " ".join(f"{v:g}" for v in ctrl[0][0]),
               "control_thumb_move_mm": round(float(np.linalg.norm(ctrl[0][2] - ga[0][2])) * 1e3, 2),
               "redraw_reasons": " | ".join(redraws),
               "initial": f"{stem}_initial.yaml", "final": f"{stem}_final.yaml", "same": f"{stem}_same.yaml"}
        return row, docs
    return None


def generation_setup(args):
    """(pairs folder, the mesh copied into it; the CPU checks are pinned to; the stderr log) of a
    generation run (``--generate``, ``--generate-v2``); prints which planner is imported."""
    import planner
    from planner.resources import grasps_dir

    out: Path = args.pairs_dir
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(Path(grasps_dir()) / "meshes" / MESH_NAME, out / "meshes" / MESH_NAME)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    print(f"planner: {Path(planner.__file__).parent}", flush=True)
    return out, pinned_cpu(args), log


def generate(args) -> dict:
    from planner.grasp import load_hand

    out, cpu, log = generation_setup(args)
    rows = []
    t0 = time.perf_counter()
    for hand_name in args.hands:
        hand = load_hand(hand_name)
        for family in args.families:
            for cls in args.classes:
                tc = time.perf_counter()
                res = generate_cell(hand, family, cls, args.seed, out, out / "meshes" / MESH_NAME, log=log)
                if res is None:
                    print(f"{hand_name} {family} {cls}: no valid pair in {MAX_ATTEMPTS} attempts", flush=True)
                    continue
                row, docs = res
                for role in ("initial", "final", "same"):
                    write_yaml(out / row[role], docs[role])
                for role in ("initial", "final", "same"):
                    code, data, err = cli_check(out / row[role], out, cpu, execution=True)
                    row[f"{role}_check_exit"] = code
                rows.append(row)
                write_csv(out / "manifest.csv", rows)
                print(f"{row['pair']}: attempt {row['attempt']} ({row['redraws']} re-drawn), pose "
                      f"{row['pose_mm']:.1f} mm / {row['pose_deg']:.1f} deg, gap A {row['palm_gap_a_mm']:.1f} mm; "
                      f"check --execution exits {row['initial_check_exit']} {row['final_check_exit']} "
                      f"{row['same_check_exit']} ({time.perf_counter() - tc:.0f} s)", flush=True)
    s = {"pairs": len(rows), "attempts": sum(int(r["attempt"]) + 1 for r in rows),
         "re-drawn attempts": sum(int(r["redraws"]) for r in rows),
         "check --execution not 0 (should be 0)": sum(
             any(r[f"{k}_check_exit"] != 0 for k in ("initial", "final", "same")) for r in rows),
         "wall s": round(time.perf_counter() - t0, 1), "manifest": str(out / "manifest.csv")}
    print_summary("exp10 generate", s)
    return s


# ====================================================================== run


def plan_reposing(plan_path: Path):
    """(reposing moves, object path mm, deg, steps) from a plan file's summary."""
    import yaml

    try:
        data = yaml.safe_load(plan_path.read_text())
    except (OSError, yaml.YAMLError):
        return None, None, None, None
    summ = (data or {}).get("summary") or {}
    rep = summ.get("reposing") or {}
    steps = data.get("steps") if isinstance(data, dict) else None
    return (rep.get("moves", 0), rep.get("object_path_mm", rep.get("path_mm")),
            rep.get("object_path_deg", rep.get("path_deg")), len(steps) if isinstance(steps, list) else None)


def run(args) -> dict:
    pairs_dir: Path = args.pairs_dir
    manifest = [m for m in read_manifest(pairs_dir) if m.get("status", "ok") == "ok"]  # v2: skipped cells
    if args.only:
        manifest = [r for r in manifest if re.search(args.only, r["pair"])]
    if args.max_pairs:
        manifest = manifest[: args.max_pairs]
    # every pose pair before the controls, the hands alternating: a stopped run covers both
    by_hand = {h: [m for m in manifest if m["hand"] == h] for h in HANDS}
    order = [m for i in range(len(manifest)) for h in HANDS if i < len(by_hand[h]) for m in [by_hand[h][i]]]
    jobs = [(m, kind) for kind in args.kinds for m in order]
    work = args.work_dir or Path(tempfile.gettempdir()) / f"exp10_{args.label}_plans"
    work.mkdir(parents=True, exist_ok=True)
    cpu = pinned_cpu(args)
    code, out, err, _ = run_sub([sys.executable, "-c", "import planner, os; print(os.path.dirname(planner.__file__))"],
                                work, 60, cpu)
    planner_dir = out.strip() or f"? ({err.strip()[:200]})"
    if out.strip():
        planner_dir += f" at {planner_state(Path(out.strip()).parent)}"
    print(f"planner: {planner_dir}; plans and logs in {work}; {len(jobs)} jobs; one at a time, pinned to CPU {cpu}"
          + ("; --no-verify" if args.no_verify else ""), flush=True)
    csv_path = args.out or RESULTS / f"exp10_{args.label}.csv"
    rows = read_csv(csv_path) if args.resume and csv_path.is_file() else []
    done = {(r["pair"], r["kind"]) for r in rows}
    t0 = time.perf_counter()
    for k, (m, kind) in enumerate(jobs, 1):
        name = f"{m['pair']}_{kind}"
        if (m["pair"], kind) in done:
            continue
        init = (pairs_dir / m["initial"]).resolve()
        final = (pairs_dir / (m["final"] if kind == "pose" else m["same"])).resolve()
        plan_path, report_path = work / f"{name}.plan.yaml", work / f"{name}.replay.json"
        for p in (plan_path, report_path):
            p.unlink(missing_ok=True)
        cmd = planner_cmd("plan", str(init), str(final), "--execution", "-o", str(plan_path))
        if args.max_rounds is not None:
            cmd += ["--max-rounds", str(args.max_rounds)]
        if args.no_verify:
            cmd += ["--no-verify"]
        code, out, err, wall = run_sub(cmd, work, args.timeout, cpu)
        (work / f"{name}.plan.log").write_text(f"$ {' '.join(cmd)}\n# exit {code}, {wall:.1f} s\n"
                                               f"--- stdout\n{out}\n--- stderr\n{err}\n")
        planned = code == 0 and plan_path.is_file()
        status = "planned" if planned else "timeout" if code is None else "refused" if code == 1 else f"error (exit {code})"
        refusal = "" if planned else (f"timeout after {args.timeout:g} s" if code is None
                                      else _first_line(err) or _first_line(out))
        row = {"pair": m["pair"], "kind": kind, "hand": m["hand"], "family": m["family"],
               "offset_class": m["offset_class"],
               "pose_mm": float(m["pose_mm"]) if kind == "pose" else 0.0,
               "pose_deg": float(m["pose_deg"]) if kind == "pose" else 0.0,
               "verified": "no" if args.no_verify else "yes",
               "planned": "yes" if planned else "no", "status": status,
               "exit_code": "timeout" if code is None else code, "plan_time_s": round(wall, 2),
               "refusal": refusal[:300]}
        if planned:
            moves, pmm, pdeg, nsteps = plan_reposing(plan_path)
            row.update(reposing_moves=moves, reposing_path_mm=pmm, reposing_path_deg=pdeg, steps=nsteps)
            rcmd = planner_cmd("replay", str(plan_path), "--gravity-set", str(GRAVITY_SET), "--workers", "1",
                               "--report", str(report_path))
            rc, rout, rerr, rwall = run_sub(rcmd, work, args.replay_timeout, cpu)
            (work / f"{name}.replay.log").write_text(f"$ {' '.join(rcmd)}\n# exit {rc}, {rwall:.1f} s\n"
                                                    f"--- stdout\n{rout}\n--- stderr\n{rerr}\n")
            passed, total, failed = replay_passed(report_path, rout)
            row.update(replay_exit="timeout" if rc is None else rc, replay_passed=passed, replay_directions=total,
                       replay_passed_of_6="" if passed is None else f"{passed}/{total}",
                       replay_failed=(failed if passed is not None else _first_line(rerr))[:300],
                       replay_time_s=round(rwall, 1))
        rows.append(row)
        write_csv(csv_path, rows)  # after every job: a stopped run keeps what it measured
        print(f"[{k}/{len(jobs)}] {name}: {status} ({wall:.1f} s)"
              + (f", {row.get('reposing_moves')} reposing move(s), replay {row.get('replay_passed_of_6')} "
                 f"({row.get('replay_time_s')} s)" if planned else f": {row['refusal'][:160]}"), flush=True)
    s = summarize(rows)
    s["planner"] = planner_dir
    s["wall s"] = round(time.perf_counter() - t0, 1)
    s["csv"] = str(csv_path)
    print_summary(f"exp10 reposing ({args.label})", s)
    return s


# ====================================================================== summary


def _is_planned(r) -> bool:
    return r["planned"] in ("yes", True, "True")


def _is_sound(r) -> bool:
    v = str(r.get("replay_passed_of_6", ""))
    return "/" in v and v.split("/")[0] not in ("", "None") and v.split("/")[0] == v.split("/")[1]


def repose_group(text: str) -> str:
    """exp9's `refusal_group`, but a "no reposing move joins them" refusal grouped by its
    first reason (at the first candidate pose), finger names and numbers generalised."""
    m = re.search(r"no reposing move joins them: at [^:]*: (.*)", text or "")
    if not m:
        return refusal_group(text)
    t = re.sub(r"^reposing, [^:]*: ", "", m.group(1))
    t = re.sub(r"\([^)]*\)?", "", t)
    t = re.sub(r"\b(thumb|index|middle|ring|little|pinky)\b", "F", t)
    t = re.sub(r"(?<![\w.])[-+]?\d+(\.\d+)?", "#", t)
    return "no reposing move: " + re.sub(r"\s+([:,])", r"\1", re.sub(r"\s+", " ", t.split("; ")[0])).strip()[:140]


def planner_state(root: Path) -> str:
    """The checkout's HEAD and whether planner/ has uncommitted changes (a shared checkout)."""
    code, out, _, _ = run_sub(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], root, 30, None)
    _, dirty, _, _ = run_sub(["git", "-C", str(root), "status", "--porcelain", "--", "planner"], root, 30, None)
    files = [ln[3:] for ln in (dirty or "").splitlines() if ln.strip()]
    return (out or "?").strip() + (f" + uncommitted {' '.join(files)}" if files else "")


def reach_cause(words: str) -> str:
    """The group of a reposing move's refusal (`reach`)."""
    if "cannot keep its contact" in words:
        return "finger at a joint limit" if "at their limits" in words else "finger cannot follow (joints free)"
    if "collision" in words and "object" in words:
        return "link into the object"
    if "fingers collide" in words or "collision" in words:
        return "hand self-collision"
    if "force closure" in words or "holds" in words or "weight" in words:
        return "no valid state (closure or load)"
    if "loses the object" in words:
        return "finger loses the object"
    return "other: " + words[:60]


def _reach_one(g, T):
    """(fraction of the path's waypoints passed, cause or "", the refusal's words) of ``g`` reposed to ``T``."""
    from planner.errors import MotionError
    from planner.options import PlanOptions
    from planner.repose import repose

    try:
        repose(g, T, PlanOptions.for_execution())
        return 1.0, "", ""
    except MotionError as err:
        words = str(err)
        m = re.search(r"waypoint (\d+)/(\d+)", words)
        frac = (int(m.group(1)) - 1) / (int(m.group(2)) - 1) if m and int(m.group(2)) > 1 else 0.0
        return frac, reach_cause(words), words


def _drive_one(g, T):
    """(fraction of the way the fingers' own path (`experiments.repose_drive.drive_toward`) carries
    the object toward ``T``: 1 minus the distance left over the distance, both in waypoints of
    the straight path (1 mm / 2 deg), and why it stopped, grouped, or "")."""
    from planner.options import PlanOptions
    from experiments.repose_drive import _goal_twist, drive_toward

    T0 = g.obj.T_palm_obj
    move, err = drive_toward(g, T, PlanOptions.for_execution())
    if err is None:
        return 1.0, ""
    total = _goal_twist(T0, T)[1]
    left = total if move is None else _goal_twist(move.poses[-1], T)[1]
    return max(0.0, 1.0 - left / total), reach_cause(str(err))


def finger_reach(g, T) -> dict[str, tuple[float, str]]:
    """finger -> (fraction of the straight path's waypoints toward ``T`` it follows alone, why it
    stops: "follow" (its outermost contact off its object point by more than the follower's
    2 x tolerance, as `planner.repose.repose` refuses it), "deep" (one of its links more than
    `PENETRATION_TOL_M` inside the object) or "" (all the way)) for every finger holding in ``g``,
    each on its own: the path is the object's, so a finger's joints depend on no other finger;
    the grasp's validity along the way (closure, load), which does, is not judged here
    (`planner.intermediate.follow_alone`)."""
    from planner.intermediate import follow_alone
    from planner.repose import _holds, object_path

    poses = object_path(g.obj.T_palm_obj, T)
    twist = float(g.friction.gamma) > 0.0
    out = {}
    for f, h in _holds(g).items():
        passed, why, _, _ = follow_alone(g.hand, g.obj, f, g.q, h, poses, twist)
        out[f] = (passed / (len(poses) - 1), why)
    return out


def _fingers_words(r: dict) -> str:
    return " ".join(f"{f}:{v:.2f}{('/' + w) if w else ''}" for f, (v, w) in r.items())


def thumb_contacts_apart_mm(ga, gb) -> float | None:
    """Distance between the two grasps' outermost thumb contact points on the object (object
    frame), mm: with sticking contacts the thumb can change its point on the object only by a
    gait (lifted and landed), at some pose; None when a grasp has no thumb contact."""
    import numpy as np

    from planner.repose import _holds

    ha, hb = _holds(ga).get("thumb"), _holds(gb).get("thumb")
    if not ha or not hb:
        return None
    return 1000.0 * float(np.linalg.norm(np.asarray(ha[0][2]) - np.asarray(hb[0][2])))


def reach(args) -> dict:
    from planner.grasp import load_grasp
    from planner.realization import realize
    from planner.repose import pose_distance

    manifest = [m for m in read_manifest(args.pairs_dir) if m.get("status", "ok") == "ok"]  # v2: skipped cells
    if args.only:
        manifest = [r for r in manifest if re.search(args.only, r["pair"])]
    rows = []
    for m in manifest:
        name = m["pair"]
        ga = realize(load_grasp(args.pairs_dir / f"{name}_initial.yaml"))
        gb = realize(load_grasp(args.pairs_dir / f"{name}_final.yaml"))
        Ta, Tb = ga.obj.T_palm_obj, gb.obj.T_palm_obj
        mm, deg = pose_distance(Ta, Tb)
        t0 = time.perf_counter()
        fa, ca, wa = _reach_one(ga, Tb)
        fb, cb, wb = _reach_one(gb, Ta)
        da, dca = _drive_one(ga, Tb)
        db, dcb = _drive_one(gb, Ta)
        from planner.options import PlanOptions
        from experiments.repose_drive import meeting

        met = meeting(ga, gb, PlanOptions.for_execution())
        fra, frb = finger_reach(ga, Tb), finger_reach(gb, Ta)
        thumb_sum = fra["thumb"][0] + frb["thumb"][0] if "thumb" in fra and "thumb" in frb else None
        rows.append({"pair": name, "hand": m["hand"], "family": m["family"], "offset_class": m["offset_class"],
                     "pose_mm": round(mm, 3), "pose_deg": round(deg, 3), "reach_a_to_b": round(fa, 3),
                     "cause_a": ca, "reach_b_to_a": round(fb, 3), "cause_b": cb, "meet": fa + fb >= 1.0,
                     "drive_a_to_b": round(da, 3), "drive_cause_a": dca, "drive_b_to_a": round(db, 3),
                     "drive_cause_b": dcb, "drives_meet": met is not None,
                     "fingers_a_to_b": _fingers_words(fra), "fingers_b_to_a": _fingers_words(frb),
                     "thumb_reach_sum": None if thumb_sum is None else round(thumb_sum, 3),
                     "thumb_contacts_apart_mm": (lambda d: None if d is None else round(d, 2))(thumb_contacts_apart_mm(ga, gb)),
                     "seconds": round(time.perf_counter() - t0, 2), "refusal_a": wa, "refusal_b": wb})
        if not args.quiet:
            print(f"{name:32s} {mm:5.1f} mm {deg:5.1f} deg  straight A->B {fa:4.2f} {ca or 'all the way'}; "
                  f"B->A {fb:4.2f} {cb or 'all the way'} | fingers' path A->B {da:4.2f}, B->A {db:4.2f}"
                  f"{'; they meet' if met is not None else ''}", flush=True)
    out = args.out or RESULTS / f"exp10_reach_{args.label}.csv"
    write_csv(out, rows)
    s = {"pairs": len(rows), "a pose on the path both grasps reach": sum(r["meet"] for r in rows),
         "median reach (both directions)": statistics.median([r[k] for r in rows for k in ("reach_a_to_b", "reach_b_to_a")])
         if rows else None}
    s["fingers' path: median reach (both directions)"] = statistics.median(
        [r[k] for r in rows for k in ("drive_a_to_b", "drive_b_to_a")]) if rows else None
    s["fingers' path: moves reaching the other pose"] = sum(r[k] >= 1.0 for r in rows for k in ("drive_a_to_b", "drive_b_to_a"))
    s["straight path: moves reaching the other pose"] = sum(r[k] >= 1.0 for r in rows for k in ("reach_a_to_b", "reach_b_to_a"))
    s["pairs whose drives meet (each toward the other's pose)"] = sum(r["drives_meet"] for r in rows)
    s["fingers alone: finger-moves following the whole path"] = (
        f"{sum(v.endswith(':1.00') for r in rows for k in ('fingers_a_to_b', 'fingers_b_to_a') for v in r[k].split())}"
        f"/{sum(len(r[k].split()) for r in rows for k in ('fingers_a_to_b', 'fingers_b_to_a'))}")
    s["pairs whose thumbs' reaches add up to the path (a pose both thumbs reach)"] = sum(
        (r["thumb_reach_sum"] or 0.0) >= 1.0 for r in rows)
    apart = [r["thumb_contacts_apart_mm"] for r in rows if r["thumb_contacts_apart_mm"] is not None]
    s["thumb contact points apart on the object (min / median mm)"] = \
        f"{min(apart):.1f} / {statistics.median(apart):.1f}" if apart else None
    causes: dict[str, int] = {}
    for r in rows:
        for k in ("cause_a", "cause_b"):
            if r[k]:
                causes[r[k]] = causes.get(r[k], 0) + 1
    for c, n in sorted(causes.items(), key=lambda kv: -kv[1]):
        s[f"stops: {c}"] = f"{n}/{2 * len(rows)} moves"
    print_summary(f"exp10 reach ({out.name})", s)
    return s


def summarize(rows: list[dict]) -> dict:
    s = {}
    for kind in ("pose", "same"):
        kr = [r for r in rows if r.get("kind", "pose") == kind]
        if not kr:
            continue
        kp = [r for r in kr if _is_planned(r)]
        times = [float(r["plan_time_s"]) for r in kr]
        s[f"{kind}: planned"] = f"{len(kp)}/{len(kr)} ({100.0 * len(kp) / len(kr):.0f} %)"
        s[f"{kind}: sound (fresh replay passes all 6)"] = f"{sum(_is_sound(r) for r in kp)}/{len(kp)}"
        s[f"{kind}: median plan time s (all / planned)"] = (
            f"{statistics.median(times):.1f} / "
            + (f"{statistics.median(float(r['plan_time_s']) for r in kp):.1f}" if kp else "-"))
        if kind == "pose" and kp:
            s["pose: planned with reposing moves"] = sum(int(r.get("reposing_moves") or 0) > 0 for r in kp)
        for h in sorted({r["hand"] for r in kr}):
            cells = []
            for cls in CLASSES:
                cr = [r for r in kr if r["hand"] == h and r["offset_class"] == cls]
                if cr:
                    cp = [r for r in cr if _is_planned(r)]
                    cells.append(f"{cls} {len(cp)}/{len(cr)} (sound {sum(_is_sound(r) for r in cp)})")
            s[f"{kind}: {h}"] = ", ".join(cells)
        for fam in FAMILIES:
            fr = [r for r in kr if r["family"] == fam]
            if fr:
                s[f"{kind}: family {fam}"] = f"planned {sum(_is_planned(r) for r in fr)}/{len(fr)}"
        groups: dict[str, list[str]] = {}
        for r in kr:
            if not _is_planned(r):
                groups.setdefault(repose_group(r["refusal"]), []).append(r["pair"])
        for i, (g, pairs) in enumerate(sorted(groups.items(), key=lambda kv: -len(kv[1])), 1):
            s[f"{kind}: refusal {i} ({len(pairs)})"] = f"{g}  [{', '.join(pairs)}]"
        unsound = [f"{r['pair']} {r.get('replay_passed_of_6')} (failed: {r.get('replay_failed', '')})"
                   for r in kp if not _is_sound(r)]
        if unsound:
            s[f"{kind}: planned but not sound"] = "; ".join(unsound)
    return s


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--generate", action="store_true", help="write the grasp pairs and manifest into --pairs-dir")
    mode.add_argument("--generate-v2", action="store_true",
                      help="the v2 pairs, every grasp synthesized (experiments/exp10_v2.py); --pairs-dir default "
                           "experiments/results/exp10_pairs_v2")
    mode.add_argument("--run", action="store_true", help="plan and replay every pair of --pairs-dir")
    mode.add_argument("--summary", type=Path, metavar="CSV", help="no run: the summary of an existing exp10 CSV")
    mode.add_argument("--reach", action="store_true",
                      help="how far each end grasp carries the object toward the other pose (no simulator)")
    ap.add_argument("--pairs-dir", type=Path, default=DEFAULT_PAIRS, help=f"default {DEFAULT_PAIRS}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hands", type=lambda s: s.split(","), default=list(HANDS))
    ap.add_argument("--families", type=lambda s: s.split(","), default=list(FAMILIES))
    ap.add_argument("--classes", type=lambda s: s.split(","), default=list(CLASSES))
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--label", default=None, help="--run: CSV experiments/results/exp10_<label>.csv (required)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--work-dir", type=Path, default=None)
    ap.add_argument("--kinds", type=lambda s: s.split(","), default=["pose", "same"],
                    help="--run: pose (initial -> final, poses differ) and/or same (initial -> same, equal poses)")
    ap.add_argument("--resume", action="store_true",
                    help="--run: keep the rows of an existing exp10_<label>.csv and run only the jobs it lacks")
    ap.add_argument("--no-verify", action="store_true", help="--run: pass --no-verify to plan --execution")
    ap.add_argument("--timeout", type=float, default=PLAN_TIMEOUT_S)
    ap.add_argument("--replay-timeout", type=float, default=REPLAY_TIMEOUT_S)
    ap.add_argument("--max-rounds", type=int, default=None, help="--run: passed to plan (default: the planner's)")
    ap.add_argument("--only", default=None, help="--run: only pairs whose name matches this regex")
    ap.add_argument("--max-pairs", type=int, default=None)
    ap.add_argument("--cpu", type=int, default=None)
    ap.add_argument("--no-pin", action="store_true")
    args = ap.parse_args(argv)
    for c in args.classes:
        if c not in CLASSES:
            ap.error(f"--classes: {c!r} is not one of {', '.join(CLASSES)}")
    if args.summary:
        s = summarize(read_csv(args.summary))
        print_summary(f"exp10 reposing ({args.summary.name})", s)
        return s
    if args.generate:
        return generate(args)
    if args.generate_v2:
        from experiments.exp10_v2 import DEFAULT_PAIRS_V2, generate_v2

        if args.pairs_dir == DEFAULT_PAIRS:
            args.pairs_dir = DEFAULT_PAIRS_V2
        return generate_v2(args)
    if not args.label:
        ap.error("--run and --reach need --label")
    if args.reach:
        return reach(args)
    return run(args)


if __name__ == "__main__":
    main()
