"""What goes on the wire, PX4 v1.16 SITL against sitl-plant, with the same client code: the
message types and rates of the API and GCS links, AUTOPILOT_VERSION, and the types and values of
parameters clients read; and the offboard link's loss counter on PX4's dialect frames.

Both are listened to as a common.xml client hears them (pymavlink's common dialect: PX4's
development-dialect messages arrive as UNKNOWN_<id>). Rates are per second of the vehicle's own
clock (the span of ATTITUDE's time_boot_ms). PX4 sends each stream at its configured rate, on a
loaded machine at 55-90 % of it (its loop falls behind); the plant at the configured rate: a
ratio plant / PX4 of 0.75 .. 1.9 is "the same" (a stream at half or twice PX4's is not).
"""

from __future__ import annotations

import select
import socket
import struct
import subprocess
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from bench.px4sitl import running_px4
from helpers.flights import ENV, PY
from offboard.demo import free_udp_ports
from offboard.link import MavLink

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py

LISTEN_S = 4.0  # wall seconds of each capture (x speed of vehicle time)
SPEED = 2.0
#: PX4 sends these, the plant does not (docs/parity/wire.md): CURRENT_EVENT_SEQUENCE and EVENT,
#: the events protocol, which the plant does not implement.
NOT_IN_PLANT = {"UNKNOWN_410", "UNKNOWN_411"}
PARAMS = ("SYS_AUTOSTART", "MAV_TYPE", "COM_OF_LOSS_T", "NAV_DLL_ACT", "RTL_RETURN_ALT", "MIS_TAKEOFF_ALT",
          "MPC_XY_CRUISE", "MPC_XY_VEL_MAX", "GF_ACTION", "BAT1_N_CELLS", "CAL_ACC0_ID", "COM_RC_IN_MODE",
          "MC_ROLLRATE_P", "MPC_THR_HOVER")  # fmt: skip


class Listener:
    """Both links of one vehicle: UDP sockets where the vehicle sends, a common.xml parser each."""

    def __init__(self, api_port: int, gcs_port: int) -> None:
        self.socks = []
        for port in (api_port, gcs_port):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", port))
            s.setblocking(False)
            self.socks.append(s)
        self.parsers = [mavlink.MAVLink(None), mavlink.MAVLink(None)]
        for p in self.parsers:
            p.robust_parsing = True
        self.addr = [None, None]
        self.packer = mavlink.MAVLink(None, srcSystem=245, srcComponent=191)

    def pump(self, seconds: float, on_message) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ready, _, _ = select.select(self.socks, [], [], 0.05)
            for s in ready:
                i = self.socks.index(s)
                while True:
                    try:
                        data, self.addr[i] = s.recvfrom(65536)
                    except BlockingIOError:
                        break
                    for msg in self.parsers[i].parse_buffer(data) or []:
                        if msg.get_type() != "BAD_DATA":
                            on_message(i, msg)

    def streams(self, seconds: float) -> list[dict[str, float]]:
        counts: list[dict[str, int]] = [{}, {}]
        span: list[list[int]] = [[], []]

        def count(i, msg):
            kind = msg.get_type()
            counts[i][kind] = counts[i].get(kind, 0) + 1
            if kind == "ATTITUDE":
                span[i].append(int(msg.time_boot_ms))

        self.pump(seconds, count)
        rates = []
        for i in (0, 1):
            assert span[i], f"{('API', 'GCS')[i]} link: no ATTITUDE in {seconds:g} s (heard from it: {self.addr[i] is not None})"
            sim_s = (max(span[i]) - min(span[i])) / 1000.0
            assert sim_s > 3.0, f"link {i}: too little telemetry"
            rates.append({k: n / sim_s for k, n in counts[i].items()})
        return rates

    def ask(self, msg, wanted, timeout_s: float = 3.0):
        """Send ``msg`` on the API link; the first message for which ``wanted(msg)`` holds."""
        found = []
        self.socks[0].sendto(msg.pack(self.packer), self.addr[0])
        end = time.monotonic() + timeout_s
        while not found and time.monotonic() < end:
            self.pump(0.05, lambda i, m: found.append(m) if i == 0 and not found and wanted(m) else None)
        return found[0] if found else None

    def close(self) -> None:
        for s in self.socks:
            s.close()


def observe(api_port: int, gcs_port: int) -> dict:
    lis = Listener(api_port, gcs_port)
    try:
        lis.pump(10.0, lambda i, m: None) if lis.addr[0] is None else None  # until both links speak
        end = time.monotonic() + 20
        while (lis.addr[0] is None or lis.addr[1] is None) and time.monotonic() < end:
            lis.pump(0.2, lambda i, m: None)
        out = {"rates": lis.streams(LISTEN_S)}
        out["version"] = lis.ask(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                 mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0),
                                 lambda m: m.get_type() == "AUTOPILOT_VERSION")  # fmt: skip
        params = {}
        for name in PARAMS:
            reply = lis.ask(mavlink.MAVLink_param_request_read_message(1, 1, name.encode(), -1),
                            lambda m, n=name: m.get_type() == "PARAM_VALUE" and m.param_id == n)  # fmt: skip
            params[name] = None if reply is None else (reply.param_type, reply.param_value)
        out["params"] = params
        return out
    finally:
        lis.close()


@pytest.fixture(scope="module")
def px4(tmp_path_factory):
    with running_px4(tmp_path_factory.mktemp("px4"), speed=SPEED) as vehicle:
        seen = observe(vehicle.api_listen_port, vehicle.gcs_listen_port)
        seen["loss"] = offboard_link_stats(vehicle.api_listen_port)
    yield seen


def offboard_link_stats(port: int):
    """The offboard's own link listening to the API link for 2 s (after the first 50 packets)."""
    with MavLink(f"udpin:127.0.0.1:{port}") as link:
        end = time.monotonic() + 10
        while link.stats.received < 50 and time.monotonic() < end:
            link.recv(0.5)
        start = time.monotonic()
        while time.monotonic() - start < 2.0:
            link.recv(0.1)
    return link.stats


@pytest.fixture(scope="module")
def plant():
    api_bind, api_remote, gcs_bind, gcs_remote = free_udp_ports(4)
    proc = subprocess.Popen(
        [PY, "-m", "sitl_plant.cli", "--quiet", "--speed", f"{SPEED:g}", "--api-bind", f"127.0.0.1:{api_bind}",
         "--api-remote", f"127.0.0.1:{api_remote}", "--gcs-bind", f"127.0.0.1:{gcs_bind}", "--gcs-remote",
         f"127.0.0.1:{gcs_remote}", "--duration", "120"],
        env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        seen = observe(api_remote, gcs_remote)
        seen["loss"] = offboard_link_stats(api_remote)
        yield seen
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def param_text(seen: tuple[int, float] | None) -> str:
    """A PARAM_VALUE's (type, value) as ``10040 (INT32)``: integers decoded from their bytes."""
    if seen is None:
        return "no answer"
    kind, value = seen
    if kind in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT16,
                mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT8):  # fmt: skip
        value = struct.unpack("<i", struct.pack("<f", value))[0]
    name = mavlink.enums["MAV_PARAM_TYPE"][kind].name.removeprefix("MAV_PARAM_TYPE_") if kind in mavlink.enums["MAV_PARAM_TYPE"] else kind
    return f"{value} ({name})" if isinstance(value, int) else f"{value:g} ({name})"


@pytest.mark.parametrize("link", [0, 1], ids=["api", "gcs"])
def test_the_plant_streams_what_px4_streams_at_px4s_rates(px4, plant, link, parity_finding):
    theirs, ours = px4["rates"][link], plant["rates"][link]
    side = ("api", "gcs")[link]
    parity_finding(f"wire.{side}.types", f"{side.upper()} link: message types (common.xml client)", len(theirs), len(ours))
    parity_finding(f"wire.{side}.alone", f"{side.upper()} link: types only one of the two sent (the plant deliberately "
                   "not PX4's events protocol: CURRENT_EVENT_SEQUENCE 411, EVENT 410)",
                   sorted(set(theirs) - set(ours)) or "none", sorted(set(ours) - set(theirs)) or "none")  # fmt: skip
    for name in sorted(theirs, key=lambda k: (-theirs[k], k)):
        if theirs[name] >= 2.0 and name not in NOT_IN_PLANT:
            parity_finding(f"wire.{side}.rate.{name}", f"{side.upper()} link: {name} (Hz)", theirs[name], ours.get(name, 0.0))
    print(f"\nlink {link}: PX4 {len(theirs)} types, plant {len(ours)}")
    for name in sorted(set(theirs) | set(ours)):
        print(f"  {name:28s} PX4 {theirs.get(name, 0):7.2f} Hz  plant {ours.get(name, 0):7.2f} Hz")
    steady = {k for k, r in theirs.items() if r >= 0.3} - NOT_IN_PLANT  # seen several times in the window
    assert steady <= set(ours), f"PX4 sends, the plant not: {sorted(steady - set(ours))}"
    extra = {k for k in ours if k not in theirs and ours[k] >= 0.3}
    assert not extra, f"the plant sends, PX4 not: {sorted(extra)}"
    for name in steady:
        if theirs[name] >= 2.0:  # enough samples for a rate
            assert 0.75 <= ours[name] / theirs[name] <= 1.9, f"{name}: PX4 {theirs[name]:.2f} Hz, plant {ours[name]:.2f} Hz"


def test_autopilot_version_is_px4s(px4, plant, parity_finding):
    theirs, ours = px4["version"], plant["version"]
    for field in ("capabilities", "flight_sw_version", "middleware_sw_version", "board_version"):
        parity_finding(f"wire.version.{field}", f"AUTOPILOT_VERSION {field}",
                       *(f"0x{getattr(v, field):X}" if v is not None else "none" for v in (theirs, ours)))  # fmt: skip
    parity_finding("wire.version.flight_custom_version", "AUTOPILOT_VERSION flight_custom_version",
                   *(list(v.flight_custom_version) if v is not None else "none" for v in (theirs, ours)))  # fmt: skip
    assert theirs is not None and ours is not None
    for field in ("capabilities", "flight_sw_version", "middleware_sw_version", "board_version", "vendor_id", "product_id"):
        assert getattr(ours, field) == getattr(theirs, field), field
    assert list(ours.flight_custom_version) == list(theirs.flight_custom_version)
    assert ours.uid != 0 and theirs.uid != 0 and list(ours.uid2) == list(theirs.uid2)


def test_parameters_clients_read_have_px4s_types_and_values(px4, plant, parity_finding):
    for name in PARAMS:
        parity_finding(f"wire.param.{name}", f"parameter {name}" + (" (the plant keeps its own: not speed-scaled, "
                       "or its vehicle's)" if name in ("MPC_THR_HOVER", "COM_OF_LOSS_T") else ""),
                       param_text(px4["params"][name]), param_text(plant["params"][name]))  # fmt: skip
    # MPC_THR_HOVER is the vehicle's own (the plant's follows its vehicle file); PX4's SITL start-up
    # (rcS) multiplies COM_OF_LOSS_T by the speed factor, the plant keeps it (docs/parity/wire.md)
    own = {"MPC_THR_HOVER", "COM_OF_LOSS_T"}
    for name in PARAMS:
        theirs, ours = px4["params"][name], plant["params"][name]
        assert theirs is not None and ours is not None, name
        assert ours[0] == theirs[0], f"{name}: type {ours[0]}, PX4 {theirs[0]}"
        if name not in own:
            assert ours[1] == pytest.approx(theirs[1], rel=1e-6, abs=1e-45), name


@pytest.mark.parametrize("vehicle", ["px4", "plant"])
def test_the_offboard_link_counts_no_loss_on_px4s_dialect(px4, plant, vehicle, parity_finding):
    s = {"px4": px4, "plant": plant}[vehicle]["loss"]
    parity_finding("wire.offboard_link_loss", "the offboard's link on the API link for 2 s: received / lost / "
                   "dialect (UNKNOWN_*) frames", **{vehicle: f"{s.received} / {s.lost} / {s.unknown}"})  # fmt: skip
    print(f"\n{vehicle} API link: received {s.received}, lost {s.lost}, unknown (dialect) {s.unknown}")
    assert s.unknown > 0  # its dialect frames did arrive
    assert s.received > 500 and s.lost <= s.received // 100  # loopback: nothing is lost
