"""PX4's services of ``sitl-plant`` as a real process over real UDP: MAVLink FTP with pymavlink's
own client (``pymavlink.mavftp.MAVFTP``, MAVProxy's) on the ground-station link, log download and
the shell with the tests' service client on the API link. One plant for the module, in real time,
writing its tlog into a run folder that FTP serves read-only."""

from __future__ import annotations

import signal
import subprocess
import sys
import zlib

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink
from pymavlink.mavftp import MAVFTP, MAVFTPSettings

from offboard.demo import free_udp_ports, stop_process
from sitl_plant.ftp import crc32
from helpers import REPO
from helpers.services import ServiceClient

pytestmark = pytest.mark.e2e

NOTES = b"".join(b"line %04d of a file the plant serves\n" % i for i in range(300))  # 11 KB: several bursts


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    run = tmp_path_factory.mktemp("run")
    (run / "notes.txt").write_bytes(NOTES)
    (tmp_path_factory.getbasetemp() / "private.txt").write_text("not served")
    api_port, gcs_port = free_udp_ports(2)
    client = ServiceClient(api_port)
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255, source_component=190, dialect="common")
    proc = subprocess.Popen(
        [sys.executable, "-m", "sitl_plant.cli", "--quiet", "--api-bind", "127.0.0.1:0", "--api-remote", f"127.0.0.1:{api_port}",
         "--gcs-bind", "127.0.0.1:0", "--gcs-remote", f"127.0.0.1:{gcs_port}", "--log", str(run / "flight.tlog")],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        client.connect()
        assert gcs.wait_heartbeat(timeout=10) is not None
        yield client, gcs, run
    finally:
        stop_process(proc, signal.SIGTERM)
        client.close()
        gcs.close()


def test_pymavlinks_ftp_client_lists_reads_and_checks_the_run_folder(plant):
    _client, gcs, run = plant
    quick = [("debug", int, 0), ("pkt_loss_tx", int, 0), ("pkt_loss_rx", int, 0), ("max_backlog", int, 5),
             ("burst_read_size", int, 239), ("write_size", int, 80), ("write_qsize", int, 5),
             ("idle_detection_time", float, 0.6), ("read_retry_time", float, 0.5), ("retry_time", float, 0.3)]  # fmt: skip
    ftp = MAVFTP(gcs, 1, 1, MAVFTPSettings(quick))  # MAVProxy's defaults but 0.6 s of silence ends a reply, not 3.7 s
    listed = ftp.cmd_list(["/"])
    assert listed.error_code == 0
    names = {e.name: e for e in ftp.list_result}
    assert {"flight.tlog", "notes.txt"} <= set(names) and names["notes.txt"].size_b == len(NOTES)
    assert ftp.read("/notes.txt", len(NOTES)) == NOTES  # burst reads, continued burst after burst
    crc = ftp.cmd_crc(["/notes.txt"])
    assert crc.error_code == 0
    assert crc32(NOTES) != zlib.crc32(NOTES)  # PX4's crc32part, not zlib's
    outside = ftp.cmd_list(["/.."])
    assert outside.error_code != 0  # FileNotFound: nothing outside the folder
    assert "private.txt" not in {e.name for e in ftp.list_result}


def test_log_download_serves_the_plants_own_tlog(plant):
    client, _gcs, run = plant
    client.connect()
    client.send(mavlink.MAVLink_log_request_list_message(1, 1, 0, 0xFFFF))
    entry = client.wait({mavlink.MAVLINK_MSG_ID_LOG_ENTRY}, 2.0)
    assert entry is not None
    assert (entry.id, entry.num_logs) == (0, 1) and entry.size > 0 and entry.time_utc > 1_600_000_000
    client.send(mavlink.MAVLink_log_request_data_message(1, 1, 0, 0, 0xFFFFFFFF))
    got: dict[int, bytes] = {}
    while sum(len(v) for v in got.values()) < entry.size:
        batch = client.receive({mavlink.MAVLINK_MSG_ID_LOG_DATA}, 0.3)
        if not batch:
            break
        got.update((d.ofs, bytes(d.data[: d.count])) for d in batch)
    data = b"".join(got[k] for k in sorted(got))
    assert len(data) == entry.size
    assert data == (run / "flight.tlog").read_bytes()[: entry.size]  # the file as it was listed
    client.send(mavlink.MAVLink_log_request_end_message(1, 1))


def test_the_shell_answers_like_pxh(plant):
    client, _gcs, _run = plant
    client.connect()
    assert client.shell("\n") == "\npxh> "
    ver = client.shell("ver all\n")
    assert ver.startswith("ver all\nHW arch: ") and "PX4 version: Release " in ver and ver.endswith("pxh> ")
    shown = client.shell("param show MPC_XY_VEL_MAX\n")
    assert "x   MPC_XY_VEL_MAX [" in shown and "parameters used." in shown
    assert client.shell("foo\n") == "foo\nInvalid command: foo\ntype 'help' for a list of commands\npxh> "
