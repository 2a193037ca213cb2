"""Shared fixtures, and the test tiers.

Layout: ``tests/unit/offboard``, ``tests/unit/sitl_plant`` (pure, in one process: the fast tier,
``make test-fast``), ``tests/e2e`` (real processes talking over loopback UDP, real PX4 where the
test is about PX4: marked ``e2e`` here, whatever the file says). Helpers are ``tests/helpers``
(on the path through ``pythonpath`` in pyproject.toml), never a test module.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from bench.px4sitl import SKIP_REASON, px4_launcher
from bench.parity import ENV as PARITY_ENV
from bench.parity import Recorder
from helpers import FakeClock

E2E_DIR = Path(__file__).resolve().parent / "e2e"


#: e2e modules whose tests fly on the wall clock (a real-time plant, PX4 at --speed, timeouts and
#: rates measured in wall time), marked ``realtime`` (``-m "not realtime"`` leaves them out).
REALTIME_MODULES = frozenset({
    "test_bench_loop", "test_bench_smoke", "test_demo", "test_fly_e2e", "test_fly_failures", "test_fly_latency",
    "test_fly_vehicle_clock", "test_fuzz",
    "test_killed", "test_lost_track", "test_plant_cli_faults", "test_plant_e2e", "test_plant_mavproxy", "test_plant_mission_e2e",
    "test_plant_services_e2e",
})  # fmt: skip

#: Long modules taken after the other long ones: the quick bench runs every many-vehicle kernel,
#: which make test compiles in the background meanwhile (Makefile), not in the test's own time.
LATE_LONG_MODULES = frozenset({"test_bench_smoke"})

#: The one xdist scope of every PX4 module under ``--dist loadfile`` (``pytest_xdist_make_scheduler``),
#: and of the ``WALL_CLOCK_MODULES``.
PX4_SCOPE = "px4-sitl"

#: Modules whose figures are measured against a plant running free on the wall clock, faster than
#: real time or behind a delayed link, flown on the PX4 worker after the PX4 modules and at its
#: priority: on a niced worker of a loaded make test a starved plant at --speed 4 fell behind
#: and caught up in a burst (0.7 s of its time in 50 ms) that the helix's 0.05 m could not
#: survive. The PX4 worker finished 90-130 s before the others, so they also even the load.
WALL_CLOCK_MODULES = frozenset({"test_fly_vehicle_clock", "test_fly_latency"})


def is_px4_module(path: str | Path) -> bool:
    """Whether a test module flies a real PX4 SITL (tests/e2e/test_px4_*.py, each starting its own)."""
    return Path(path).name.startswith("test_px4_")


def on_px4_worker(path: str | Path) -> bool:
    """Whether a test module runs on make test's PX4 worker: a PX4 module or a ``WALL_CLOCK_MODULES`` one."""
    return is_px4_module(path) or Path(path).stem in WALL_CLOCK_MODULES


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        path = Path(str(item.fspath)).resolve()
        if E2E_DIR in path.parents:
            item.add_marker(pytest.mark.e2e)
        if path.stem in REALTIME_MODULES or item.get_closest_marker("px4") is not None or is_px4_module(path):
            item.add_marker(pytest.mark.realtime)
    items[:] = long_modules_first(items)


def long_modules_first(items: list[pytest.Item]) -> list[pytest.Item]:
    """The items, a module's together, in the order ``make test``'s workers should take them
    (``--dist loadfile --no-loadscope-reorder`` hands the scopes out in collection order; without
    the flag xdist >= 3.8 sorts them by their number of tests): the PX4 modules first (one scope,
    ``pytest_xdist_make_scheduler``: a few minutes), then the ``WALL_CLOCK_MODULES`` (the same
    scope), then the other long ones, then the short ones,
    so that the short ones fill the gaps at the end instead of one worker finishing a long module
    alone while the other idles. Long: an e2e module (processes) or one marked ``slow``; the
    ``LATE_LONG_MODULES`` after the other long ones. Within each kind, the collection order."""
    modules: dict[str, list[pytest.Item]] = {}
    for item in items:
        modules.setdefault(str(item.fspath), []).append(item)

    def kind(group: list[pytest.Item]) -> int:
        path = Path(str(group[0].fspath))
        if is_px4_module(path):
            return 0
        if on_px4_worker(path):  # after the PX4 modules, in the same scope
            return 1
        if any(i.get_closest_marker(mark) for i in group for mark in ("slow", "realtime", "e2e")):
            return 3 if path.stem in LATE_LONG_MODULES else 2
        return 4

    return [item for group in sorted(modules.values(), key=kind) for item in group]


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):  # noqa: ANN001, ANN201 - xdist's hook
    """``--dist loadfile`` (``make test``) with every PX4 module in one scope: one worker flies
    them one after the other, so that a PX4 flight shares the cores with the other workers' tests
    but never with a second PX4 SITL (their timings are compared with the plant's; two at once made
    them flaky); the ``WALL_CLOCK_MODULES`` join that scope, after them. Every other module is a
    scope of its own, as xdist's loadfile has it.

    With at least ``PX4_WORKER_RETIRES_WITH`` other workers the PX4 one takes nothing else and
    stops when its flights are done: a PX4 flight waits on the wall clock much of the time (the
    PX4 modules took 160-180 s of CPU in 360 s, their PX4 SITLs and plants included), so ``make
    test`` runs them beside two workers for the rest, which then have the cores to themselves;
    with fewer other workers it goes on with their files."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class Px4ModulesTogether(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = super()._split_scope(nodeid)
            return PX4_SCOPE if on_px4_worker(module) else module

        def _reschedule(self, node) -> None:  # noqa: ANN001 - xdist's WorkerController
            others = [n for n in self.nodes if n is not node and not n.shutting_down]
            if PX4_SCOPE in self.assigned_work.get(node, {}) and len(others) >= PX4_WORKER_RETIRES_WITH:
                if not node.shutting_down:
                    node.shutdown()  # runs what it was given (the PX4 modules), then stops
                return
            super()._reschedule(node)

    return Px4ModulesTogether(config, log)


#: How many other workers there must be for the PX4 worker to take nothing but the PX4 modules.
PX4_WORKER_RETIRES_WITH = 2


#: How much a worker lowers its priority once it runs anything but the PX4 modules (``yield_to_px4``).
OTHERS_NICENESS = 5
_yielded: list[bool] = []


def yield_to_px4(item: pytest.Item) -> None:
    """Under xdist, a worker lowers its priority (and its children's) before its first test that is
    not on the PX4 worker (``on_px4_worker``), for good: a PX4 SITL runs free on the wall clock (not in lockstep with the
    test) and misses its own deadlines when the other workers' processes take its core (in loaded
    runs of ``make test`` PX4 slowed at a corner it flies through, or never entered Mission mode),
    while the other tests use what it leaves. The PX4 modules come first in their worker's queue
    (``long_modules_first``), so that worker keeps its priority through all of them."""
    if os.environ.get("PYTEST_XDIST_WORKER") and not on_px4_worker(str(item.fspath)) and not _yielded:
        os.nice(OTHERS_NICENESS)
        _yielded.append(True)


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A ``px4`` test without a PX4 SITL is skipped from here, so that ``-ra`` folds every such skip
    into one line saying how to point the tests at a PX4 (a ``skipif`` mark in each module gave a
    line per test). Every other worker yields the cores to the PX4 one (``yield_to_px4``)."""
    yield_to_px4(item)
    if item.get_closest_marker("px4") is not None and px4_launcher() is None:
        pytest.skip(SKIP_REASON)


_OUTCOME = pytest.StashKey[str]()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Iterator[None]:
    report = (yield).get_result()
    if report.when == "call" or (report.when == "setup" and not report.passed):
        item.stash[_OUTCOME] = report.outcome


@pytest.fixture
def parity_finding(request: pytest.FixtureRequest) -> Iterator[Recorder]:
    """``parity_finding(key, behaviour, px4=..., plant=...)``: one behaviour a px4 parity test
    compared, for docs/parity/measured.md (``make parity``; bench/parity.py). Only a list append
    during the test; with ``PARITY_FINDINGS=DIR`` set the test's findings go to a file in DIR as it
    ends, with its outcome and the module's PX4 speed (its ``PX4_SPEED``, else ``SPEED``)."""
    recorder = Recorder(request.node.name)
    yield recorder
    folder = os.environ.get(PARITY_ENV)
    if folder and recorder.findings:
        recorder.write(Path(folder), request.node.nodeid, outcome=request.node.stash.get(_OUTCOME, "unknown"),
                       line=request.node.location[1] or 0, px4_speed=getattr(request.module, "PX4_SPEED", getattr(request.module, "SPEED", None)))  # fmt: skip


@pytest.fixture
def fake_clock() -> FakeClock:
    """A clock the test advances by setting ``fake_clock.now``."""
    return FakeClock()


@pytest.fixture
def free_ports() -> Callable[[int], list[int]]:
    """``free_ports(n)``: n distinct UDP ports on 127.0.0.1 the OS just handed out (never PX4's)."""
    from offboard.demo import free_udp_ports

    return free_udp_ports
