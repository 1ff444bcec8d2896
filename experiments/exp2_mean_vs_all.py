"""Exp. 2 - mean contact versus all patch points (thesis fig. 13).

Along the box plan's states a, b1, c1, d, e1, f (thesis fig. 11: a initial; b1 index
lifted; c1 index final, ring lifted; d index and ring final; e1 little lifted; f little
and thumb lifted = final) and for each finger's removal test ("a-i": state a without the
index), the closure metric from one mean point / mean normal per finger versus from all
points of every patch.

Three sources of contacts:
* plan: the planner's geometric patches (noise free);
* noisy: the plan's patches with simulator-like corruption, many seeds: point noise
  (--point-noise-mm), normal noise (--normal-noise-deg) and each point kept with probability
  --keep (unsynchronised contact samples, thesis table I); reported as the fraction of
  seeds whose force-closure decision agrees with the noise-free all-points decision;
* sim: the filtered pybullet contacts of `planner.sim.replay.replay_plan` at the plan's
  states, when the replay reaches them.

    python experiments/exp2_mean_vs_all.py [--quick] [--workers N]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import (  # noqa: E402
    REPLAY_CONTACT_MODEL,
    REPLAY_GRAVITY,
    parser,
    print_summary,
    pyplot,
    realized,
    run_tasks,
    save,
    write_csv,
)

INITIAL = "grasps/icub/box_parallel_extension.yaml"
FINAL = "grasps/icub/box_ir2m.yaml"
#: thesis fig. 11 states: finger -> slot label (fingers not named keep the previous label)
THESIS_STATES = [
    ("a", {}),
    ("b1", {"index": "lifted"}),
    ("c1", {"index": "final", "ring": "lifted"}),
    ("d", {"ring": "final"}),
    ("e1", {"little": "lifted"}),
    ("f", {"thumb": "lifted"}),
]
LETTER = {"thumb": "t", "index": "i", "middle": "m", "ring": "r", "little": "l"}


def thesis_states(problem):
    """[(name, labels {finger: label})] of the thesis sequence, on this problem's slots."""
    labels = problem.labels(problem.start)
    out = []
    for name, change in THESIS_STATES:
        labels = dict(labels, **change)
        out.append((name, dict(labels)))
    return out


def patches_of(problem, labels):
    out = {}
    for f in problem.fingers:
        if labels[f] == "lifted":
            continue
        slot = next(s for s in problem.slots[f] if s.label == labels[f])
        out[f] = (np.asarray(slot.points), np.asarray(slot.normals))
    return out


def mean_patches(patches):
    """One mean contact per finger (the planner's "mean" contact model)."""
    from planner.closure import apply_contact_model

    return apply_contact_model(patches, "mean")


def tests(state_name, patches):
    """[(label, patches)]: the state itself, then each touching finger removed."""
    out = [(state_name, patches)]
    for f in patches:
        out.append((f"{state_name}-{LETTER.get(f, f)}", {g: v for g, v in patches.items() if g != f}))
    return out


def metrics(patches, friction):
    from planner.closure import grasp_closure

    if not patches:
        return float("nan"), float("nan")
    return grasp_closure(patches, friction).metric, grasp_closure(mean_patches(patches), friction).metric


def _problem():
    from planner.options import PlanOptions
    from planner.slots import build_problem

    a, b = realized(INITIAL), realized(FINAL)
    return a, build_problem(a, b, PlanOptions(motion=False))


def corrupt(patches, rng, point_sigma_m, normal_sigma_rad, keep):
    out = {}
    for f, (p, n) in patches.items():
        p = np.asarray(p, float)
        n = np.asarray(n, float)
        mask = rng.random(len(p)) < keep
        if not mask.any():
            mask[rng.integers(len(p))] = True
        p = p[mask] + rng.normal(0.0, point_sigma_m, size=(mask.sum(), 3))
        n = n[mask] + rng.normal(0.0, normal_sigma_rad, size=(mask.sum(), 3))
        out[f] = (p, n / np.linalg.norm(n, axis=1, keepdims=True))
    return out


def noisy_task(t: dict) -> list[dict]:
    a, problem = _problem()
    rng = np.random.default_rng(t["seed"])
    rows = []
    for name, labels in thesis_states(problem):
        noisy = corrupt(patches_of(problem, labels), rng, t["point_sigma_m"], t["normal_sigma_rad"], t["keep"])
        for label, pt in tests(name, noisy):
            m_all, m_mean = metrics(pt, a.friction)
            rows.append({"seed": t["seed"], "test": label, "metric_all": m_all, "metric_mean": m_mean})
    return rows


def sim_metrics(a, b) -> tuple[dict, str]:
    """test label -> (all, mean) metrics from replay contacts, and a status line."""
    from planner.errors import PlannerError

    try:
        from planner.options import PlanOptions
        from planner.regrasp import plan_regrasp
        from planner.sim.replay import replay_plan

        res = plan_regrasp(a, b, PlanOptions(contact_model=REPLAY_CONTACT_MODEL))
        report = replay_plan(res.plan.to_dict(), gravity=REPLAY_GRAVITY)
    except (ImportError, PlannerError) as err:  # optional: no pybullet, no sequence, a failed replay
        return {}, f"replay unavailable: {type(err).__name__}: {err}"
    problem_states = {tuple(sorted(s.fingers.items())): i for i, s in enumerate(res.plan.states)}
    _, problem = _problem()
    out = {}
    reached = 0
    for name, labels in thesis_states(problem):
        i = problem_states.get(tuple(sorted(labels.items())))
        if i is None or not report.states[i].reached or not report.states[i].sim_patches:
            continue
        reached += 1
        sp = {f: v for f, v in report.states[i].sim_patches.items() if f != "palm"}
        for label, pt in tests(name, sp):
            out[label] = metrics(pt, a.friction)
    return out, f"{report.verdict}; thesis states with sim contacts: {reached}/{len(THESIS_STATES)}"


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=None, help="noisy repetitions (default 16 quick, 200 full)")
    ap.add_argument("--point-noise-mm", type=float, default=1.0)
    ap.add_argument("--normal-noise-deg", type=float, default=10.0)
    ap.add_argument("--keep", type=float, default=0.5)
    ap.add_argument("--no-sim", action="store_true", help="skip the pybullet replay")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    a, problem = _problem()
    b = realized(FINAL)
    base = {}
    for name, labels in thesis_states(problem):
        for label, pt in tests(name, patches_of(problem, labels)):
            base[label] = metrics(pt, a.friction)
    sim, sim_status = ({}, "skipped (--no-sim)") if args.no_sim else sim_metrics(a, b)

    n_seeds = args.seeds or (16 if args.quick else 200)
    tasks = [{"seed": args.seed * 100_003 + s, "point_sigma_m": args.point_noise_mm * 1e-3,
              "normal_sigma_rad": np.radians(args.normal_noise_deg), "keep": args.keep} for s in range(n_seeds)]
    noisy = [r for rows in run_tasks(noisy_task, tasks, args, desc="exp2 noisy contacts") for r in rows]

    rows = []
    for label, (m_all, m_mean) in base.items():
        sub = [r for r in noisy if r["test"] == label]
        fc_ref = m_all > 0
        na = np.array([r["metric_all"] for r in sub])
        nm = np.array([r["metric_mean"] for r in sub])
        s_all, s_mean = sim.get(label, (float("nan"), float("nan")))
        rows.append({
            "test": label,
            "plan_metric_all": m_all, "plan_metric_mean": m_mean,
            "plan_fc_all": m_all > 0, "plan_fc_mean": m_mean > 0,
            "noisy_agree_all": float(np.mean((na > 0) == fc_ref)),
            "noisy_agree_mean": float(np.mean((nm > 0) == fc_ref)),
            "noisy_self_agree_mean": float(np.mean((nm > 0) == (m_mean > 0))),
            "noisy_metric_all_mean": float(na.mean()), "noisy_metric_all_std": float(na.std()),
            "noisy_metric_mean_mean": float(nm.mean()), "noisy_metric_mean_std": float(nm.std()),
            "sim_metric_all": s_all, "sim_metric_mean": s_mean,
        })
    write_csv(args.out / "exp2_mean_vs_all.csv", rows)

    plt = pyplot()
    x = np.arange(len(rows))
    fig, ax = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    w = 0.38
    ax[0].bar(x - w / 2, [r["plan_metric_mean"] for r in rows], w, label="mean point/normal per finger", color="tab:blue")
    ax[0].bar(x + w / 2, [r["plan_metric_all"] for r in rows], w, label="all points", color="tab:orange")
    if sim:
        ax[0].plot(x, [r["sim_metric_mean"] for r in rows], "v", color="navy", label="sim contacts, mean")
        ax[0].plot(x, [r["sim_metric_all"] for r in rows], "^", color="darkred", label="sim contacts, all")
    ax[0].axhline(0, color="k", lw=0.8)
    ax[0].set_yscale("symlog", linthresh=0.02)
    ax[0].set_ylabel("metric (<0: not force closure)")
    ax[0].set_title("planner patches (noise free)" + ("" if sim else f" - sim: {sim_status[:60]}"))
    ax[0].legend(fontsize=8, ncol=2)
    ax[1].bar(x - w / 2, [r["noisy_agree_mean"] for r in rows], w, label="mean", color="tab:blue")
    ax[1].bar(x + w / 2, [r["noisy_agree_all"] for r in rows], w, label="all points", color="tab:orange")
    ax[1].set_ylabel("FC decision agrees\nwith noise-free (fraction)")
    ax[1].set_title(f"noisy contacts ({n_seeds} seeds: {args.point_noise_mm} mm, {args.normal_noise_deg} deg, keep {args.keep})")
    ax[1].set_ylim(0, 1.05)
    ax[1].legend(fontsize=8)
    ax[1].set_xticks(x)
    ax[1].set_xticklabels([r["test"] for r in rows], rotation=90, fontsize=8)
    save(fig, args.out / "exp2_mean_vs_all.png")

    disagree = [r["test"] for r in rows if r["plan_fc_all"] != r["plan_fc_mean"]]
    summary = {
        "tests": len(rows),
        "plan_fc_decisions_differ_mean_vs_all": f"{len(disagree)} ({', '.join(disagree)})",
        "plan_metric_ratio_mean_over_all_median": float(np.median([r["plan_metric_mean"] / r["plan_metric_all"] for r in rows if r["plan_metric_all"] > 0])),
        "noisy_agreement_all_points": float(np.mean([r["noisy_agree_all"] for r in rows])),
        "noisy_agreement_mean_point": float(np.mean([r["noisy_agree_mean"] for r in rows])),
        "noisy_mean_point_agrees_with_its_own_noise_free": float(np.mean([r["noisy_self_agree_mean"] for r in rows])),
        "noisy_seeds": n_seeds,
        "sim": sim_status,
        "sim_tests": len(sim),
        "wall_s": time.perf_counter() - t0,
    }
    print_summary("exp2 mean vs all", summary)
    return summary


if __name__ == "__main__":
    main()
