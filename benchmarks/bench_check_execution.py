"""Does ``regrasp check --execution`` agree with ``plan --execution``'s own validity test?

Run: ``python benchmarks/bench_check_execution.py [--quick] [--json FILE]``.

End grasps, seeded: the bundled grasps (``grasps/``) at their own mass and at 0.03, 0.1, 0.3
and 2 kg, and grasps from `planner.synthesis.synthesize` (``regrasp synth``, the object's
pose sampled) on both bundled hands (icub_right, allegro_right) around a sphere, a box, a
cylinder and a plate, each at 0.03, 0.1, 0.3 and 2 kg. Every grasp is written as a file and
judged twice, independently:

* ``regrasp check FILE --execution --no-verify --json`` (the static test) (`planner.cli.main`): its ``execution.accepted``
  verdict, its exit code and the planner's reason it quotes;
* ``planner.plan(FILE, FILE, execution=True, motion=False, verify=False)``: the grasp is the
  plan's initial and final grasp, so the plan is returned exactly when the planner accepts it
  as an end grasp, and refused (`PlannerError`) with its reason otherwise.

It prints the agreement count, every disagreement and the grasps check fails for another
reason (not as written: a penetration, a finger closed to its limit) while the planner
accepts them, and how the 2 kg grasps are refused (every failing direction's limiting joint
named); it exits 1 on a disagreement of the verdicts.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planner.api import plan, synth  # noqa: E402
from planner.cli import main  # noqa: E402
from planner.errors import PlannerError  # noqa: E402

HANDS = ("icub_right", "allegro_right")
MASSES = (0.03, 0.1, 0.3, 2.0)
#: Objects synthesized around, their pose sampled (the ``object:`` block of a grasp file).
OBJECTS = {
    "sphere": {"shape": "sphere", "size": [0.03]},
    "box": {"shape": "box", "size": [0.04, 0.05, 0.06]},
    "cylinder": {"shape": "cylinder", "size": [0.025, 0.08]},
    "plate": {"shape": "box", "size": [0.07, 0.06, 0.006]},
}
SEED = 0


def bundled() -> list[tuple[str, dict]]:
    """(label, grasp data) of every bundled grasp, its hand and mesh paths made absolute."""
    out = []
    for path in sorted((ROOT / "grasps").glob("*/*.yaml")):
        data = yaml.safe_load(path.read_text())
        obj = data["object"]
        if "mesh" in obj:
            obj["mesh"] = str((path.parent / obj["mesh"]).resolve())
        if "/" in data["hand"] or data["hand"].endswith((".yaml", ".yml")):
            data["hand"] = str((path.parent / data["hand"]).resolve())
        out.append((f"{path.parent.name}/{path.stem}", data))
    return out


def synthesized(n: int, objects=OBJECTS, hands=HANDS) -> list[tuple[str, dict]]:
    """(label, grasp data) of ``n`` seeded `synthesize` grasps per hand and object."""
    out = []
    for hand in hands:
        for name, block in objects.items():
            fingers = "thumb,index,middle"
            res = synth(hand, dict(block, mass_kg=0.1), fingers, n, fixed=False, seed=SEED, max_attempts=60 * n)
            out += [(f"synth/{hand}/{name}/{i}", g.data) for i, g in enumerate(res.grasps)]
    return out


def with_mass(data: dict, mass_kg: float | None) -> dict:
    """The grasp data with another object mass (None: the file's own)."""
    if mass_kg is None:
        return data
    d = json.loads(json.dumps(data))
    d["object"]["mass_kg"] = float(mass_kg)
    d["name"] = f"{d.get('name', 'grasp')}_{mass_kg:g}kg"
    return d


def judge(path: Path) -> dict:
    """The two verdicts on one grasp file (module docstring)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["check", str(path), "--execution", "--no-verify", "--json"])
    row = {"check_exit": code}
    if code == 2:  # bad input: no report
        row.update(check_accepted=None, check_reason=None, failing=[])
    else:
        ex = json.loads(buf.getvalue())["execution"]
        row.update(check_accepted=ex["accepted"], check_reason=ex["reason"], failing=ex["failing"])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            plan(path, path, execution=True, motion=False, verify=False)
        row.update(plan_accepted=True, plan_reason=None)
    except PlannerError as err:
        row.update(plan_accepted=False, plan_reason=str(err))
    return row


def reasons_match(row: dict) -> bool:
    """The planner's refusal quotes the reason check gives (or says the same: not force closure)."""
    c, p = row["check_reason"], row["plan_reason"]
    if c is None or p is None:
        return c is None and p is None
    return c in p or (c == "not force closure" and "is not force closure" in p)


def run(cases: list[tuple[str, dict]], masses=(None,) + MASSES, log=print) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, data) in enumerate(cases):
            for m in masses:
                path = Path(tmp) / f"g{k}_{'own' if m is None else m}.yaml"
                path.write_text(yaml.safe_dump(with_mass(data, m), sort_keys=False))
                row = {"grasp": label, "mass_kg": m, **judge(path)}
                rows.append(row)
                if row["check_accepted"] != row["plan_accepted"]:
                    log(f"DISAGREE {label} {m} kg: check {row['check_accepted']} ({row['check_reason']}), "
                        f"plan {row['plan_accepted']} ({row['plan_reason']})")
    return rows


def summary(rows: list[dict]) -> dict:
    agree = [r for r in rows if r["check_accepted"] == r["plan_accepted"]]
    heavy = [r for r in rows if r["mass_kg"] == 2.0]
    heavy_named = [r for r in heavy if not r["check_accepted"] and r["check_exit"] == 1 and r["failing"]
                   and (r["failing"][0]["limit"] or {}).get("joint")
                   and r["check_reason"].startswith(r["failing"][0]["direction"] + ":")]
    return {
        "grasps": len(rows),
        "agree": len(agree),
        "disagree": [r for r in rows if r not in agree],
        "reasons_match": sum(reasons_match(r) for r in agree),
        "accepted": sum(bool(r["plan_accepted"]) for r in rows),
        "refused": sum(not r["plan_accepted"] for r in rows),
        "check_stricter": [r for r in rows if r["plan_accepted"] and r["check_exit"] == 1],
        "heavy": len(heavy),
        "heavy_refused": sum(not r["check_accepted"] for r in heavy),
        "heavy_named": len(heavy_named),
        "heavy_unnamed": [r for r in heavy if not r["check_accepted"] and r not in heavy_named],
    }


def main_(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 synthesized grasps per hand and object (default 6)")
    ap.add_argument("--json", metavar="FILE", help="write every row and the summary here")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    cases = bundled() + synthesized(2 if args.quick else 6)
    t1 = time.perf_counter()
    rows = run(cases)
    s = summary(rows)
    print(f"{len(cases)} grasps ({len(cases) - len(bundled())} synthesized in {t1 - t0:.0f} s) x {len(MASSES) + 1} "
          f"masses = {s['grasps']} end grasps judged in {time.perf_counter() - t1:.0f} s")
    print(f"agree: {s['agree']}/{s['grasps']} (planner accepts {s['accepted']}, refuses {s['refused']}); the "
          f"planner's reason is check's in {s['reasons_match']}/{s['agree']}")
    print(f"2 kg: {s['heavy_refused']}/{s['heavy']} refused, {s['heavy_named']} naming the failing direction and "
          f"its limiting joint" + (f"; without a joint: " + "; ".join(f"{r['grasp']}: {r['check_reason']}"
                                                                   for r in s["heavy_unnamed"]) if s["heavy_unnamed"] else ""))
    print(f"check exits 1 although the planner accepts (not as written, check only): {len(s['check_stricter'])}"
          + "".join(f"\n  {r['grasp']} {r['mass_kg']} kg" for r in s["check_stricter"]))
    for r in s["disagree"]:
        print(f"DISAGREE {r['grasp']} {r['mass_kg']} kg: check {r['check_accepted']}, plan {r['plan_accepted']}: "
              f"{r['check_reason'] or r['plan_reason']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": {k: v for k, v in s.items()}, "rows": rows}, indent=1))
    return 1 if s["disagree"] else 0


if __name__ == "__main__":
    sys.exit(main_())
