"""A real ground station against ``sitl-plant``: MAVProxy (from PyPI) on the GCS link.

MAVProxy is driven through its standard input (commands as a user types them) and watched
through its standard output; the plant's tlog then shows what went over the wire.
"""

from __future__ import annotations

import os
import select
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from helpers import REPO

pytestmark = pytest.mark.e2e

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Console:
    """MAVProxy's output, read without blocking, searchable as it grows."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self.text = ""
        os.set_blocking(proc.stdout.fileno(), False)  # type: ignore[union-attr]

    def expect(self, needle: str, timeout: float = 30.0, after: int = 0) -> int:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = self.text.find(needle, after)
            if found >= 0:
                return found + len(needle)
            readable, _, _ = select.select([self.proc.stdout], [], [], 0.2)
            if readable:
                self.text += self.proc.stdout.read() or ""  # type: ignore[union-attr]
            if self.proc.poll() is not None and needle not in self.text:
                break
        raise AssertionError(f"MAVProxy never printed {needle!r}; it printed:\n{self.text}")

    def send(self, line: str) -> int:
        mark = len(self.text)
        self.proc.stdin.write(line + "\n")  # type: ignore[union-attr]
        self.proc.stdin.flush()  # type: ignore[union-attr]
        return mark


@pytest.fixture
def processes():
    started: list[subprocess.Popen] = []
    yield started
    for proc in reversed(started):
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def test_mavproxy_sees_mode_and_arming_and_arms_the_vehicle(processes, tmp_path):
    gcs_port = free_udp_port()
    log = tmp_path / "plant.tlog"
    plant = subprocess.Popen(
        [sys.executable, "-m", "sitl_plant.cli", "--quiet", "--api-bind", "127.0.0.1:0", "--api-remote", "none",
         "--gcs-bind", "127.0.0.1:0", "--gcs-remote", f"127.0.0.1:{gcs_port}", "--log", str(log)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    processes.append(plant)
    mavproxy = subprocess.Popen(
        [str(MAVPROXY if MAVPROXY.exists() else shutil.which("mavproxy.py") or "mavproxy.py"), f"--master=udpin:127.0.0.1:{gcs_port}",
         "--default-modules=arm,mode", f"--state-basedir={tmp_path / 'mavproxy'}"],
        cwd=tmp_path, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "TERM": "dumb"},
    )  # fmt: skip
    processes.append(mavproxy)
    console = Console(mavproxy)

    console.expect("Detected vehicle 1:1")
    console.expect("Mode LOITER")  # PX4's AUTO_LOITER (Hold), decoded from our heartbeat
    mark = console.send("arm throttle")
    mark = console.expect("COMPONENT_ARM_DISARM: ACCEPTED", after=mark)
    console.expect("\nARMED", after=mark)  # a line of its own, not the end of DISARMED
    mark = console.send("disarm")
    console.expect("DISARMED", after=mark)

    plant.terminate()
    assert plant.wait(timeout=10) == 0
    # what went over the wire: MAVProxy's command and our heartbeats saying armed
    reader = mavutil.mavlink_connection(str(log), dialect="common")
    arm_commands, armed_beats = 0, 0
    while (msg := reader.recv_match()) is not None:
        if msg.get_type() == "COMMAND_LONG" and msg.command == 400 and msg.get_srcSystem() == 255:
            arm_commands += 1
        if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.base_mode & 128:
            armed_beats += 1
    assert arm_commands >= 2 and armed_beats >= 1
