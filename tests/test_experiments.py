"""Smoke test of the experiments: the fastest one, in --quick mode, into a temporary directory."""

import csv

import pytest


def test_exp1_quick_writes_csv_and_png(tmp_path, capsys):
    from experiments import exp1_cone_edges

    summary = exp1_cone_edges.main(["--quick", "--workers", "1", "--no-progress", "--out", str(tmp_path)])
    rows = list(csv.DictReader(open(tmp_path / "exp1_cone_edges.csv")))
    assert [int(r["edges"]) for r in rows][:3] == [3, 4, 5]
    assert all(r["force_closure"] == "True" for r in rows)
    assert (tmp_path / "exp1_cone_edges.png").stat().st_size > 1000
    assert summary["metric_reference"] > 0
    assert "exp1 cone edges" in capsys.readouterr().out


def test_dask_option_without_dask_is_one_line_error(tmp_path):
    from experiments.common import parser, run_tasks

    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        args = parser("x").parse_args(["--dask-scheduler", "tcp://127.0.0.1:1", "--no-progress"])
        with pytest.raises(SystemExit, match="dask"):
            run_tasks(abs, [1, -2], args)
    else:
        pytest.skip("dask is installed")


def test_local_pool_keeps_task_order():
    from experiments.common import parser, run_tasks

    args = parser("x").parse_args(["--workers", "2", "--no-progress"])
    assert run_tasks(abs, [-3, 1, -2], args) == [3, 1, 2]
