"""Exp. 4 - robustness to object shape variations (thesis section IX-C).

The parallel-extension -> IR2M pairs with the object's size varied around the nominal
(+/-30 %): box uniformly and along each axis, cylinder radius and length. Contact points
keep their tangential position and move onto the new surface (method "points",
`experiments.common.scaled_spec`; posture fingers re-closed from their postures), or every
finger is re-closed from its nominal realized posture (method "postures"). The object's
pad-side face stays where it was (it still rests on the finger pads). Success = both grasps realized force closure and
a finger-gaiting plan found (also reported: whether every finger the file
wants on the object touches it) (graph search, no OMPL
paths: motion=False). Then, as the thesis did, the pair is executed: planned again with
finger paths under the "mean" contact model (the executable plan) and replayed in pybullet
palm up (`planner.sim.replay.replay_plan`); its verdict, drift and closure agreement are
recorded, and "plan + replay" success needs both (`--no-replay`: planning only). The
executable plan is also made gravity-aware (`PlanOptions.gravity`: every state holds the
weight with at most the replay's squeeze force per finger) and replayed ("g_" columns).

    python experiments/exp4_shape_robustness.py [--quick] [--workers N] [--no-replay]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import REPLAY_CONTACT_MODEL, REPLAY_FINGER_FORCE_N, REPLAY_GRAVITY, grasp_pairs, load_spec, parser, print_summary, pyplot, realized, run_tasks, save, scaled_spec, write_csv  # noqa: E402

MODES = {
    "box": {"uniform": (1, 1, 1), "x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)},
    "cylinder": {"radius": (1, 0), "length": (0, 1), "uniform": (1, 1)},
    "sphere": {"radius": (1,)},
}


def factors(mode_axes, s):
    return tuple(s if a else 1.0 for a in mode_axes)


def as_postures(path: str):
    """The grasp with every contact finger turned into a posture finger at its nominal
    realized joint values (re-closed onto the scaled object by `realize`)."""
    from dataclasses import replace

    spec, g = load_spec(path), realized(path)
    return replace(spec, fingers=tuple(
        replace(f, kind="posture", point_obj=None, link=None, posture=tuple(float(v) for v in g.finger_q[f.name]))
        if f.kind == "contact" else f for f in spec.fingers))


def task(t: dict) -> dict:
    from planner.errors import PlannerError
    from planner.grasp import load_hand
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp

    row = {"pair": t["pair"], "method": t["method"], "mode": t["mode"], "scale": t["scale"]}
    t0 = time.perf_counter()
    si = scaled_spec(as_postures(t["initial"]) if t["method"] == "postures" else load_spec(t["initial"]), t["factors"])
    sf = scaled_spec(as_postures(t["final"]) if t["method"] == "postures" else load_spec(t["final"]), t["factors"])
    row["size"] = " ".join(f"{v:.4f}" for v in si.object.size)
    hand = load_hand(si.hand_ref)
    try:
        gi, gf = realize(si, hand), realize(sf, hand)
    except PlannerError as err:
        row.update(realized=False, reason=f"realize: {type(err).__name__}: {str(err).split(': ', 1)[-1]}"[:200], planned=False, success=False)
        row["time_s"] = time.perf_counter() - t0
        return row
    row.update(realized=True, initial_fc=gi.is_force_closure, final_fc=gf.is_force_closure,
               initial_metric=gi.metric, final_metric=gf.metric,
               missing=" ".join(gi.missing + gf.missing))
    ok_grasps = gi.is_force_closure and gf.is_force_closure
    row["all_fingers_touch"] = not gi.missing and not gf.missing
    try:
        res = plan_regrasp(gi, gf, PlanOptions(motion=False))
        row.update(planned=True, gait_steps=res.sequence.gait_steps, bottleneck=res.sequence.bottleneck,
                   order=" ".join(res.sequence.order(res.graph.graph["problem"])), graph_nodes=res.graph.number_of_nodes())
    except PlannerError as err:
        res = None
        row.update(planned=False, reason=str(err)[:160])
    row["success"] = bool(ok_grasps and row["planned"])
    row["success_all_fingers"] = bool(row["success"] and row["all_fingers_touch"])
    if t["replay"] and ok_grasps:
        # executable plans: one mean contact per finger, finger paths, replayed palm up;
        # "g_": the same, planned gravity-aware (every state holds the weight with at most
        # the replay's squeeze force per finger)
        from planner.sim.replay import replay_plan

        for prefix, opts in (("", PlanOptions(contact_model=REPLAY_CONTACT_MODEL)),
                             ("g_", PlanOptions(contact_model=REPLAY_CONTACT_MODEL, gravity=REPLAY_GRAVITY,
                                                max_finger_force_n=REPLAY_FINGER_FORCE_N))):
            try:
                res_m = plan_regrasp(gi, gf, opts)
            except PlannerError as err:
                row.update({f"{prefix}replay_planned": False, f"{prefix}replay_passed": False,
                            f"{prefix}replay_verdict": f"{type(err).__name__}: {err}"[:120]})
                continue
            rep = replay_plan(res_m.plan.to_dict(), gravity=REPLAY_GRAVITY, finger_force_n=REPLAY_FINGER_FORCE_N)
            row.update({f"{prefix}replay_planned": True, f"{prefix}replay_passed": rep.passed,
                        f"{prefix}replay_verdict": rep.verdict[:120], f"{prefix}replay_max_drift_mm": rep.max_drift_mm,
                        f"{prefix}replay_max_drift_deg": rep.max_drift_deg,
                        f"{prefix}replay_closure_agree": f"{rep.closure_agreement[0]}/{rep.closure_agreement[1]}"})
            if not prefix:
                row.update(replay_limit_mm=rep.drift_mm_max, replay_limit_deg=rep.drift_deg_max)
    if t["replay"]:
        row["success_replay"] = bool(row["success"] and row.get("replay_passed", False))
        row["g_success_replay"] = bool(row["success"] and row.get("g_replay_passed", False))
        # a plan that was made but dropped the object: the failure a user does not see coming
        row["false_plan"] = bool(row.get("replay_planned") and not row.get("replay_passed"))
        row["g_false_plan"] = bool(row.get("g_replay_planned") and not row.get("g_replay_passed"))
    row["time_s"] = time.perf_counter() - t0
    return row


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--no-replay", dest="replay", action="store_false",
                    help="planning and closure only (no OMPL paths, no pybullet replay)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    scales = [0.7, 0.9, 0.95, 1.0, 1.05, 1.1, 1.3] if args.quick else [float(round(x, 2)) for x in np.arange(0.7, 1.301, 0.05)]
    tasks = []
    for name, ini, fin in grasp_pairs():
        shape = load_spec(ini).object.shape
        modes = MODES.get(shape, {})
        if args.quick:
            modes = {k: v for k, v in modes.items() if k in ("uniform", "radius")}
        for method in ("points", "postures"):
            for mode, axes in modes.items():
                for s in scales:
                    tasks.append({"pair": name, "initial": ini, "final": fin, "method": method, "mode": mode, "scale": s,
                                  "factors": factors(axes, s), "replay": args.replay})
    rows = run_tasks(task, tasks, args, desc="exp4 shape variations")
    write_csv(args.out / "exp4_shape_robustness.csv", rows)

    plt = pyplot()
    groups = sorted({(r["pair"], r["method"], r["mode"]) for r in rows})
    fig, ax = plt.subplots(1, 3 if args.replay else 2, figsize=(16 if args.replay else 11, 4))
    for pair, method, mode in groups:
        sub = sorted((r for r in rows if (r["pair"], r["method"], r["mode"]) == (pair, method, mode)), key=lambda r: r["scale"])
        mode = f"{mode} ({method})"
        x = [r["scale"] for r in sub]
        ax[0].plot(x, [r.get("bottleneck", np.nan) if r["success"] else np.nan for r in sub], "o-", label=f"{pair} {mode}")
        ax[0].plot([r["scale"] for r in sub if not r["success"]], [0] * sum(not r["success"] for r in sub), "x", color="red")
        ax[1].plot(x, [r.get("initial_metric", np.nan) for r in sub], "o-", label=f"{pair} {mode}: initial")
        ax[1].plot(x, [r.get("final_metric", np.nan) for r in sub], "s--", label=f"{pair} {mode}: final")
        if args.replay:
            line, = ax[2].plot(x, [r.get("replay_max_drift_deg", np.nan) for r in sub], "o-", label=f"{pair} {mode}")
            failed = [r for r in sub if not r.get("success_replay")]
            ax[2].plot([r["scale"] for r in failed], [r["replay_max_drift_deg"] if np.isfinite(r.get("replay_max_drift_deg", np.nan)) else 0.3
                                                    for r in failed], "x", color="red", ms=8)
    ax[0].set_xlabel("size scale (x nominal)")
    ax[0].set_ylabel("plan bottleneck metric (x at 0: failed)")
    ax[0].set_title("planning success and bottleneck")
    ax[0].legend(fontsize=7)
    ax[1].axhline(0, color="k", lw=0.8)
    ax[1].set_xlabel("size scale (x nominal)")
    ax[1].set_ylabel("grasp metric")
    ax[1].set_title("realized initial / final grasp metrics")
    ax[1].legend(fontsize=6, ncol=2)
    if args.replay:
        limit = next((r["replay_limit_deg"] for r in rows if "replay_limit_deg" in r), None)
        if limit is not None:
            ax[2].axhline(limit, color="k", ls="--", lw=0.8, label="pass limit (rotation)")
        ax[2].set_xlabel("size scale (x nominal)")
        ax[2].set_yscale("log")
        ax[2].set_ylabel("replay max rotation drift (deg; x at 0.3: no plan)")
        ax[2].set_title("plan + replay (mean contacts, palm up; x: failed)")
        ax[2].legend(fontsize=6)
    save(fig, args.out / "exp4_shape_robustness.png")

    summary = {"variations": len(rows), "success": f"{sum(r['success'] for r in rows)}/{len(rows)}",
               "replay": "on" if args.replay else "off (planning + closure only)"}
    if args.replay:
        summary["success plan + replay"] = f"{sum(bool(r.get('success_replay')) for r in rows)}/{len(rows)}"
        summary["gravity-aware plan + replay"] = f"{sum(bool(r.get('g_success_replay')) for r in rows)}/{len(rows)}"
        summary["plans that fail in the replay (plain / gravity-aware)"] = (
            f"{sum(bool(r.get('false_plan')) for r in rows)}/{sum(bool(r.get('replay_planned')) for r in rows)} / "
            f"{sum(bool(r.get('g_false_plan')) for r in rows)}/{sum(bool(r.get('g_replay_planned')) for r in rows)}")
    for pair, method, mode in groups:
        sub = [r for r in rows if (r["pair"], r["method"], r["mode"]) == (pair, method, mode)]
        mode = f"{mode} ({method})"
        ok = sorted(r["scale"] for r in sub if r["success"])
        bad = sorted(r["scale"] for r in sub if not r["success"])
        strict = sum(bool(r.get("success_all_fingers")) for r in sub)
        summary[f"{pair} {mode}"] = f"{len(ok)}/{len(sub)} succeed ({strict} with every finger touching); failed at {bad}"
        if args.replay:
            ok_r = sorted(r["scale"] for r in sub if r.get("success_replay"))
            summary[f"{pair} {mode} plan + replay"] = f"{len(ok_r)}/{len(sub)} pass, scales {ok_r}"
            ok_g = sorted(r["scale"] for r in sub if r.get("g_success_replay"))
            refused = sum(1 for r in sub if r.get("success") and r.get("g_replay_planned") is False)
            summary[f"{pair} {mode} gravity-aware plan + replay"] = (
                f"{len(ok_g)}/{len(sub)} pass, {refused} refused, scales {ok_g}")
    summary["wall_s"] = time.perf_counter() - t0
    print_summary("exp4 shape robustness", summary)
    return summary


if __name__ == "__main__":
    main()
