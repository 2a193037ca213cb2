"""The same ground-station client against the real PX4 v1.16 SITL and against ``sitl-plant``:
mission upload, download and clear (mission, geofence and rally lists), the protocol's refusals,
and a short mission flown in Mission mode. The two must answer the same exchange and reach the
same items; the flown times (simulation time) are printed and held within a stated tolerance.

One PX4 (speed 4) and one plant serve the module. What was measured is in docs/parity/mission.md.
"""

from __future__ import annotations

import math
import time

import pytest
from pymavlink import mavutil

from bench.px4sitl import running_px4
from helpers import REPO
from helpers.mission_client import MAV, Item, MissionClient, fly_mission, items_from_file, quiet_streams, start_plant
from offboard.demo import stop_process
from offboard.missions import MISSIONS_DIR

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py
PX4_SPEED = 4


@pytest.fixture(scope="module")
def vehicles(tmp_path_factory):
    """{"px4": (conn, sysid), "plant": (conn, sysid), "px4_log": PX4's console log}, both ready to arm."""
    with running_px4(tmp_path_factory.mktemp("px4"), speed=PX4_SPEED) as px4:
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{px4.api_listen_port}", source_system=255, source_component=190)
        hb = conn.wait_heartbeat(timeout=30)
        assert hb is not None, "PX4 sent no heartbeat"
        plant_conn, proc = start_plant("--speed", "50", "--physics-dt", "0.004")
        try:
            quiet_streams(conn, hb.get_srcSystem())
            quiet_streams(plant_conn, 1)
            yield {"px4": (conn, hb.get_srcSystem()), "plant": (plant_conn, 1), "px4_log": px4.log}
        finally:
            stop_process(proc)
            plant_conn.close()
            conn.close()


def on_both(vehicles, fly) -> dict:
    """``fly(conn, sysid)`` on PX4 and on the plant at once (a thread each: the two run their own
    clocks, so flying them side by side halves the wall time); re-raises the first failure."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(2) as pool:
        futures = {name: pool.submit(fly, *vehicles[name]) for name in ("px4", "plant")}
        return {name: f.result() for name, f in futures.items()}


def px4_console_size(vehicles) -> int:
    log = vehicles["px4_log"]
    return log.stat().st_size if log.exists() else 0


def px4_console_since(vehicles, offset: int, lines: int = 40) -> str:
    """The last ``lines`` of what PX4 printed on its console since ``offset`` (bytes)."""
    log = vehicles["px4_log"]
    if not log.exists():
        return f"(no console log at {log})"
    with log.open("rb") as f:
        f.seek(offset)
        text = f.read().decode(errors="replace")
    return "\n".join(text.splitlines()[-lines:]) or "(nothing)"


def mission_current(conn, timeout_s: float = 5.0, until=lambda seq_total: True):
    """The next MISSION_CURRENT's (seq, total), or the first that satisfies ``until``; the last
    heard (or None) after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        msg = conn.recv_match(type="MISSION_CURRENT", blocking=True, timeout=0.2)
        if msg is not None:
            last = (msg.seq, msg.total)
            if until(last):
                return last
    return last


def home_of(conn) -> tuple[int, int]:
    msg = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=10)
    assert msg is not None
    return msg.lat, msg.lon


def protocol_exchange(conn, sysid) -> dict:
    """Everything the protocol answers, for one vehicle (its first upload after boot included)."""
    c = MissionClient(conn, sysid)
    box = items_from_file(MISSIONS_DIR / "px4-sitl-box.waypoints")
    out: dict = {}
    up = c.upload(box)
    out["upload"] = (up.steps(), up.ack)
    out["current after upload"] = mission_current(conn)
    down = c.download()
    out["download"] = (down.count, [i.key() for i in down.items] == [i.key() for i in box])
    lat, lon = 473977420, 85455940
    fence = [Item(5, 5001, (4, 0, 0, 0), lat + dn, lon + de, 0.0) for dn, de in ((-9000, -13000), (9000, -13000), (9000, 13000), (-9000, 13000))]
    out["fence upload"] = c.upload(fence, 1).ack
    fence_down = c.download(1)
    out["fence download"] = (fence_down.count, [i.autocontinue for i in fence_down.items], [i.command for i in fence_down.items])
    out["rally upload"] = c.upload([Item(5, 5100, (0, 0, 0, 0), lat + 1000, lon + 1000, 0.0)], 2).ack
    out["rally download"] = c.download(2).count
    out["too few vertices"] = c.upload([Item(5, 5001, (2, 0, 0, 0), lat, lon, 0.0)], 1).ack
    out["local frame"] = c.upload([Item(1, 16, (0, 0, 0, 0), 0, 0, 5.0)]).ack
    out["unknown command"] = c.upload([Item(6, 31000, (0, 0, 0, 0), lat, lon, 5.0)]).ack
    conn.mav.mission_count_send(sysid, 1, 65535, 0)
    out["65535 items"] = (c._recv(("MISSION_ACK",)) or type("none", (), {"type": None})).type
    out["clear fence"] = c.clear(1).ack
    out["clear rally"] = c.clear(2).ack
    out["mission kept"] = c.download().count
    out["clear mission"] = c.clear(0).ack
    # PX4 acks the clear at once and empties its storage a moment later (dataman, asynchronous):
    # on a loaded machine a download right after the ACK still found the 7 items. A client waits
    # for MISSION_CURRENT to show the empty list first (the plant's is at once).
    out["current after clear"] = mission_current(conn, until=lambda seq_total: seq_total[1] in (0, 65535))
    out["download after clear"] = c.download().steps()
    return out


def test_the_mission_protocol_answers_as_px4(vehicles, parity_finding):
    got = {name: protocol_exchange(*vehicles[name]) for name in ("px4", "plant")}
    for key in got["px4"]:
        print(f"{key}: PX4 {got['px4'][key]}  plant {got['plant'][key]}")
        parity_finding(f"mission.protocol.{key}", f"mission protocol: {key}", got["px4"][key], got["plant"].get(key))
    assert got["plant"] == got["px4"]
    # and what PX4 v1.16 said, written down (the comparison above could pass with both wrong)
    px4 = got["px4"]
    assert px4["upload"][0][:3] == [("MISSION_COUNT", 7), ("MISSION_REQUEST", 0), ("MISSION_ITEM_INT", 0)]
    assert px4["upload"][1] == MAV.MAV_MISSION_ACCEPTED and px4["current after upload"] == (0, 7)
    assert px4["fence download"] == (4, [0, 0, 0, 0], [5001] * 4)
    assert (px4["local frame"], px4["unknown command"], px4["65535 items"]) == (2, 3, 4)
    assert px4["current after clear"] == (0, 65535)



#: The bundled missions, with the items PX4 v1.16 flies through (no hold time, the next waypoint
#: further than the acceptance radius: FlightTaskAuto plans the corner at sqrt(MPC_XY_TRAJ_P
#: MPC_ACC_HOR NAV_ACC_RAD tan(alpha / 2)), 1.0-1.5 m/s at these 90-degree corners) and those it
#: stops at (a hold time, a loiter), by seq.
BUNDLED = {
    "px4-sitl-box.waypoints": {"through": (2, 4), "stops": (3, 5)},
    "px4-sitl-survey.plan": {"through": (3, 4, 5, 6, 7, 8), "stops": (9, 10)},
}
#: the slowest speed within 2.5 s of an item's MISSION_ITEM_REACHED below this: it stopped. PX4's
#: corners 0.85-1.56 m/s over four runs of each file, its stops 0.01-0.46; the plant's 2.2-2.5 and 0.0-0.04
STOPPED_M_S = 0.65


def fly_bundled(conn, sysid, name: str) -> dict:
    """Clear the mission, upload a bundled file, fly it in Mission mode from arming to the disarm
    after the landing, then Hold. PX4 v1.16 keeps the current item of the mission flown before
    across an upload (MissionBase: the new mission's current_seq is the old one, within the new
    count; neither a Hold nor MISSION_SET_CURRENT 0 while landed reset it): without the clear it
    flew the survey from item 6, where the box had ended."""
    from helpers.mission_client import command

    c = MissionClient(conn, sysid)
    # an unanswered clear is sent again, as ground stations do (one went unanswered after a flight)
    cleared = [c.clear(0).ack for _ in range(3)]
    emptied = mission_current(conn, until=lambda seq_total: seq_total[1] in (0, 65535))
    assert emptied is not None and emptied[1] in (0, 65535), (sysid, cleared, emptied)
    assert c.upload(items_from_file(MISSIONS_DIR / name)).ack == 0
    assert (mission_current(conn, until=lambda seq_total: seq_total[0] == 0) or (None,))[0] == 0, sysid
    f = fly_mission(conn, sysid, timeout_s=90.0)
    command(conn, sysid, MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3)
    cleared = [c.clear(0).ack for _ in range(3)]  # and nothing left behind for the module's next upload
    emptied = mission_current(conn, until=lambda seq_total: seq_total[1] in (0, 65535))
    assert emptied is not None and emptied[1] in (0, 65535), (sysid, cleared, emptied)
    start = f.track[0][0]
    speeds = [((a[0] + b[0]) / 2, math.hypot(b[1] - a[1], b[2] - a[2]) / ((b[0] - a[0]) / 1000))
              for a, b in zip(f.track, f.track[3:]) if b[0] > a[0]]  # fmt: skip
    slowest = {seq: round(min((v for t, v in speeds if abs(t - at) < 2500), default=math.nan), 2) for seq, at in f.reached_at_ms.items()}
    return {
        "reached": f.reached,
        "reached s": {seq: round((t - start) / 1000, 1) for seq, t in f.reached_at_ms.items()},
        "slowest m/s": slowest,
        "top m/s": round(max(v for _, v in speeds), 2),
        "disarmed s": None if f.disarmed_at_ms is None else round((f.disarmed_at_ms - start) / 1000, 1),
        "landed from home m": round(math.hypot(f.track[-1][1] - f.track[0][1], f.track[-1][2] - f.track[0][2]), 1),
        "modes": [m for m, _ in f.modes],
    }


def _slowest(obs: dict) -> str:
    """The slowest speed at each item reached, as ``seq: m/s`` (waypoints flown through or stopped at)."""
    return ", ".join(f"{seq}: {v:.2f}" for seq, v in sorted(obs["slowest m/s"].items()))


def test_the_bundled_missions_fly_on_both_as_px4_flies_them(vehicles, parity_finding):
    """missions/px4-sitl-box.waypoints and px4-sitl-survey.plan, each uploaded to PX4 and the plant
    by the same client and flown side by side: the same items reached in order, the same
    waypoints flown through and stopped at, both land home and disarm, in PX4's time."""
    got = {}
    for name in BUNDLED:
        got[name] = on_both(vehicles, lambda conn, sysid: fly_bundled(conn, sysid, name))  # noqa: B023
        for who in ("px4", "plant"):
            print(name, who, got[name][who])
    for name in BUNDLED:
        px4, plant = got[name]["px4"], got[name]["plant"]
        parity_finding(f"mission.bundled.{name}.reached", f"{name} in Mission mode: MISSION_ITEM_REACHED in order",
                       px4["reached"], plant["reached"])  # fmt: skip
        parity_finding(f"mission.bundled.{name}.disarmed s", f"{name} in Mission mode: arming to the disarm after the "
                       "landing (s)", px4["disarmed s"], plant["disarmed s"])  # fmt: skip
        parity_finding(f"mission.bundled.{name}.landed from home m", f"{name} in Mission mode: landed from home (m)",
                       px4["landed from home m"], plant["landed from home m"])  # fmt: skip
        parity_finding(f"mission.bundled.{name}.slowest", f"{name} in Mission mode: slowest speed at each item (m/s)",
                       _slowest(px4), _slowest(plant))  # fmt: skip
    for name, expect in BUNDLED.items():
        px4, plant = got[name]["px4"], got[name]["plant"]
        n = len(items_from_file(MISSIONS_DIR / name))
        assert px4["reached"] == list(range(1, n)), name  # the take-off and the speed change in one step
        assert plant["reached"] == px4["reached"], name
        # PX4 came down 0.2-0.9 m from where it armed after the box, 0.3-8.6 m after the survey
        # (its landing there starts from 50 m away: 8.6 m in one make test run, 0.3-5.0 m in the
        # eleven before); the plant at 0.0 m. PX4's bound tells landing at the land item from
        # landing anywhere on the last leg (50 m); the plant is held to its own 0.0 m
        assert px4["landed from home m"] < 15.0 and plant["landed from home m"] < 2.5, name
        for obs in (px4, plant):
            assert obs["disarmed s"] is not None, name
            assert obs["modes"][-1] == (4, 4), name  # Mission until disarmed
            for seq in expect["through"]:
                assert obs["slowest m/s"][seq] > STOPPED_M_S, (name, seq, obs["slowest m/s"])
            for seq in expect["stops"]:
                assert obs["slowest m/s"][seq] < STOPPED_M_S, (name, seq, obs["slowest m/s"])
    # arming -> disarmed after the landing (simulation time). The box: PX4 71.7-80.1 s over eight
    # runs (+-5 % about 76 s: EKF, land detector, the corners' speeds), the plant 64.8-65.6 s since
    # it flies through waypoints as PX4 (before: 63.4-65.6 s, stopping at each but overshooting the
    # cruise speed by a third); 0.82-0.91 of the same run's PX4, 0.81-0.91 over PX4's spread: the
    # plant's legs are quicker (no drag: PX4's SIH peaks at 2.8-2.9 m/s at 3 set, the plant at
    # 3.5), hence +-25 % as the short mission. The survey: PX4 161.6-163.4 s in the three runs flown from
    # its first item (the others started at item 6, see fly_bundled), the plant 129.3-129.8 s,
    # 0.79-0.80 of it: held within 30 % until more runs give PX4's spread.
    box, survey = (got[name] for name in BUNDLED)
    assert box["plant"]["disarmed s"] == pytest.approx(box["px4"]["disarmed s"], rel=0.25)
    assert survey["plant"]["disarmed s"] == pytest.approx(survey["px4"]["disarmed s"], rel=0.3)


def short_mission(home: tuple[int, int]) -> list[Item]:
    lat, lon = home
    north = lat + round(12.0 / 111195.0 * 1e7)  # 12 m north of home
    return [
        Item(6, 22, (0, 0, 0, math.nan), lat, lon, 5.0),  # take off to 5 m
        Item(2, 178, (1, 3, -1, 0), 0, 0, 0.0),  # 3 m/s
        Item(6, 16, (0, 2, 0, math.nan), north, lon, 5.0),
        Item(6, 21, (0, 0, 0, math.nan), north, lon, 0.0),
    ]


def test_a_short_mission_reaches_the_same_items_on_both(vehicles, parity_finding):
    def fly(conn, sysid):
        assert MissionClient(conn, sysid).upload(short_mission(home_of(conn))).ack == 0
        return fly_mission(conn, sysid, timeout_s=60.0)

    console_from = px4_console_size(vehicles)
    flights = on_both(vehicles, fly)
    summary = {}
    for name, f in flights.items():
        start = f.track[0][0]
        land = f.track[-1]
        summary[name] = {
            "reached": f.reached,
            "reached s": {seq: round((t - start) / 1000, 1) for seq, t in f.reached_at_ms.items()},
            "end north m": round(land[1] - f.track[0][1], 2),
            "disarmed s": None if f.disarmed_at_ms is None else round((f.disarmed_at_ms - start) / 1000, 1),
        }
        print(name, summary[name], "modes", f.modes, "texts", f.texts)  # the plant names its failsafe; PX4 v1.16 sends no STATUSTEXT on this link (measured)
    px4, plant = summary["px4"], summary["plant"]
    what = "short mission (take-off 5 m, 3 m/s, waypoint 12 m N, land)"
    parity_finding("mission.short.reached", f"{what}: MISSION_ITEM_REACHED", px4["reached"], plant["reached"])
    parity_finding("mission.short.takeoff_s", f"{what}: take-off item reached (s)", px4["reached s"].get(1), plant["reached s"].get(1))
    parity_finding("mission.short.end_north", f"{what}: lands north of home (m)", px4["end north m"], plant["end north m"])
    parity_finding("mission.short.disarmed_s", f"{what}: arming to disarmed (s)", px4["disarmed s"], plant["disarmed s"])
    # PX4 v1.16 sends no STATUSTEXT on this link: why it flew otherwise is in its console
    # PX4 reaches the take-off (0) and the speed change (1) in one navigator step; its MAVLink mission
    # manager sends MISSION_ITEM_REACHED for the seq_reached it finds when it polls mission_result
    # (mavlink_mission.cpp, MavlinkMissionManager::send()), so it names 0 only when a poll fell between the two
    # publications (one make test run in several): then 0 comes within a tenth of a second of 1
    reached = px4["reached"]
    if reached[:2] == [0, 1]:
        assert px4["reached s"][1] - px4["reached s"][0] <= 0.2, px4["reached s"]
        reached = reached[1:]
    assert reached == [1, 2, 3], f"PX4 modes {flights['px4'].modes}; its console:\n{px4_console_since(vehicles, console_from)}"
    assert plant["reached"] == reached
    assert plant["end north m"] == pytest.approx(px4["end north m"], abs=1.5)
    assert px4["disarmed s"] is not None and plant["disarmed s"] is not None
    # simulation time from arming to disarming after the landing (docs/parity/mission.md): PX4
    # 25.8-32.1 s over thirteen runs (its own spread, +-11 % about 29 s: EKF, land detector), the
    # plant 25.6-26.3 s over five since its take-offs from the ground spool up and ramp as PX4's
    # (before: 16-21.5 s). Against the same run's PX4 the plant was 0.93-0.99 of it; over PX4's
    # whole spread 0.80-1.02, hence +-25 %.
    assert plant["disarmed s"] == pytest.approx(px4["disarmed s"], rel=0.25)
    # the take-off item reached (spool-up, ramp, climb to 5 m): PX4 7.8-9.7 s, the plant 7.8 s
    # (before: 2.9 s, no spool-up or ramp); PX4's lift-off alone varies by 1.5 s (2.7-4.2 s,
    # docs/parity/commander.md), hence +-30 %
    assert plant["reached s"][1] == pytest.approx(px4["reached s"][1], rel=0.3)


def record_until(conn, flight, done, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(blocking=True, timeout=0.1)
        if msg is not None:
            flight.note(msg)
            if done(flight):
                return True
    return False


def here_global(conn) -> tuple[float, int, int]:
    """Home's altitude AMSL (m) and the vehicle's latitude, longitude now (degE7)."""
    msg = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=10)
    assert msg is not None
    return (msg.alt - msg.relative_alt) / 1000.0, msg.lat, msg.lon


def set_param(conn, sysid: int, name: str, value: float) -> float | None:
    for _ in range(3):
        conn.mav.param_set_send(sysid, 1, name.encode(), value, MAV.MAV_PARAM_TYPE_REAL32)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2.0)
        while msg is not None and msg.param_id != name:
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2.0)
        if msg is not None:
            return msg.param_value
    return None


def test_reposition_then_return_climbs_to_rtl_return_alt_and_lands_at_home(vehicles, parity_finding):
    """Take off to 4 m (home is where it armed), DO_REPOSITION 12 m north at 6 m (Hold mode), then
    Return with RTL_RETURN_ALT 10: beyond RTL_MIN_DIST it climbs over the point to 10 m, comes
    home and lands there."""
    from helpers.mission_client import Flight, command

    def fly(conn, sysid):
        assert set_param(conn, sysid, "RTL_RETURN_ALT", 10.0) == 10.0
        home_alt, lat, lon = here_global(conn)
        f = Flight()
        record_until(conn, f, lambda f: len(f.track) > 5, 5.0)
        origin = f.track[-1]
        assert command(conn, sysid, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1, flight=f) == 0
        assert command(conn, sysid, MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, home_alt + 4.0, flight=f) == 0
        assert record_until(conn, f, lambda f: len(f.modes) > 1 and f.modes[-1] == ((4, 3), True) and ((4, 2), True) in f.modes, 30.0), (f.modes, f.texts)
        north = lat * 1e-7 + 12.0 / 111195.0
        assert command(conn, sysid, MAV.MAV_CMD_DO_REPOSITION, -1, 1, 0, math.nan, north, lon * 1e-7, home_alt + 6.0, flight=f) == 0
        there = lambda f: f.track[-1][1] - origin[1] > 11.0  # noqa: E731
        assert record_until(conn, f, there, 30.0), f.track[-1]
        record_until(conn, f, lambda f: False, 0.5)
        at_rtl = len(f.track)
        assert command(conn, sysid, MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH, flight=f) == 0
        assert record_until(conn, f, lambda f: f.disarmed_at_ms is not None and f.track[-1][0] > f.track[at_rtl][0], 60.0), (f.modes, f.texts)
        rtl = f.track[at_rtl:]
        top = min(rtl, key=lambda p: p[3])
        climbed = next(p for p in rtl if p[3] <= top[3] + 0.7)  # where it first came near the return height
        home = (origin[1], origin[2])
        return {
            "reposition north m": round(f.track[at_rtl][1] - origin[1], 1),
            "reposition height m": round(-f.track[at_rtl][3] + origin[3], 1),
            "return height m": round(-top[3] + origin[3], 1),
            "north when at the return height m": round(climbed[1] - origin[1], 1),
            "landed from home m": round(math.hypot(rtl[-1][1] - home[0], rtl[-1][2] - home[1]), 1),
            "return s": round((rtl[-1][0] - rtl[0][0]) / 1000, 1),
            "modes": [m for m, _ in f.modes[-3:]],
        }

    got = on_both(vehicles, fly)
    for name in got:
        print("return", name, got[name])
    px4, plant = got["px4"], got["plant"]
    for key, what in (("reposition north m", "north at the reposition (m)"), ("reposition height m", "height at the reposition (m)"),
                      ("return height m", "Return's top height (m)"), ("north when at the return height m", "north when at "
                      "the return height (m)"), ("landed from home m", "landed from home (m)"), ("return s", "Return to "
                      "disarmed (s)"), ("modes", "the last modes (main, sub)")):  # fmt: skip
        parity_finding(f"mission.return.{key}", f"DO_REPOSITION 12 m N at 6 m, then Return (RTL_RETURN_ALT 10): {what}", px4[key], plant[key])
    assert px4["return height m"] == pytest.approx(10.0, abs=1.0)
    for key in ("reposition north m", "reposition height m", "return height m", "north when at the return height m"):
        assert plant[key] == pytest.approx(px4[key], abs=1.5), key
    assert px4["landed from home m"] < 2.5 and plant["landed from home m"] < 2.5
    assert plant["modes"] == px4["modes"] == [(4, 3), (4, 5), (4, 3)]  # Hold, Return, Hold once disarmed
    # RTL -> disarmed: PX4 25.3-30.5 s over seven runs, and 29.9 and 34.7 s in two `make parity`
    # runs beside other work (load 5-11 on 2 cores: PX4's own time moves by a third with the load);
    # the plant 24.0-26.0 s over seven since the land detector's delay and its legs waiting for a
    # lagging vehicle as PX4's trajectory does (before: 19.3-19.8 s). Against the same run's PX4
    # 0.70-1.03, so the plant may be up to a quarter slower than PX4 and as fast as its loaded
    # runs make it look (0.65): the 0.4-1x of before let a plant twice as fast pass.
    assert 0.65 * px4["return s"] <= plant["return s"] <= 1.25 * px4["return s"], (plant["return s"], px4["return s"])


#: The vehicle PX4 flies (its SIH quadrotor, sitl_plant/vehicles/px4-sih.toml): Orbit's speed
#: depends on its drag, so the orbit comparison flies the plant with it.
PX4_SIH_VEHICLE = REPO / "sitl_plant" / "vehicles" / "px4-sih.toml"
ORBITS = ((5.0, 2.0), (2.0, 3.0))  # radius m, asked speed m/s: the second above sqrt(2 m/s^2 r) = 2 m/s


def fly_orbits(conn, sysid) -> dict:
    """Take off to 6 m; for each of ``ORBITS``, DO_ORBIT around a centre ``r`` north of the vehicle
    (so it starts on the circle), 25 s of vehicle time, then Hold: the ACKs, the mode, and over the
    last 13 s the mean distance from the centre and the mean speed (chords of 0.2-0.5 s)."""
    from helpers.mission_client import Flight, command

    home_alt, lat, lon = here_global(conn)
    f = Flight()
    record_until(conn, f, lambda f: len(f.track) > 5, 5.0)
    origin = f.track[-1]
    assert command(conn, sysid, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1, flight=f) == 0
    assert command(conn, sysid, MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, home_alt + 6.0, flight=f) == 0
    assert record_until(conn, f, lambda f: len(f.modes) > 1 and f.modes[-1] == ((4, 3), True) and ((4, 2), True) in f.modes, 30.0), (f.modes, f.texts)
    out = {}
    for radius, speed in ORBITS:
        here = f.track[-1]
        centre = (here[1] + radius, here[2])
        c_lat = lat * 1e-7 + (centre[0] - origin[1]) / 111195.0
        c_lon = lon * 1e-7 + (centre[1] - origin[2]) / (111195.0 * math.cos(math.radians(lat * 1e-7)))
        f.acks.pop(MAV.MAV_CMD_DO_ORBIT, None)
        ack = command(conn, sysid, MAV.MAV_CMD_DO_ORBIT, radius, speed, 0, math.nan, c_lat, c_lon, home_alt + 6.0, flight=f)
        start = len(f.track)
        assert record_until(conn, f, lambda f: len(f.track) > start + 1 and f.track[-1][0] - f.track[start][0] > 25000, 60.0)
        seg = [p for p in f.track[start:] if p[0] - f.track[start][0] > 12000]
        radii = [math.hypot(p[1] - centre[0], p[2] - centre[1]) for p in seg]
        speeds = [math.hypot(b[1] - a[1], b[2] - a[2]) / ((b[0] - a[0]) / 1000)
                  for a, b in zip(seg, seg[1:]) if 200 <= b[0] - a[0] <= 500]  # fmt: skip
        speeds = speeds or [math.hypot(b[1] - a[1], b[2] - a[2]) / ((b[0] - a[0]) / 1000) for a, b in zip(seg, seg[5:]) if b[0] > a[0]]
        turn = math.atan2(seg[-1][2] - centre[1], seg[-1][1] - centre[0]) - math.atan2(seg[-2][2] - centre[1], seg[-2][1] - centre[0])
        out[(radius, speed)] = {
            "ack": ack, "mode": f.modes[-1],
            "radius m": round(sum(radii) / len(radii), 2),
            "speed m/s": round(sum(speeds) / len(speeds), 2),
            "clockwise": math.sin(turn) > 0,
        }  # fmt: skip
        assert command(conn, sysid, MAV.MAV_CMD_DO_SET_MODE, 1, 4, 3, flight=f) == 0
        record_until(conn, f, lambda f: False, 1.0)
    return out


def test_orbit_flies_px4s_radius_and_speed(vehicles, parity_finding):
    """DO_ORBIT on both (the module's PX4; a plant of its own flying PX4's SIH vehicle): one
    ACCEPTED, Orbit (3, 1), clockwise at the radius, and PX4's speed: FlightTaskOrbit lowers v to
    sqrt(2 m/s^2 r) where v^2 >= 2 r and flies a velocity setpoint (no horizontal position), so the
    SIH vehicle's drag (1 N s/m) leaves it slower than asked. Measured: r 5 m at 2 m/s, PX4 1.37
    m/s, the plant 2.16 before (a moving position target); r 2 m at 3 m/s, PX4 1.22 m/s, the
    plant 4.96 before. PX4's own figures on the tight orbit move with the host's load (--speed 4 on
    2 cores): 1.03-1.25 m/s on circles of 1.52-1.80 m over seven runs (quiet, beside two busy
    processes, inside make test, on CI), the r 5 m orbit 1.32-1.45 m/s; the plant flies 1.27 m/s
    at 1.71-1.75 m and 1.42 m/s at 5.31 m, up to 23 % above PX4's. So the speeds are compared within
    30 %: the plant's offset with PX4's spread, which still tells the asked speed or the sqrt(a r)
    bound (2 m/s) from PX4's drag-limited circle."""
    plant_conn, proc = start_plant("--speed", "4", "--vehicle", str(PX4_SIH_VEHICLE))
    try:
        quiet_streams(plant_conn, 1)
        got = on_both({"px4": vehicles["px4"], "plant": (plant_conn, 1)}, fly_orbits)
    finally:
        stop_process(proc)
        plant_conn.close()
    for name in got:
        print(name, got[name])
    px4, plant = got["px4"], got["plant"]
    for r, v in ORBITS:
        what = f"DO_ORBIT r {r:g} m at {v:g} m/s (the plant flying px4-sih.toml)"
        parity_finding(f"mission.orbit.{r:g}.ack", f"{what}: ACK; mode (main, sub); clockwise",
                       *(f"{o[(r, v)]['ack']}; {o[(r, v)]['mode'][0]}; {o[(r, v)]['clockwise']}" for o in (px4, plant)))  # fmt: skip
        parity_finding(f"mission.orbit.{r:g}.radius", f"{what}: radius flown (m)", px4[(r, v)]["radius m"], plant[(r, v)]["radius m"])
        parity_finding(f"mission.orbit.{r:g}.speed", f"{what}: speed (m/s)", px4[(r, v)]["speed m/s"], plant[(r, v)]["speed m/s"])
    for case in ORBITS:
        for obs in (px4[case], plant[case]):
            assert obs["ack"] == MAV.MAV_RESULT_ACCEPTED and obs["mode"] == ((3, 1), True) and obs["clockwise"], case
        assert plant[case]["radius m"] == pytest.approx(px4[case]["radius m"], abs=0.7), case
        assert plant[case]["speed m/s"] == pytest.approx(px4[case]["speed m/s"], rel=0.3), case
    assert px4[(2.0, 3.0)]["speed m/s"] < 2.0 and plant[(2.0, 3.0)]["speed m/s"] < 2.0  # sqrt(a r) = 2 m/s
