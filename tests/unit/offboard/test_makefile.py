"""`make demo` installs what the demo needs, `make test` what the tests need, each once
(`make -n`: what make would run, with a virtual environment of our own; nothing is installed)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import REPO

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="no make on this machine")


def dry_run(target: str, venv: Path) -> list[str]:
    # run from `make test` itself: the outer make's flags would add "make[1]: Entering directory" lines
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MAKELEVEL", "MFLAGS", "MAKEOVERRIDES")}
    proc = subprocess.run(["make", "--no-print-directory", "-n", target, f"VENV={venv}"], cwd=REPO, capture_output=True,
                          text=True, timeout=60, env=env)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.splitlines()


def installs(lines: list[str]) -> list[str]:
    """What each install line installs (uv's or, where uv is missing, pip's: the same in both)."""
    found = []
    for line in lines:
        if "pip install" in line and " -e " in line:
            targets = {part.split(";", 1)[0].strip() for part in line.split(" -e ")[1:]}
            assert len(targets) == 1, line  # uv and the fallback install the same thing
            found.append(targets.pop())
    return found


def stamp(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.touch()
    later = time.time() + 5  # newer than pyproject.toml, whatever the file system's resolution
    os.utime(path, (later, later))


def test_a_fresh_demo_installs_the_project_without_the_test_extra(tmp_path):
    lines = dry_run("demo", tmp_path / "venv")
    assert installs(lines) == ["."]
    assert any("-m venv" in line for line in lines) and any("offboard.demo" in line for line in lines)


def test_a_fresh_test_installs_the_test_extra_too(tmp_path):
    lines = dry_run("test", tmp_path / "venv")
    assert installs(lines) == [".", "'.[test]'"]
    # three workers, a file (or all the PX4 files, on a worker that takes nothing else:
    # tests/conftest.py) at a time each, in tests/conftest.py's order (xdist's own would put the
    # files with the most tests first)
    assert lines[-1].endswith("-m pytest -q -n 3 --dist loadfile --no-loadscope-reorder")


def test_demo_then_test_installs_only_the_test_extra(tmp_path):
    venv = tmp_path / "venv"
    stamp(venv / ".installed")  # what `make demo` leaves
    assert installs(dry_run("demo", venv)) == []
    assert installs(dry_run("test", venv)) == ["'.[test]'"]
    stamp(venv / ".installed-test")  # and then `make test`
    assert installs(dry_run("test", venv)) == [] and installs(dry_run("demo", venv)) == []


def test_a_changed_pyproject_installs_again(tmp_path):
    venv = tmp_path / "venv"
    for name in (".installed", ".installed-test"):
        stamp(venv / name)
        earlier = (REPO / "pyproject.toml").stat().st_mtime - 60
        os.utime(venv / name, (earlier, earlier))  # older than pyproject.toml: it changed since
    assert installs(dry_run("test", venv)) == [".", "'.[test]'"]


def test_the_installs_say_what_they_do(tmp_path):
    text = "\n".join(dry_run("test", tmp_path / "venv"))
    assert "installing rosales-offboard and what it needs to fly" in text and "installing the test tools" in text
    assert " -e ." in text and "--quiet -e" not in text  # pip's own lines show the progress


def test_the_license_is_an_spdx_expression():
    """A table (`{ text = "MIT" }`) made setuptools warn three times per install."""
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert project["project"]["license"] == "MIT"
    assert any(r.replace(" ", "").startswith("setuptools>=77") for r in project["build-system"]["requires"])


def test_make_test_flies_every_px4_module_on_one_worker_and_the_others_a_file_each(pytestconfig, monkeypatch):
    """tests/conftest.py's scheduler for ``--dist loadfile``: never two PX4 SITLs at once."""
    import conftest

    monkeypatch.setattr(pytestconfig.option, "dist", "loadfile")
    monkeypatch.setattr(pytestconfig.option, "tx", ["popen", "popen"], raising=False)  # -n 2
    scheduler = conftest.pytest_xdist_make_scheduler(pytestconfig, None)
    px4 = ["tests/e2e/test_px4_flight.py::test_a", "tests/e2e/test_px4_parity_wire.py::test_b[api]"]
    assert {scheduler._split_scope(nodeid) for nodeid in px4} == {conftest.PX4_SCOPE}
    # and the modules flown against a plant on the wall clock, at that worker's priority
    assert scheduler._split_scope("tests/e2e/test_fly_vehicle_clock.py::test_e") == conftest.PX4_SCOPE
    assert scheduler._split_scope("tests/e2e/test_fly_e2e.py::test_c") == "tests/e2e/test_fly_e2e.py"
    assert (
        scheduler._split_scope("tests/unit/offboard/test_bench_px4sitl.py::test_d") == "tests/unit/offboard/test_bench_px4sitl.py"
    )
    monkeypatch.setattr(pytestconfig.option, "dist", "load")
    assert conftest.pytest_xdist_make_scheduler(pytestconfig, None) is None  # xdist's own


PX4_LIKE_MODULE = """
import os, time
def test_{name}_{i}():
    time.sleep({sleep})
    with open(os.environ["WHO_RAN"], "a") as f:
        f.write("{name} " + os.environ["PYTEST_XDIST_WORKER"] + "\\n")
"""


def _who_ran_what(tmp_path: Path, workers: int) -> dict[str, set[str]]:
    """A real ``pytest -n workers --dist loadfile`` with tests/conftest.py's scheduler and order on
    a tree of two PX4-named modules (short tests) and six others (longer): module -> its workers."""
    tree = tmp_path / "tree"
    tree.mkdir()
    (tree / "conftest.py").write_text(
        "import importlib.util\n"
        f"spec = importlib.util.spec_from_file_location('project_conftest', {str(REPO / 'tests' / 'conftest.py')!r})\n"
        "project = importlib.util.module_from_spec(spec); spec.loader.exec_module(project)\n"
        "pytest_collection_modifyitems = project.pytest_collection_modifyitems\n"
        "pytest_xdist_make_scheduler = project.pytest_xdist_make_scheduler\n"
    )  # fmt: skip
    modules = {"test_px4_a": 0.05, "test_px4_b": 0.05, **{f"test_other_{k}": 0.4 for k in range(6)}}
    for name, sleep in modules.items():
        (tree / f"{name}.py").write_text("".join(PX4_LIKE_MODULE.format(name=name, i=i, sleep=sleep) for i in range(3)))
    who = tmp_path / "who.txt"
    env = {k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"}  # the outer run's options are not this one's
    env.update(WHO_RAN=str(who), PYTHONPATH=os.pathsep.join([str(REPO), str(REPO / "tests")]))
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", str(workers), "--dist", "loadfile",
         "--no-loadscope-reorder", "--rootdir", str(tree), "-c", os.devnull, str(tree)],
        cwd=tree, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    ran: dict[str, set[str]] = {}
    for line in who.read_text().splitlines():
        name, worker = line.split()
        ran.setdefault(name, set()).add(worker)
    assert sorted(ran) == sorted(modules)  # every module ran (3 tests each, below)
    assert len(who.read_text().splitlines()) == 3 * len(modules)
    return ran


def test_the_px4_worker_takes_nothing_else_beside_two_others(tmp_path):
    ran = _who_ran_what(tmp_path, 3)
    px4_workers = ran["test_px4_a"] | ran["test_px4_b"]
    assert len(px4_workers) == 1  # every PX4 module on one worker
    others = set().union(*(w for name, w in ran.items() if not name.startswith("test_px4_")))
    assert not px4_workers & others and len(others) == 2  # which ran nothing else; the two others ran the rest


def test_with_one_other_worker_the_px4_worker_goes_on_with_the_rest(tmp_path):
    ran = _who_ran_what(tmp_path, 2)
    px4_workers = ran["test_px4_a"] | ran["test_px4_b"]
    assert len(px4_workers) == 1
    others = set().union(*(w for name, w in ran.items() if not name.startswith("test_px4_")))
    assert px4_workers <= others  # two workers: both take the other files


@pytest.mark.parametrize("worker, module, niceness", [
    ("gw1", "tests/e2e/test_fly_e2e.py", 5),  # another worker: yields to the PX4 one
    ("gw0", "tests/e2e/test_px4_flight.py", 0),  # the PX4 worker keeps its priority
    ("gw0", "tests/e2e/test_fly_vehicle_clock.py", 0),  # through the wall-clock modules it flies too
    ("", "tests/e2e/test_fly_e2e.py", 0),  # no xdist (one process): nothing to yield to
])  # fmt: skip
def test_the_workers_yield_the_cores_to_the_px4_one(worker, module, niceness):
    """tests/conftest.py's ``yield_to_px4``, in a process of its own (a niceness cannot be undone)."""
    code = (f"import os, types, conftest; base = os.nice(0); item = types.SimpleNamespace(fspath={module!r}); "
            "conftest.yield_to_px4(item); conftest.yield_to_px4(item); print(os.nice(0) - base)")  # twice: once only
    env = {**os.environ, "PYTEST_XDIST_WORKER": worker, "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests")])}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO / "tests", env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) == niceness


def test_make_test_compiles_the_plants_kernels_first_and_the_others_in_the_background(tmp_path):
    lines = dry_run("test", tmp_path / "venv")
    plant = next(i for i, line in enumerate(lines) if line.endswith("-m sitl_plant.px4_kernel"))
    tests = next(i for i, line in enumerate(lines) if "-m pytest" in line)
    assert plant < tests  # every plant a test starts finds its compiled kernels
    background = "\n".join(lines[plant + 1:])
    assert "nice -n 19 " in background and "-m sitl_plant.dynamics.batch >/dev/null &" in background


def _fake_venv(venv: Path, pytest_exit: int) -> Path:
    """A venv whose python does nothing but what make test asks of it: the many-vehicle kernels'
    warm-up sleeps (its pid written down), pytest exits with ``pytest_exit``."""
    (venv / "bin").mkdir(parents=True)
    pidfile = venv / "warm.pid"
    script = venv / "bin" / "python"
    script.write_text(
        "#!/bin/sh\n"
        'case "$*" in\n'
        f'  *sitl_plant.dynamics.batch*) echo $$ > {pidfile}; exec sleep 60 ;;\n'
        f'  *pytest*) while [ ! -s {pidfile} ]; do sleep 0.05; done; exit {pytest_exit} ;;\n'
        "  *) exit 0 ;;\n"
        "esac\n"
    )
    script.chmod(0o755)
    stamp(venv / ".installed")
    stamp(venv / ".installed-test")
    return pidfile


@pytest.mark.parametrize("pytest_exit", [0, 3])
def test_make_test_stops_the_background_compile_with_the_tests_and_keeps_their_status(tmp_path, pytest_exit):
    pidfile = _fake_venv(tmp_path / "venv", pytest_exit)
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MAKELEVEL", "MFLAGS", "MAKEOVERRIDES")}
    proc = subprocess.run(["make", "--no-print-directory", "test", f"VENV={tmp_path / 'venv'}"], cwd=REPO,
                          capture_output=True, text=True, timeout=30, env=env)  # fmt: skip
    assert (proc.returncode == 0) == (pytest_exit == 0), proc.stderr
    pid = int(pidfile.read_text())
    for _ in range(100):  # the kill is sent as the recipe's shell exits; the sleeper goes at once
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(pid, 9)
        pytest.fail("make test left its background compile running")


def test_the_quick_bench_comes_after_the_other_long_modules_and_before_the_short_ones():
    import types

    import conftest

    def item(path: str, marks: tuple[str, ...]) -> types.SimpleNamespace:
        return types.SimpleNamespace(fspath=path, get_closest_marker=lambda mark: mark if mark in marks else None)

    items = [item("tests/unit/test_a.py", ()), item("tests/e2e/test_bench_smoke.py", ("slow", "e2e")),
             item("tests/e2e/test_demo.py", ("e2e",)), item("tests/e2e/test_fly_latency.py", ("e2e",)),
             item("tests/e2e/test_px4_flight.py", ("e2e",)), item("tests/e2e/test_zzz.py", ("e2e",))]  # fmt: skip
    order = [Path(i.fspath).stem for i in conftest.long_modules_first(items)]  # type: ignore[arg-type]
    assert order == ["test_px4_flight", "test_fly_latency", "test_demo", "test_zzz", "test_bench_smoke", "test_a"]
