"""An unsigned SETUP_SIGNING with a key, sent to the real PX4 v1.16 SITL (SIH, speed 4) and to a
``sitl-plant`` started without ``--signing-key``, by the same client: both ignore it. What they
send stays unsigned and an unsigned command is still answered. (PX4 v1.16 has no MAVLink signing;
the plant once switched signing on with the sender's key, locking its owner out.)
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from bench.px4sitl import running_px4
from helpers import REPO
from helpers.services import ServiceClient, mavlink
from offboard.demo import free_udp_ports, stop_process

PX4_SPEED = 4  # the page of findings says at which speed PX4 ran
pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py

KEY = bytes(range(100, 132))


def signed_and_unsigned(client: ServiceClient, seconds: float) -> tuple[int, int]:
    """How many frames from the vehicle arrived signed and unsigned within ``seconds``."""
    signed = unsigned = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            data, _ = client.sock.recvfrom(65536)
        except TimeoutError:
            continue
        i = 0
        while i + 12 <= len(data) and data[i] == 0xFD:  # MAVLink 2 frames, one after the other
            flags = data[i + 2]
            signed, unsigned = (signed + 1, unsigned) if flags & 1 else (signed, unsigned + 1)
            i += 12 + data[i + 1] + (13 if flags & 1 else 0)
    return signed, unsigned


def setup_signing_outcome(client: ServiceClient) -> dict:
    """Send an unsigned SETUP_SIGNING with a key, then: are the vehicle's frames signed, and is
    an unsigned command still answered?"""
    client.sock.setblocking(False)  # what arrived before it is not what is asked about
    try:
        while True:
            client.sock.recv(65536)
    except BlockingIOError:
        client.sock.settimeout(0.05)
    stamp = int((time.time() - 1_420_070_400) * 1e5)  # 10 us since 2015, as the spec asks
    client.send(mavlink.MAVLink_setup_signing_message(client.target, 1, list(KEY), stamp))
    time.sleep(0.3)
    signed, unsigned = signed_and_unsigned(client, 1.0)
    result = client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    return {"frames_signed": signed > 0, "frames_unsigned": unsigned > 0, "unsigned_command": result}


def _finding(key: str, value: object) -> str:
    if key == "unsigned_command":
        return mavlink.enums["MAV_RESULT"][value].name.removeprefix("MAV_RESULT_") if isinstance(value, int) else str(value)
    return "yes" if value else "no"


def test_an_unsigned_setup_signing_is_ignored_as_px4_does(tmp_path, parity_finding):
    (port,) = free_udp_ports(1)
    ours_client = ServiceClient(port)
    proc = subprocess.Popen(  # started first: it is ready by the time PX4 is
        [sys.executable, "-m", "sitl_plant.cli", "--speed", "4", "--api-bind", "127.0.0.1:0",
         "--api-remote", f"127.0.0.1:{port}", "--gcs-bind", "none"],
        cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        with running_px4(tmp_path / "px4", speed=4) as px4:
            client = ServiceClient(px4.api_listen_port)
            try:
                client.connect()
                theirs = setup_signing_outcome(client)
            finally:
                client.close()
        ours_client.connect()
        ours = setup_signing_outcome(ours_client)
    finally:
        stop_process(proc, signal.SIGTERM)
        ours_client.close()
    err = proc.stderr.read()
    for key, what in (("frames_signed", "its frames signed afterwards"), ("unsigned_command", "an unsigned command answered")):
        parity_finding(f"services.setup_signing.{key}", f"an unsigned SETUP_SIGNING with a key: {what}",
                       _finding(key, theirs[key]), _finding(key, ours[key]))  # fmt: skip
    expected = {"frames_signed": False, "frames_unsigned": True, "unsigned_command": mavlink.MAV_RESULT_ACCEPTED}
    assert theirs == expected, theirs  # PX4 v1.16: no signing, SETUP_SIGNING ignored
    assert ours == theirs
    assert "ignored 1 messages as PX4 v1.16 does (SETUP_SIGNING 1" in err, err
