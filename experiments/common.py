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
import contextlib
import csv
import functools
import importlib
import math
import multiprocessing
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
#: Where --quick runs write by default (ignored by git): never over the committed results.
QUICK_RESULTS = RESULTS / "quick"
GRASPS = REPO / "grasps"
#: Replays run palm up (gravity along the palm's -z), the orientation the library's
#: parallel-extension grasps are made for, with plans made under the "mean" contact
#: model (one contact per finger, what the simulator's rigid fingertips give).
REPLAY_GRAVITY = (0.0, 0.0, -9.81)
REPLAY_CONTACT_MODEL = "mean"
#: The replay's squeeze force per finger (its default), also the gravity-aware plans' budget.
REPLAY_FINGER_FORCE_N = 1.0


# ------------------------------------------------------------------ command line


class _ExperimentParser(argparse.ArgumentParser):
    """The experiments' options; ``--out`` defaults to experiments/results for a full run and
    to experiments/results/quick for ``--quick``, so a quick run never writes over the
    committed full-run results."""

    def parse_known_args(self, args=None, namespace=None):
        ns, rest = super().parse_known_args(args, namespace)
        if getattr(ns, "out", False) is None:
            ns.out = QUICK_RESULTS if getattr(ns, "quick", False) else RESULTS
            ns.out.mkdir(parents=True, exist_ok=True)
        return ns, rest


def parser(description: str) -> argparse.ArgumentParser:
    ap = _ExperimentParser(description=description)
    ap.add_argument("--quick", action="store_true", help="small sweep (seconds to a minute)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="local worker processes (default: all cores; 1 = in this process)")
    ap.add_argument("--dask-scheduler", metavar="ADDRESS", default=None,
                    help="run the sweep on an existing Dask cluster (e.g. tcp://host:8786)")
    ap.add_argument("--seed", type=int, default=0, help="base seed of the sweep")
    ap.add_argument("--out", type=Path, default=None,
                    help="directory for CSV and PNG results (default experiments/results, with --quick "
                         "experiments/results/quick: never over the full runs' results)")
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


#: Thread-count variables of the BLAS libraries numpy and scipy may load.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_blas():
    """One BLAS thread per worker process (unless the user set the variables).

    With one worker per core, each worker's OpenBLAS would otherwise start a thread per
    core and they oversubscribe the cores: measured on 2 cores, graphs with 64-point
    patches (exp6) built 4-14x slower in 2 workers than alone. The variables only act on
    a BLAS loaded after they are set, hence fresh ("spawn") worker processes.
    """
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARS}
    for k, v in saved.items():
        if v is None:
            os.environ[k] = "1"
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)


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
            with _single_threaded_blas(), ProcessPoolExecutor(
                    max_workers=min(args.workers, len(tasks)), mp_context=multiprocessing.get_context("spawn")) as pool:
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
    from planner.realization import realize

    return realize(load_spec(path))


def _onto_scaled_surface(shape, old_size, new_size, p):
    """Move an object-frame contact point of the old object onto the new object's surface,
    keeping its tangential coordinates (so it stays where the finger is): box, the
    coordinate of its face set to the new face, the others clipped inside the new face;
    cylinder, side points keep height and direction (radius changed), cap points keep
    direction and radius (clipped)."""
    p = np.asarray(p, float).copy()
    margin = 1e-3
    if shape == "box":
        h_old, h_new = np.asarray(old_size) / 2.0, np.asarray(new_size) / 2.0
        face = int(np.argmax(np.abs(p) / h_old))
        for j in range(3):
            p[j] = np.sign(p[j]) * h_new[j] if j == face else np.clip(p[j], -(h_new[j] - margin), h_new[j] - margin)
        return p
    if shape == "cylinder":
        (r0, l0), (r1, l1) = old_size, new_size
        rho = np.hypot(p[0], p[1])
        if rho / r0 >= abs(p[2]) / (l0 / 2):  # side
            p[:2] *= r1 / max(rho, 1e-12)
            p[2] = np.clip(p[2], -(l1 / 2 - margin), l1 / 2 - margin)
        else:  # cap
            p[2] = np.sign(p[2]) * l1 / 2
            if rho > r1 - margin:
                p[:2] *= (r1 - margin) / rho
        return p
    if shape == "sphere":
        return p * (new_size[0] / np.linalg.norm(p))
    raise ValueError(f"scaling a {shape} is not supported")


def scaled_spec(spec, factors: Sequence[float]):
    """The grasp on an object whose size is scaled by ``factors`` (box: per axis x, y, z;
    cylinder: (radius, length); sphere: (radius,)).

    The object's pad-side extreme (palm -z: where it rests on the finger pads) stays where
    it was; contact points keep their tangential position and move onto the new surface
    (`_onto_scaled_surface`); posture fingers keep their postures and are re-closed onto
    the new surface by `planner.realization.realize`.
    """
    obj = spec.object
    size = tuple(float(s) * float(f) for s, f in zip(obj.size, factors))
    T = obj.T_palm_obj
    R = T[:3, :3]
    # lowest point along palm z of the object, before and after (support function)
    def low(sz):
        if obj.shape == "box":
            return float(np.abs(R[2, :]) @ (np.asarray(sz) / 2.0))
        if obj.shape == "cylinder":
            r, L = sz
            axis_z = R[2, 2]
            return float(abs(axis_z) * L / 2 + r * np.sqrt(max(0.0, 1 - axis_z ** 2)))
        return float(sz[0])
    shift = np.array([0.0, 0.0, low(size) - low(obj.size)])
    new_obj = obj.replaced(size=size, position=tuple(np.asarray(obj.position, float) + shift))
    fingers = []
    for f in spec.fingers:
        if f.kind == "contact" and f.point_obj is not None:
            p_new = _onto_scaled_surface(obj.shape, obj.size, size, f.point_obj)
            # the object moved by `shift` (palm frame): keep the point's palm x, y where possible
            fingers.append(replace(f, point_obj=tuple(float(v) for v in p_new)))
        else:
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


def read_rows(path: Path) -> list[dict]:
    """Rows of a CSV written by `write_csv`, with their types back (booleans, numbers; an
    empty cell is NaN in a time, drift or metric column, else empty)."""

    def conv(k, v):
        if v in ("True", "False"):
            return v == "True"
        if v == "":
            return np.nan if k.endswith(("_s", "_mm", "_deg", "_metric")) or k == "bottleneck" else v
        try:
            return float(v) if any(c in v for c in ".en") else int(v)
        except ValueError:
            return v

    with open(path, newline="") as fh:
        return [{k: conv(k, v) for k, v in r.items()} for r in csv.DictReader(fh)]


def replot(csv_path: Path, png_path: Path, title: str, plot, summarize) -> dict:
    """``--from-csv``: no run, the plot and summary of an existing CSV."""
    rows = read_rows(csv_path)
    plot(rows, png_path)
    summary = summarize(rows)
    print_summary(f"{title} ({csv_path.name})", summary)
    return summary


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
