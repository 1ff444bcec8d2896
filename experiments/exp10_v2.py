"""Exp. 10 v2 - reposing pairs whose end grasps come from the product's own synthesis.

The v1 pairs (`experiments.exp10_reposing` ``--generate``) close the fingers by posture and
add a thumb contact: in 35 of their 48 grasps the thumb has a joint within 0.01 rad of a
limit and even their equal-pose controls mostly fail as gaits. v2 makes every end grasp the
way a user would, with ``regrasp synth`` (`planner.synthesis.synthesize`, called in process),
execution-ready (exp8's `experiments.exp8_random_pairs.execution_ready`: one mean contact per
finger, twice the weight held in execution mode's six gravity directions within the torque
limits and its friction reserve, a sampled object at least the replay's drift limit from the
palm), with the default tripod (`planner.synthesis.default_fingers`: thumb, index, middle on
both hands).

Cells: hand (icub_right, allegro_right) x family (sphere, box, cylinder, mesh ellipsoid; sizes
per hand from exp9's `SIZES`, 0.1 kg as v1) x offset class (v1's `CLASSES`: small 5-10 mm and
5-15 deg, medium 10-20 mm and 15-30 deg, large 20-30 mm and 30-45 deg) = 24 pairs. Each cell
draws attempts from ``numpy.random.default_rng([seed, hand, family, class, attempt])``
(deterministic for a ``--seed``; every synthesis gets its seed from that generator):

1. Grasp A: synthesis with the object pose sampled (its position and orientation are the
   synthesis's), one grasp, at most `SYNTH_POSE_ATTEMPTS` candidates; it must be
   execution-ready (synthesis's own verdict, `SynthGrasp.execution_ready`).
2. Pose B = pose A moved by the class's length (uniform) along a uniformly random direction
   and turned by the class's angle (uniform) about a uniformly random axis through the
   object's centre (v1's `moved_block`). A pose B that penetrates the open hand or comes
   closer to the palm than the sampled poses keep (the replay's drift limit, 5 mm: the
   object could settle onto the palm) is re-drawn (at most `POSE_B_TRIES` draws).
3. Grasp B: synthesis at the FIXED pose B (an object block with ``position``/``quat_xyzw``),
   the same fingers, one execution-ready grasp in at most `SYNTH_FIXED_ATTEMPTS` candidates;
   when there is none another pose B is drawn (at most `POSE_B_SYNTHS` syntheses per attempt).
4. The equal-pose control: synthesis at the fixed pose A (up to `CONTROL_N` grasps), the first
   execution-ready one whose mean thumb contact (object frame) is at least
   `CONTROL_THUMB_MOVE_M` (5 mm) from grasp A's.
5. Each file is written, read back and judged as ``check --execution`` judges it (in process:
   `planner.grasp.load_grasp`, `planner.realization.realize`, `execution_refusal`); a file
   that fails is removed and the attempt re-drawn. Finally every written file is checked by a
   fresh ``python -m planner check FILE --execution --json`` (exit codes in the manifest).
   A cell with no pair in `MAX_ATTEMPTS` attempts is written to the manifest as skipped
   (``status`` skipped, with its re-draw reasons; the runner plans only ``status`` ok rows).

Palm grasps (``--palm``) are not used in any cell. Rule: every end grasp is a fingertip
tripod clear of the palm. A palm-supported grasp pins the object's pose to the palm
(``palm: hold`` with the object against it), so a pose B moved 5-30 mm along a random
direction is no longer against the palm and has no palm grasp; mixing one palm end into a pair
would measure leaving the palm (exp9's subject), not reposing between two poses.

Files: ``<pairs-dir>/<hand>_<family>_<class>_{initial,final,same}.yaml`` (default
``experiments/results/exp10_pairs_v2/``), ``meshes/ellipsoid.obj`` and ``manifest.csv``
(the columns the exp10 runner reads, and per grasp the thumb's smallest joint-limit margin).

    python experiments/exp10_reposing.py --generate-v2 [--seed 0]
    python experiments/exp10_reposing.py --run --label L --pairs-dir experiments/results/exp10_pairs_v2
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from experiments.exp8_random_pairs import execution_ready
from experiments.exp9_whole_hand import (FAMILIES, HANDS, MESH_NAME, SIZES, THUMB, _thumb_contact, cli_check,
                                         open_hand_penetration, palm_gap, print_summary, write_csv, write_yaml)
from experiments.exp10_reposing import (CLASSES, CONTROL_THUMB_MOVE_M, MASS_KG, RESULTS, _unit, generation_setup,
                                        moved_block)

DEFAULT_PAIRS_V2 = RESULTS / "exp10_pairs_v2"
#: Candidates of the sampled-pose synthesis (grasp A) and of each fixed-pose synthesis.
SYNTH_POSE_ATTEMPTS = 200
SYNTH_FIXED_ATTEMPTS = 120
#: Pose-B draws per attempt, and fixed-pose syntheses at pose B per attempt.
POSE_B_TRIES = 30
POSE_B_SYNTHS = 4
#: Grasps the control's synthesis at pose A keeps (the first far enough from A's thumb wins).
CONTROL_N = 6
MAX_ATTEMPTS = 30
ROLES = ("initial", "final", "same")


def object_block(hand_name: str, family: str, rng, mesh_rel: str) -> dict:
    """The object block without a pose: exp9's size range for the hand and family, v1's mass."""
    size = [float(round(rng.uniform(lo, hi), 5)) for lo, hi in SIZES[hand_name][family]]
    block = {"shape": "mesh" if family == "mesh" else family, "size": size, "mass_kg": MASS_KG}
    if family == "mesh":
        block["mesh"] = mesh_rel
    return block


def _abs(block: dict, out_dir: Path) -> dict:
    """The block with its mesh path absolute (what synthesis reads in process)."""
    return dict(block, mesh=str((out_dir / block["mesh"]).resolve())) if "mesh" in block else dict(block)


def thumb_margin(g) -> float:
    """The thumb's smallest distance to a joint limit (rad) in a realized grasp."""
    import numpy as np

    f = g.hand.finger(THUMB)
    q = np.asarray(g.q, float)[list(f.q_index)]
    lo = np.asarray(g.hand.lower, float)[list(f.q_index)]
    hi = np.asarray(g.hand.upper, float)[list(f.q_index)]
    return float(np.min(np.minimum(q - lo, hi - q)))


def _synth(hand_name, block, fingers, n, fixed, seed, attempts, kw):
    from planner.synthesis import synthesize

    return synthesize(hand_name, block, fingers, n, fixed=fixed, seed=seed, max_attempts=attempts, **kw)


def _doc(hand_name: str, synth_grasp, block: dict, name: str, description: str) -> dict:
    """A grasp file from a synthesized grasp: its fingers' postures and friction, the object
    block as the pair's (relative mesh, the mass), the hand by name."""
    data = synth_grasp.data
    obj = dict(block, position=[float(v) for v in data["object"]["position"]],
               quat_xyzw=[float(v) for v in data["object"]["quat_xyzw"]])
    return {"schema_version": 1, "name": name, "description": description, "hand": hand_name,
            "object": obj, "friction": dict(data["friction"]), "fingers": data["fingers"]}


def _write_checked(path: Path, doc: dict):
    """Write ``doc`` and judge the file as ``check --execution`` does: (realized grasp, None)
    or (None, why) with the file removed."""
    from planner.grasp import load_grasp
    from planner.realization import execution_refusal, realize

    write_yaml(path, doc)
    path.write_text(path.read_text().replace("experiments/exp9_whole_hand.py --generate",
                                             "experiments/exp10_reposing.py --generate-v2 (experiments/exp10_v2.py)"))
    g = realize(load_grasp(path))
    why = "; ".join(g.problems) if not g.ok else execution_refusal(g)
    if why:
        path.unlink()
        return None, why
    return g, None


def generate_cell(hand, family, cls, seed, out_dir: Path, log=print):
    """(manifest row, redraw reasons) of one cell; the files written when the row's status is ok."""
    import numpy as np

    from planner.objects import GraspObject
    from planner.repose import pose_distance
    from planner.synthesis import default_fingers

    hi, fi, ci = HANDS.index(hand.name), FAMILIES.index(family), list(CLASSES).index(cls)
    (t_lo, t_hi), (r_lo, r_hi) = CLASSES[cls]
    stem = f"{hand.name}_{family}_{cls}"
    fingers = default_fingers(hand)
    kw = execution_ready(hand.name)
    clearance = kw["palm_clearance_m"]
    mesh_abs = (out_dir / "meshes" / MESH_NAME).resolve()
    redraws: list[str] = []
    syntheses = 0

    def fail(attempt, why):
        redraws.append(f"{attempt}: {why}")
        log(f"  {stem} attempt {attempt}: {why}")

    t0 = time.perf_counter()
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([seed, hi, fi, ci, attempt])
        block = object_block(hand.name, family, rng, "meshes/" + MESH_NAME)
        ra = _synth(hand.name, _abs(block, out_dir), fingers, 1, False, int(rng.integers(2**31)),
                    SYNTH_POSE_ATTEMPTS, kw)
        syntheses += 1
        if not ra.grasps or not ra.grasps[0].execution_ready:
            fail(attempt, "no execution-ready grasp with the pose sampled" +
                 (f" ({ra.grasps[0].execution})" if ra.grasps else f" in {ra.attempts} candidates"))
            continue
        sa = ra.grasps[0]
        block_a = dict(block, position=[float(v) for v in sa.data["object"]["position"]],
                       quat_xyzw=[float(v) for v in sa.data["object"]["quat_xyzw"]])
        obj_a = GraspObject.from_data(_abs(block_a, out_dir))
        gap_a = palm_gap(hand, obj_a)
        # pose B: drawn until clear of the open hand and the palm, then a grasp synthesized there
        sb = block_b = obj_b = None
        b_draws = b_synths = 0
        b_why = []
        while b_draws < POSE_B_TRIES and b_synths < POSE_B_SYNTHS:
            b_draws += 1
            dist_m = float(rng.uniform(t_lo, t_hi)) * 1e-3
            angle = math.radians(float(rng.uniform(r_lo, r_hi)))
            shift, axis = _unit(rng) * dist_m, _unit(rng)
            cand, obj_c = moved_block(block_a, shift, axis, angle, mesh_abs)
            if open_hand_penetration(hand, obj_c) > 0.0:
                b_why.append("penetrates the open hand")
                continue
            if palm_gap(hand, obj_c) < clearance:
                b_why.append(f"within {clearance * 1e3:g} mm of the palm")
                continue
            b_synths += 1
            rb = _synth(hand.name, _abs(cand, out_dir), fingers, 1, True, int(rng.integers(2**31)),
                        SYNTH_FIXED_ATTEMPTS, kw)
            syntheses += 1
            if rb.grasps and rb.grasps[0].execution_ready:
                sb, block_b, obj_b = rb.grasps[0], cand, obj_c
                break
            b_why.append("no execution-ready grasp at the fixed pose B")
        if sb is None:
            fail(attempt, f"no pose B with a grasp in {b_draws} draws ({'; '.join(sorted(set(b_why)))})")
            continue
        # the control: another grasp at pose A, its thumb elsewhere
        rc = _synth(hand.name, _abs(block_a, out_dir), fingers, CONTROL_N, True, int(rng.integers(2**31)),
                    SYNTH_FIXED_ATTEMPTS, kw)
        syntheses += 1
        tp_a, _ = _thumb_contact(sa.grasp)
        sc, move = None, None
        for c in rc.grasps:
            if not c.execution_ready:
                continue
            tp_c, _ = _thumb_contact(c.grasp)
            d = float(np.linalg.norm(tp_c - tp_a))
            if d >= CONTROL_THUMB_MOVE_M:
                sc, move = c, d
                break
        if sc is None:
            fail(attempt, f"no execution-ready control at pose A with the thumb >= {CONTROL_THUMB_MOVE_M * 1e3:g} mm "
                          f"from A's ({len(rc.grasps)} grasps found)")
            continue
        mm, deg = pose_distance(obj_a.T_palm_obj, obj_b.T_palm_obj)
        desc = f"exp10 v2 reposing pair {stem} (seed {seed}, attempt {attempt}), synthesized ({','.join(fingers)}): "
        docs = {
            "initial": _doc(hand.name, sa, block_a, f"{stem}_initial", desc + "pose A (sampled by synthesis)"),
            "final": _doc(hand.name, sb, block_b, f"{stem}_final",
                          desc + f"pose B: pose A moved {mm:.1f} mm and turned {deg:.1f} deg"),
            "same": _doc(hand.name, sc, block_a, f"{stem}_same",
                         desc + f"pose A, another synthesized grasp, thumb {move * 1e3:.1f} mm away (the equal-pose control)"),
        }
        realized, bad = {}, None
        for role in ROLES:
            g, why = _write_checked(out_dir / f"{stem}_{role}.yaml", docs[role])
            if g is None:
                bad = f"the written {role} file fails check --execution: {why[:160]}"
                break
            realized[role] = g
        if bad:
            for role in ROLES:
                (out_dir / f"{stem}_{role}.yaml").unlink(missing_ok=True)
            fail(attempt, bad)
            continue
        row = {"pair": stem, "status": "ok", "hand": hand.name, "family": family, "offset_class": cls,
               "mass_kg": MASS_KG, "size": " ".join(f"{s:g}" for s in block["size"]), "fingers": ",".join(fingers),
               "seed": seed, "attempt": attempt, "redraws": len(redraws), "syntheses": syntheses,
               "pose_b_draws": b_draws, "pose_mm": round(mm, 3), "pose_deg": round(deg, 3),
               "position_a": " ".join(f"{v:g}" for v in block_a["position"]),
               "quat_a": " ".join(f"{v:g}" for v in block_a["quat_xyzw"]),
               "position_b": " ".join(f"{v:g}" for v in block_b["position"]),
               "quat_b": " ".join(f"{v:g}" for v in block_b["quat_xyzw"]),
               "palm_gap_a_mm": round(gap_a * 1e3, 3), "palm_gap_b_mm": round(palm_gap(hand, obj_b) * 1e3, 3),
               "synth_attempt_a": sa.attempt, "synth_attempt_b": sb.attempt, "synth_attempt_same": sc.attempt,
               "metric_initial": round(sa.metric, 5), "metric_final": round(sb.metric, 5),
               "metric_same": round(sc.metric, 5),
               "control_thumb_move_mm": round(move * 1e3, 2),
               **{f"thumb_limit_margin_{r}": round(thumb_margin(realized[r]), 4) for r in ROLES},
               "redraw_reasons": " | ".join(redraws), "seconds": round(time.perf_counter() - t0, 1),
               "initial": f"{stem}_initial.yaml", "final": f"{stem}_final.yaml", "same": f"{stem}_same.yaml"}
        return row
    return {"pair": stem, "status": "skipped", "hand": hand.name, "family": family, "offset_class": cls,
            "mass_kg": MASS_KG, "fingers": ",".join(fingers), "seed": seed, "attempt": MAX_ATTEMPTS,
            "redraws": len(redraws), "syntheses": syntheses, "redraw_reasons": " | ".join(redraws),
            "seconds": round(time.perf_counter() - t0, 1), "initial": "", "final": "", "same": ""}


def generate_v2(args) -> dict:
    from planner.grasp import load_hand

    out, cpu, log = generation_setup(args)
    rows = []
    t0 = time.perf_counter()
    for hand_name in args.hands:
        hand = load_hand(hand_name)
        for family in args.families:
            for cls in args.classes:
                row = generate_cell(hand, family, cls, args.seed, out, log=log)
                if row["status"] == "ok":
                    for role in ROLES:
                        code, _, _ = cli_check(out / row[role], out, cpu, execution=True)
                        row[f"{role}_check_exit"] = code
                rows.append(row)
                write_csv(out / "manifest.csv", rows)
                if row["status"] != "ok":
                    print(f"{row['pair']}: SKIPPED, no pair in {MAX_ATTEMPTS} attempts ({row['seconds']:.0f} s)",
                          flush=True)
                    continue
                print(f"{row['pair']}: attempt {row['attempt']} ({row['redraws']} re-drawn, {row['syntheses']} "
                      f"syntheses), pose {row['pose_mm']:.1f} mm / {row['pose_deg']:.1f} deg, palm gap "
                      f"{row['palm_gap_a_mm']:.1f}/{row['palm_gap_b_mm']:.1f} mm, thumb limit margins "
                      f"{row['thumb_limit_margin_initial']:.3f}/{row['thumb_limit_margin_final']:.3f}/"
                      f"{row['thumb_limit_margin_same']:.3f} rad; check --execution exits "
                      f"{row['initial_check_exit']} {row['final_check_exit']} {row['same_check_exit']} "
                      f"({row['seconds']:.0f} s)", flush=True)
    ok = [r for r in rows if r["status"] == "ok"]
    s = {"pairs": f"{len(ok)}/{len(rows)}", "skipped": " ".join(r["pair"] for r in rows if r["status"] != "ok") or "-",
         "attempts": sum(int(r["attempt"]) + 1 for r in ok) + sum(MAX_ATTEMPTS for r in rows if r not in ok),
         "re-drawn attempts": sum(int(r["redraws"]) for r in rows),
         "syntheses": sum(int(r["syntheses"]) for r in rows),
         "check --execution not 0 (should be 0)": sum(
             any(r[f"{k}_check_exit"] != 0 for k in ROLES) for r in ok),
         "thumb joint within 0.01 rad of a limit (grasps)": f"{sum(r[f'thumb_limit_margin_{k}'] < 0.01 for r in ok for k in ROLES)}"
                                                           f"/{3 * len(ok)}",
         "wall s": round(time.perf_counter() - t0, 1), "manifest": str(out / "manifest.csv")}
    print_summary("exp10 v2 generate", s)
    return s
