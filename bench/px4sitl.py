"""A real PX4 SITL for the tests that are about PX4 (marker ``px4``) and the benchmarks.

The launcher is ``$PX4_SITL`` or ``../shared/px4-sitl/px4-sitl`` beside the project (a PX4 v1.16
SITL with its SIH quadrotor; its README). Tests without one are skipped with the one line
``SKIP_REASON`` saying how to point them at a PX4. ``running_px4`` starts it on free ports and
always stops it.

A copy of PX4's ``bin/`` that lost its symbolic links (each ``px4-<module>`` then a small file
holding the word ``px4``, not executable: PX4's start-up script fails with "px4-param:
Permission denied") is run from a mirror with the links restored, in a temporary folder; the
original is never written to.
"""

from __future__ import annotations

import hashlib
import os
import random
import subprocess
import tempfile
import time
from collections.abc import Iterator
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


@dataclass(frozen=True)
class Px4:
    pid: int
    log: Path
    api_listen_port: int  # where PX4 sends its API link: offboard fly --connect udpin:127.0.0.1:PORT
    gcs_listen_port: int = 0  # where PX4 sends its ground-station link


@contextmanager
def running_px4(workdir: Path, *, speed: float = 1.0) -> Iterator[Px4]:
    """A PX4 SITL on free loopback ports, ready for takeoff; stopped at the end, whatever happens."""
    launcher = px4_launcher()
    assert launcher is not None, SKIP_REASON
    api_bind, api_remote, gcs_bind, gcs_remote = free_udp_ports(4)
    instance = random.randint(20, 90)
    workdir.mkdir(parents=True, exist_ok=True)
    started = subprocess.run(
        [str(runnable_launcher(launcher)), "--api-bind", str(api_bind), "--api-remote", str(api_remote),
         "--gcs-bind", str(gcs_bind), "--gcs-remote", str(gcs_remote), "--instance", str(instance),
         "--speed", f"{speed:g}", "--workdir", str(workdir), "--timeout", "60"],
        capture_output=True, text=True, timeout=90,
    )  # fmt: skip
    values = dict(line.split("=", 1) for line in started.stdout.splitlines() if "=" in line)
    assert started.returncode == 0 and "PX4_PID" in values, f"PX4 SITL did not start:\n{started.stderr}"
    pid = int(values["PX4_PID"])
    try:
        yield Px4(pid, Path(values.get("PX4_LOG", workdir / "px4.log")), api_remote, gcs_remote)
    finally:
        try:
            os.kill(pid, 15)
            for _ in range(50):
                os.kill(pid, 0)
                time.sleep(0.1)
            os.kill(pid, 9)
        except ProcessLookupError:
            pass
