"""A real PX4 SITL for the tests that are about PX4 (marker ``px4``) and the benchmarks.

The launcher is ``$PX4_SITL`` or ``../shared/px4-sitl/px4-sitl`` beside the project (a PX4 v1.16
SITL with its SIH quadrotor; its README). Tests without one are skipped with the one line
``SKIP_REASON`` saying how to point them at a PX4. ``running_px4`` starts it on free ports and
always stops it.

PX4's ``--instance`` N picks more than the ports we pass: its payload, gimbal and SIH-display links
bind UDP 14280+N, 13030+N and 19450+N (``etc/init.d-posix/px4-rc.mavlink``), and its daemon takes
the lock ``/tmp/px4_lock-N``, so a second PX4 on the same N refuses to start ("PX4 server already
running for instance N"). Two pytest-xdist workers (``make test`` runs two) or two checkouts on
one machine must therefore not pick the same N: ``choose_instance`` tries the calling worker's own
share of the instances first (``PYTEST_XDIST_WORKER``), in a random order, and only those whose
ports bind; ``running_px4`` tries another instance when PX4 still does not start on the chosen one
(the port probe and PX4's own bind are not atomic).

A copy of PX4's ``bin/`` that lost its symbolic links (each ``px4-<module>`` then a small file
holding the word ``px4``, not executable: PX4's start-up script fails with "px4-param:
Permission denied") is run from a mirror with the links restored, in a temporary folder; the
original is never written to.
"""

from __future__ import annotations

import hashlib
import os
import random
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from offboard.demo import free_udp_ports

ROOT = Path(__file__).resolve().parents[1]
SKIP_REASON = "no PX4 SITL found: set PX4_SITL=/path/to/px4-sitl (the launcher in ../shared/px4-sitl) to run it"


def px4_launcher() -> Path | None:
    """The PX4 SITL launcher to use, or None."""
    env = os.environ.get("PX4_SITL")
    candidates = [Path(env)] if env else [ROOT.parent / "shared" / "px4-sitl" / "px4-sitl"]
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    return None


def _flattened_links(bin_dir: Path) -> bool:
    probe = bin_dir / "px4-param"
    return probe.exists() and not probe.is_symlink() and not os.access(probe, os.X_OK)


def runnable_launcher(launcher: Path) -> Path:
    """``launcher``, or a mirror of its folder with ``bin/``'s links restored (module docstring)."""
    home = launcher.parent
    if not _flattened_links(home / "bin"):
        return launcher
    digest = hashlib.sha1(str(home).encode()).hexdigest()[:10]
    mirror = Path(tempfile.gettempdir()) / f"px4-sitl-mirror-{os.getuid()}-{digest}"
    if not (mirror / launcher.name).is_file():
        tmp = Path(tempfile.mkdtemp(prefix="px4-sitl-mirror-"))
        (tmp / "bin").mkdir()
        for entry in (home / "bin").iterdir():
            target: str | Path = entry
            if entry.name != "px4" and not os.access(entry, os.X_OK) and entry.stat().st_size < 64:
                target = entry.read_text().strip() or "px4"  # a flattened link: it names its target
            (tmp / "bin" / entry.name).symlink_to(target)
        for entry in home.iterdir():
            if entry.name not in ("bin", launcher.name):
                (tmp / entry.name).symlink_to(entry)
        (tmp / launcher.name).write_bytes(launcher.read_bytes())
        (tmp / launcher.name).chmod(0o755)
        try:
            tmp.rename(mirror)
        except OSError:  # another test made it first
            pass
    return mirror / launcher.name


INSTANCES = range(20, 100)  # clear of 0..19, which people use by hand (make px4_sitl, multi-vehicle scripts)
WORKER_SHARES = 4  # instances are dealt round-robin to this many xdist workers: gw0 first gets 20, 24, ...
START_ATTEMPTS = 3  # instances tried by running_px4 before it gives up


def instance_ports(instance: int) -> tuple[int, int, int]:
    """The UDP ports PX4 SITL ``--instance`` binds on its own: payload, gimbal, SIH display links."""
    return 14280 + instance, 13030 + instance, 19450 + instance


def udp_port_free(port: int) -> bool:
    """Whether UDP ``port`` on 127.0.0.1 can be bound now (PX4 binds all addresses: that conflicts)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def instance_free(instance: int) -> bool:
    """Whether every port PX4 ``--instance`` binds is free now."""
    return all(udp_port_free(port) for port in instance_ports(instance))


def worker_index(worker: str | None) -> int:
    """The pytest-xdist worker's number (``gw3`` -> 3), 0 outside xdist."""
    digits = (worker or "").removeprefix("gw")
    return int(digits) if digits.isdigit() else 0


def choose_instance(
    *,
    worker: str | None = None,
    avoid: Iterable[int] = (),
    is_free: Callable[[int], bool] = instance_free,
    rng: random.Random | None = None,
) -> int:
    """A PX4 SITL instance number whose ports are free, this worker's own first.

    Parameters
    ----------
    worker : str or None
        ``PYTEST_XDIST_WORKER`` (``gw0``, ``gw1``, ...); None reads it from the environment.
        Worker k's own instances are those with ``n % WORKER_SHARES == k % WORKER_SHARES``, so two
        workers of one run never race for the same one; the others follow, for when it is full.
    avoid : iterable of int
        Instances not to give (those PX4 has already failed to start on).
    is_free : callable
        The probe, ``instance_free`` by default (binding its UDP ports on 127.0.0.1).
    rng : random.Random or None
        Orders the candidates within each group, so that two checkouts' workers of the same
        number do not walk the instances in step.

    Raises
    ------
    RuntimeError
        No instance in ``INSTANCES`` is free.
    """
    rng = rng or random.Random()
    share = worker_index(os.environ.get("PYTEST_XDIST_WORKER") if worker is None else worker) % WORKER_SHARES
    skip = set(avoid)
    own = [n for n in INSTANCES if n % WORKER_SHARES == share and n not in skip]
    others = [n for n in INSTANCES if n % WORKER_SHARES != share and n not in skip]
    rng.shuffle(own)
    rng.shuffle(others)
    for instance in own + others:
        if is_free(instance):
            return instance
    raise RuntimeError(f"no free PX4 SITL instance in {INSTANCES.start}..{INSTANCES.stop - 1}")


@dataclass(frozen=True)
class Px4:
    pid: int
    log: Path
    api_listen_port: int  # where PX4 sends its API link: offboard fly --connect udpin:127.0.0.1:PORT
    gcs_listen_port: int = 0  # where PX4 sends its ground-station link
    instance: int = 0
    bin_dir: Path | None = None  # PX4's bin/ (its px4-<module> commands)

    def shell(self, module: str, *args: str, timeout_s: float = 10.0) -> str:
        """Run one of PX4's own commands on this instance (``px4-<module> --instance N args``, as
        PX4's shell would: ``sensor_gps_sim stop``, ``listener vehicle_status``); returns what it
        printed. A command that fails raises ``AssertionError`` with its output."""
        assert self.bin_dir is not None, "this PX4 was not started by running_px4"
        done = subprocess.run([str(self.bin_dir / f"px4-{module}"), "--instance", str(self.instance), *args],
                              capture_output=True, text=True, timeout=timeout_s)  # fmt: skip
        assert done.returncode == 0, f"px4-{module} {' '.join(args)}: exit {done.returncode}\n{done.stdout}{done.stderr}"
        return done.stdout


@contextmanager
def running_px4(workdir: Path, *, speed: float = 1.0) -> Iterator[Px4]:
    """A PX4 SITL on free loopback ports, ready for takeoff; stopped at the end, whatever happens."""
    launcher = px4_launcher()
    assert launcher is not None, SKIP_REASON
    workdir.mkdir(parents=True, exist_ok=True)
    tried: list[int] = []
    failures: list[str] = []
    values: dict[str, str] = {}
    while len(tried) < START_ATTEMPTS:
        api_bind, api_remote, gcs_bind, gcs_remote = free_udp_ports(4)
        instance = choose_instance(avoid=tried)
        tried.append(instance)
        runnable = runnable_launcher(launcher)
        started = subprocess.run(
            [str(runnable), "--api-bind", str(api_bind), "--api-remote", str(api_remote),
             "--gcs-bind", str(gcs_bind), "--gcs-remote", str(gcs_remote), "--instance", str(instance),
             "--speed", f"{speed:g}", "--workdir", str(workdir if not failures else workdir / f"retry-{instance}"), "--timeout", "60"],
            capture_output=True, text=True, timeout=90,
        )  # fmt: skip
        values = dict(line.split("=", 1) for line in started.stdout.splitlines() if "=" in line)
        if started.returncode == 0 and "PX4_PID" in values:
            break
        failures.append(f"--instance {instance}: {started.stderr.strip()}")
    else:
        raise AssertionError("PX4 SITL did not start:\n" + "\n".join(failures))
    pid = int(values["PX4_PID"])
    try:
        yield Px4(pid, Path(values.get("PX4_LOG", workdir / "px4.log")), api_remote, gcs_remote, instance, runnable.parent / "bin")
    finally:
        try:
            os.kill(pid, 15)
            for _ in range(50):
                os.kill(pid, 0)
                time.sleep(0.1)
            os.kill(pid, 9)
        except ProcessLookupError:
            pass
