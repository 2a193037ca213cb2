"""``sitl-plant``'s fault options on a real plant process (issue 14): ``--allow-sysid`` refuses
another system's frames and says so at exit, by sender; ``--link-in`` / ``--link-out`` impair
what the plant receives and sends, as the exit report counts it; and the tlog records the
impairment whole (the options that reproduce it, in chunked STATUSTEXT), read back with
pymavlink. A few seconds each."""

from __future__ import annotations

import signal
import socket
import subprocess
import time

from pymavlink import mavutil

from helpers.flights import ENV, PY
from helpers.services import ServiceClient, mavlink
from offboard.demo import free_udp_ports, stop_process
from sitl_plant.impairment import parse_impairment

LINK_IN = "loss=30"
LINK_OUT = "delay=80,jitter=30,reorder=2,duplicate=1,corrupt=0.1"
SEED = 7
PINGS = 100


def start_plant(client_port: int, *options: str) -> subprocess.Popen:
    plant = subprocess.Popen([PY, "-m", "sitl_plant.cli", "--api-bind", "127.0.0.1:0", "--api-remote", f"127.0.0.1:{client_port}",
                              "--gcs-bind", "none", *options], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             env=ENV)  # fmt: skip
    banner = plant.stderr.readline()  # printed once the links are up
    assert banner.startswith("sitl-plant:"), banner
    return plant


def stop(plant: subprocess.Popen) -> str:
    stop_process(plant, signal.SIGTERM)
    err = plant.stderr.read()
    assert plant.returncode == 0, err
    assert "Traceback" not in err, err
    return err


def armed(client: ServiceClient) -> bool:
    beat = client.wait({mavlink.MAVLINK_MSG_ID_HEARTBEAT}, 3.0)
    assert beat is not None
    return bool(beat.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


def test_allow_sysid_refuses_another_system_and_reports_it_by_sender():
    (port,) = free_udp_ports(1)
    owner = ServiceClient(port, sysid=245)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plant = start_plant(port, "--allow-sysid", "245,255")
    try:
        owner.connect()
        assert owner.peer is not None
        intruder = mavlink.MAVLink(None, srcSystem=200, srcComponent=190)
        attacks = [mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 21196, 0, 0, 0, 0, 0),  # forced arm
                   mavlink.MAVLink_param_set_message(1, 1, b"MPC_XY_VEL_MAX", 1.0, mavlink.MAV_PARAM_TYPE_REAL32),
                   mavlink.MAVLink_command_long_message(1, 1, 176, 0, 1, 4, 3, 0, 0, 0, 0)]  # Hold  # fmt: skip
        for msg in attacks:
            stranger.sendto(msg.pack(intruder), owner.peer)
        time.sleep(0.3)
        assert not armed(owner)
        # the owner is still answered: its own command is
        assert owner.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == mavlink.MAV_RESULT_ACCEPTED
    finally:
        stranger.close()
        owner.close()
        err = stop(plant)
    assert "frames handled from system ids 245,255 only" in err, err
    assert "refused 3 frames before handling (sender 3; system 200: 3)" in err, err


def test_link_in_and_out_impair_a_real_plant_and_its_tlog_says_how(tmp_path):
    """PINGs sent to a plant that loses 30 % of what it receives and delays what it sends by
    80 +- 30 ms: the answers that come back are the pings the plant's report says it did not
    drop, each at least 50 ms late."""
    (port,) = free_udp_ports(1)
    client = ServiceClient(port, sysid=245)
    tlog = tmp_path / "plant.tlog"
    plant = start_plant(port, "--link-in", LINK_IN, "--link-out", LINK_OUT, "--seed", str(SEED), "--log", str(tlog))
    sent: dict[int, float] = {}
    answers: dict[int, float] = {}
    try:
        client.connect()  # also lost 30 % of the time: it says nothing the test counts on
        for seq in range(PINGS):
            sent[seq] = time.monotonic()
            client.send(mavlink.MAVLink_ping_message(int(sent[seq] * 1e6), seq, 0, 0))
            for m in client.receive({mavlink.MAVLINK_MSG_ID_PING}, 0.01):
                if m.target_system == 245:
                    answers.setdefault(m.seq, time.monotonic())
        for m in client.receive({mavlink.MAVLINK_MSG_ID_PING}, 0.5):
            if m.target_system == 245:
                answers.setdefault(m.seq, time.monotonic())
    finally:
        client.close()
        err = stop(plant)
    report = err.split("sitl-plant: api link in: ")[1].splitlines()[0]
    datagrams, dropped = int(report.split(" datagrams")[0]), int(report.split(": ")[1].split(" dropped")[0])
    assert datagrams == PINGS + 1  # the pings and the connect's heartbeat
    assert 0.15 * datagrams < dropped < 0.45 * datagrams, report
    # every ping the plant kept was answered (the kept datagrams are the pings and maybe the
    # heartbeat; the way back loses nothing but what corrupt=0.1 % may spoil: one at most)
    kept = datagrams - dropped
    assert kept - 2 <= len(answers) <= kept, (report, len(answers))
    assert "sitl-plant: api link out: " in err
    delays_ms = sorted((answers[s] - sent[s]) * 1e3 for s in answers)
    early = [d for d in delays_ms if d < 50.0]  # 80 - 30 ms: only a reordered datagram (2 %) skips the delay
    assert len(early) <= 6 and delays_ms[len(delays_ms) // 2] >= 60.0, delays_ms

    # the tlog says what link it was recorded over, whole: chunks of one id joined in order
    log = mavutil.mavlink_connection(str(tlog))
    chunks: dict[int, dict[int, str]] = {}
    while (m := log.recv_match(type="STATUSTEXT")) is not None:
        if m.get_srcSystem() == 1:
            chunks.setdefault(m.id, {})[m.chunk_seq] = m.text
    notes = ["".join(parts[i] for i in sorted(parts)) for parts in chunks.values()]
    notes = [n for n in notes if n.startswith("sitl-plant --link-")]
    recorded = {}
    for note in notes:
        _, option, spec, _, seed = note.split(": ")[0].split(" ")  # sitl-plant --link-out SPEC --seed N: in words
        recorded[option] = (parse_impairment(spec, option), int(seed))
    assert recorded == {"--link-in": (parse_impairment(LINK_IN), SEED), "--link-out": (parse_impairment(LINK_OUT), SEED)}, notes
