"""`offboard sweep` on a real Dask cluster: a scheduler and two worker processes over TCP on loopback.

The same flights come back whatever flies them: the cluster in tasks of two flights, the cluster
in tasks of one, and this process alone; rows land in Parquet, one per flight.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from helpers.sweeps import MIXED, write_sweep

pytestmark = [pytest.mark.slow]

DASK = Path(sys.executable).with_name("dask")
FLIGHTS = 6


def _free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """``dask scheduler`` and ``dask worker --nworkers 2`` as processes; the scheduler's address."""
    port = _free_tcp_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path_factory.mktemp("dask")
    env = dict(os.environ)
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=(logs / "scheduler.log").open("w"), env=env)]  # fmt: skip
    try:
        from distributed import Client

        for _ in range(2):  # two worker processes (no nanny: half the processes to start)
            procs.append(subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                           "--no-dashboard", "--no-nanny"],
                                          stdout=subprocess.DEVNULL, stderr=(logs / "worker.log").open("a"), env=env))  # fmt: skip
        with Client(address, timeout=20) as client:
            client.wait_for_workers(2, timeout=30)
        yield address
    finally:
        try:  # the scheduler stops itself and its workers
            from distributed import Client

            with Client(address, timeout=5) as client:
                client.shutdown()
        except (OSError, RuntimeError):
            pass
        for p in reversed(procs):
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def _table(path: Path) -> list[dict]:
    """The rows by flight, NaN as None (so that equal rows compare equal)."""
    import pyarrow.parquet as pq

    from offboard.jsonout import strict

    return strict(sorted(pq.read_table(path).to_pylist(), key=lambda r: r["flight"]))  # type: ignore[return-value]


def test_sweep_on_a_two_worker_cluster_gives_the_flights_of_any_chunking(tmp_path, scheduler, capsys):
    from offboard.jsonout import strict
    from offboard.sweep.runner import fly_chunk, run_sweep
    from offboard.sweep.spec import load_sweep

    from offboard.cli import main

    spec_path = write_sweep(tmp_path, MIXED, flights=FLIGHTS, duration_s=0.3)
    code = main(["sweep", str(spec_path), "--scheduler", scheduler, "--flights-per-task", "2", "--json",
                 "--run-dir", str(tmp_path / "run")])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, err
    summary = json.loads(out)
    assert summary["workers"] == 2 and summary["scheduler"] == scheduler
    assert summary["tasks"] == FLIGHTS // 2 and summary["flights"] == FLIGHTS
    assert 0.0 <= summary["success_rate"] <= 1.0 and sum(summary["statuses"].values()) == FLIGHTS
    assert {s["parameter"] for s in summary["sensitivity"]} >= {"controller.mass_kg", "vehicle.motor_time_constant_s"}
    assert f"sweep mini: {FLIGHTS}/{FLIGHTS} flights" in err  # the progress line
    for name in ("flights.parquet", "report.md", "summary.json", "rms-histogram.png", "rms-vs-parameters.png", "failure-map.png"):
        assert (tmp_path / "run" / name).stat().st_size > 0, name
    rows = _table(tmp_path / "run" / "flights.parquet")
    assert [r["flight"] for r in rows] == list(range(FLIGHTS))
    assert all(r["status"] in ("complete", "diverged", "crashed") for r in rows)
    assert all(r["rms_whole_m"] > 0 and r["peak_thrust_n"] > 0 for r in rows)

    # the same flights in tasks of one on the same cluster, and flown here without Dask
    spec = load_sweep(spec_path)
    (tmp_path / "again").mkdir()
    again = run_sweep(spec, tmp_path / "again", scheduler=scheduler, flights_per_task=1)
    assert again.tasks == FLIGHTS and again.workers == 2
    assert _table(again.parquet) == rows
    here = sorted(fly_chunk(spec, 0, FLIGHTS), key=lambda r: r["flight"])
    assert strict([{k: r[k] for k in rows[0]} for r in here]) == rows


def test_sweep_on_the_default_local_cluster(tmp_path):
    from offboard.sweep.runner import run_sweep
    from offboard.sweep.spec import load_sweep

    spec = load_sweep(write_sweep(tmp_path, "[parameters.controller]\nmass_kg = { grid = [0.45, 0.55] }\n", flights=2,
                                  duration_s=0.3))  # fmt: skip
    seen = []
    run = run_sweep(spec, tmp_path, workers=1, flights_per_task=1, progress=lambda *a: seen.append(a[:2]))
    assert (run.scheduler, run.workers, run.tasks, run.flights) == ("local", 1, 2, 2)
    assert seen == [(1, 2), (2, 2)]
    assert [r["controller.mass_kg"] for r in _table(run.parquet)] == [0.45, 0.55]


@pytest.mark.parametrize("args, expected", [
    (["nope.toml"], "offboard sweep: error: nope.toml: no such file"),
    (["--scheduler", "localhost:8786", "SPEC"], "--scheduler: expected tcp://HOST:PORT"),
    (["--workers", "0", "SPEC"], "--workers must be >= 1"),
    (["--scheduler", "tcp://127.0.0.1:1", "--workers", "2", "SPEC"], "--workers sizes the local cluster"),
    ([], "a sweep file is needed"),
])  # fmt: skip
def test_bad_input_is_one_line(tmp_path, capsys, args, expected):
    from offboard.cli import main

    spec_path = write_sweep(tmp_path, "")
    assert main(["sweep", *(str(spec_path) if a == "SPEC" else a for a in args)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err, err


def test_list_parameters(capsys):
    from offboard.cli import main
    from offboard.sweep.spec import PARAMETERS

    assert main(["sweep", "--list-parameters"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out] == list(PARAMETERS)
