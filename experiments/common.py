"""Shared plumbing of the experiments: command line, parallel map, grasps, CSV, plots.

Every experiment is a script ``experiments/expN_*.py`` with ``main(argv=None) -> dict``
(the printed summary). Sweeps are lists of plain-data tasks mapped by `run_tasks` over
local processes (``--workers``, default: all cores) or an existing Dask cluster
(``--dask-scheduler tcp://host:8786``; the workers need this repository on their
PYTHONPATH and the project installed). Every task carries its own seed, so results do not
depend on the number of workers or the order in which tasks finish.
"""

from __future__ import annotations

import argparse
import csv
import functools
import importlib
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # `python experiments/expN.py` puts only experiments/ on sys.path
    sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

RESULTS = REPO / "experiments" / "results"
GRASPS = REPO / "grasps"


# ------------------------------------------------------------------ command line


def parser(description: str) -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--quick", action="store_true", help="small sweep (seconds to a minute)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="local worker processes (default: all cores; 1 = in this process)")
    ap.add_argument("--dask-scheduler", metavar="ADDRESS", default=None,
                    help="run the sweep on an existing Dask cluster (e.g. tcp://host:8786)")
    ap.add_argument("--seed", type=int, default=0, help="base seed of the sweep")
    ap.add_argument("--out", type=Path, default=RESULTS, help="directory for CSV and PNG results")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


# ------------------------------------------------------------------ parallel map


def _importable(fn: Callable) -> Callable:
    """A task function defined in a script run as __main__, re-imported under its
    module name, so that it pickles by a name other processes (and Dask workers) know."""
    if getattr(fn, "__module__", None) != "__main__":
        return fn
    main = sys.modules["__main__"]
    stem = Path(getattr(main, "__file__", "")).stem
    if not stem:
        return fn
    module = importlib.import_module(f"experiments.{stem}")
    return getattr(module, fn.__name__)


def _bar(total: int, desc: str, disable: bool):
    try:
        from tqdm import tqdm
    except ImportError:  # progress bars are optional: pip install tqdm
        class _NoBar:
            def update(self, n=1):
                pass

            def close(self):
                pass

        return _NoBar()
    return tqdm(total=total, desc=desc, disable=disable, leave=False, dynamic_ncols=True, file=sys.stderr)


def run_tasks(fn: Callable[[Any], Any], tasks: Sequence[Any], args, desc: str = "") -> list:
    """Map ``fn`` over ``tasks`` (results in task order) with a progress bar.

    Local processes by default (``args.workers``; 1 runs in this process), or the Dask
    cluster at ``args.dask_scheduler``.
    """
    tasks = list(tasks)
    fn = _importable(fn)
    disable = getattr(args, "no_progress", False)
    out: list = [None] * len(tasks)
    bar = _bar(len(tasks), desc, disable)
    try:
        if getattr(args, "dask_scheduler", None):
            try:
                from dask.distributed import Client, as_completed as dask_completed
            except ImportError:
                raise SystemExit("--dask-scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
            client = Client(args.dask_scheduler)
            try:
                futures = client.map(fn, tasks, pure=False)
                index = {f.key: i for i, f in enumerate(futures)}
                for fut in dask_completed(futures):
                    out[index[fut.key]] = fut.result()
                    bar.update()
            finally:
                client.close()
        elif args.workers <= 1 or len(tasks) <= 1:
            for i, t in enumerate(tasks):
                out[i] = fn(t)
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=min(args.workers, len(tasks))) as pool:
                futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
                for fut in as_completed(futures):
                    out[futures[fut]] = fut.result()
                    bar.update()
    finally:
        bar.close()
    return out


# ------------------------------------------------------------------ grasps


def grasp_pairs(hand_dirs: Iterable[str] = ("icub", "allegro")) -> list[tuple[str, str, str]]:
    """(name, initial path, final path) of every ``<obj>_parallel_extension`` ->
    ``<obj>_ir2m`` pair in the library (the thesis's pair), relative to the repository."""
    out = []
    for d in hand_dirs:
        for pe in sorted((GRASPS / d).glob("*_parallel_extension.yaml")):
            obj = pe.name[: -len("_parallel_extension.yaml")]
            ir = pe.with_name(f"{obj}_ir2m.yaml")
            if ir.exists():
                out.append((f"{d}/{obj}", str(pe.relative_to(REPO)), str(ir.relative_to(REPO))))
    return out


def library_grasps() -> list[str]:
    """Every grasp file of the library, relative to the repository."""
    return sorted(str(p.relative_to(REPO)) for p in GRASPS.glob("**/*.yaml"))


@functools.lru_cache(maxsize=None)
def load_spec(path: str):
    from planner.grasp import load_grasp

    return load_grasp(REPO / path)


@functools.lru_cache(maxsize=None)
def realized(path: str):
    """The realized grasp of a library file (cached per process)."""
    from planner.grasp import realize

    return realize(load_spec(path))


def scaled_spec(spec, factors: Sequence[float], keep_bottom: bool = True):
    """The grasp on an object with its size scaled by ``factors`` (box: per axis x, y, z;
    cylinder: (radius, length)); contact points scaled onto the new surface the same way;
    postures unchanged (re-closed onto the new surface by `realize`). With ``keep_bottom``
    the object's -z face (box) or the cylinder's lowest side line stays where it was, so
    an object resting on the finger pads still rests on them."""
    obj = spec.object
    size = tuple(float(s) * float(f) for s, f in zip(obj.size, factors))
    if obj.shape == "box":
        point_scale = np.array(factors, float)
        dz = (size[2] - obj.size[2]) / 2.0
    elif obj.shape == "cylinder":
        fr, fl = factors
        point_scale = np.array([fr, fr, fl])
        dz = size[0] - obj.size[0]
    elif obj.shape == "sphere":
        point_scale = np.full(3, factors[0])
        dz = size[0] - obj.size[0]
    else:
        raise ValueError(f"scaling a {obj.shape} is not supported")
    R = spec.object.T_palm_obj[:3, :3]
    # keep the lowest point of the object (palm -z... the pad side) in place: shift the centre
    # along the palm direction of the object's own z axis only for boxes; cylinders lie on the
    # pads with their side, whose lowest line moves by the radius change along palm z
    if obj.shape == "box":
        shift = R @ np.array([0.0, 0.0, dz]) if keep_bottom else np.zeros(3)
    else:
        shift = np.array([0.0, 0.0, dz]) if keep_bottom else np.zeros(3)
    new_obj = replace(obj, size=size, position=tuple(np.asarray(obj.position, float) + shift))
    fingers = []
    for f in spec.fingers:
        if f.kind == "contact" and f.point_obj is not None:
            f = replace(f, point_obj=tuple(np.asarray(f.point_obj, float) * point_scale))
        fingers.append(f)
    return replace(spec, object=new_obj, fingers=tuple(fingers), name=f"{spec.name}_x{'_'.join(f'{x:.2f}' for x in factors)}")


# ------------------------------------------------------------------ output


def write_csv(path: Path, rows: Sequence[dict]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    keys: list[str] = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(r.get(k)) for k in keys})
    return path


def _fmt(v):
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    if isinstance(v, (np.floating,)):
        return _fmt(float(v))
    if isinstance(v, (list, tuple)):
        return " ".join(str(x) for x in v)
    return v


def pyplot():
    """matplotlib.pyplot with the headless Agg backend (pip install matplotlib)."""
    try:
        import matplotlib
    except ImportError:
        raise SystemExit("plots need matplotlib: pip install -e '.[experiments]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.s = time.perf_counter() - self.t0


def print_summary(name: str, summary: dict) -> None:
    print(f"== {name}")
    for k, v in summary.items():
        if isinstance(v, float):
            v = f"{v:.4g}"
        print(f"  {k}: {v}")
