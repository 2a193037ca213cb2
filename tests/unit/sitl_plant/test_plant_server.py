"""The plant's loops with an injected clock and a fake link: pacing, lockstep, keepalive — no
sockets and no sleeping (the fake link's ``wait`` moves the fake clock)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_plant.autopilot import Autopilot
from sitl_plant.params import plant_params
from sitl_plant.server import API, CATCH_UP_SIM_S, KEEPALIVE_S, TICK_S, Plant, PlantConfig, StreamSchedule, run_lockstep, run_realtime
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle
from helpers import FakeClock

_SENDER = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
_PARSER = mavlink.MAVLink(None)


def wire(msg):
    return _PARSER.parse_buffer(msg.pack(_SENDER))[0]


class FakeEndpoint:
    def __init__(self) -> None:
        self.remembered: dict[str, list[bytes]] = {}


class FakeLink:
    """Records what is sent; ``script(plant)`` decides what arrives; ``wait`` advances the clock."""

    def __init__(self, clock: FakeClock, script=None) -> None:
        self.clock = clock
        self.endpoints = [FakeEndpoint()]
        self.tlog = None
        self.sent: list[tuple[float, list]] = []
        self.keepalives = 0
        self.resends = 0
        self.inbox: list = []
        self.script = script

    def wait(self, timeout_s: float) -> bool:
        if self.inbox:
            return True
        self.clock.now += max(timeout_s, 1e-4)
        return bool(self.inbox)

    def receive(self):
        out, self.inbox = [(API, m) for m in self.inbox], []
        return out

    def log_received(self, msg) -> None:
        pass

    def send(self, index, messages, *, remember=None) -> None:
        if messages:
            self.sent.append((self.clock.now, list(messages)))
            if self.script is not None:
                self.script(self, messages)

    def resend_remembered(self) -> None:
        self.resends += 1

    def send_keepalive(self, index, messages) -> None:
        self.keepalives += 1

    def flush(self) -> None:
        pass


def make_plant(lockstep: bool, period_s: float = 0.05) -> Plant:
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    params = plant_params(vehicle)
    config = PlantConfig(model="paper", lockstep=lockstep, lockstep_period_s=period_s)
    return Plant(config, vehicle, params, Autopilot(params))


def test_real_time_runs_at_the_requested_speed():
    clock = FakeClock()
    plant = make_plant(lockstep=False)
    link = FakeLink(clock)
    start = clock.now
    stats = run_realtime(plant, link, speed=2.0, stop=lambda: clock.now - start >= 1.0, clock=clock)  # type: ignore[arg-type]
    assert plant.time_s == pytest.approx(2.0, abs=0.01)
    assert stats.overruns == 0 and stats.periods == pytest.approx(2.0 / 0.004, abs=3)
    # the heartbeat goes out once a second of simulation time
    beats = [t for t, msgs in link.sent for m in msgs if m.get_type() == "HEARTBEAT"]
    assert len(beats) == 2 or len(beats) == 3


def test_real_time_drops_lag_when_it_cannot_keep_up():
    clock = FakeClock()
    plant = make_plant(lockstep=False)
    link = FakeLink(clock)
    start = clock.now
    real_advance = plant.advance

    def slow_advance(n: int) -> None:
        clock.now += 0.01  # a 4 ms tick that takes 10 ms of wall time
        real_advance(n)

    plant.advance = slow_advance  # type: ignore[method-assign]
    stats = run_realtime(plant, link, speed=1.0, stop=lambda: clock.now - start >= 3.0, clock=clock)  # type: ignore[arg-type]
    assert stats.overruns >= 1
    assert plant.time_s == pytest.approx(3.0 * 0.4, abs=0.05)  # as fast as it can: 0.4x


def test_a_stalled_real_time_plant_slips_instead_of_running_a_burst():
    """At --speed 4, a stall of half a second of the wall clock (the process starved): afterwards
    the plant runs at most CATCH_UP_SIM_S of its time at once, then paces itself again (it ran
    the whole 2 s it was behind as fast as it could, 0.7 s of it in 50 ms of wall once)."""
    clock = FakeClock()
    plant = make_plant(lockstep=False)
    link = FakeLink(clock)
    start = clock.now
    real_advance = plant.advance
    burst: list[float] = []  # the plant's time at each tick run without the wall clock moving

    def advance(n: int) -> None:
        if clock.now - start >= 1.0 and not burst:
            clock.now += 0.5  # stalled for half a second, once
        real_advance(n)
        if clock.now - start >= 1.5:
            burst.append(clock.now)

    plant.advance = advance  # type: ignore[method-assign]
    stats = run_realtime(plant, link, speed=4.0, stop=lambda: clock.now - start >= 2.0, clock=clock)  # type: ignore[arg-type]
    at_once = max(burst.count(t) for t in set(burst))  # ticks run at one instant of the wall clock
    assert at_once * TICK_S <= CATCH_UP_SIM_S + 2 * TICK_S
    assert stats.overruns == 1
    assert plant.time_s == pytest.approx(4.0 * 1.5, abs=CATCH_UP_SIM_S + 0.02)  # the half second of wall slipped


def test_lockstep_advances_one_period_per_echo_and_drops_stale_answers():
    clock = FakeClock()
    plant = make_plant(lockstep=True)
    answered: list[int] = []

    def client(link: FakeLink, messages: list) -> None:
        stamps = {m.time_boot_ms for m in messages if m.get_type() == "LOCAL_POSITION_NED"}
        for t in stamps:
            answered.append(t)
            sp = mavlink.MAVLink_set_attitude_target_message(t, 1, 1, 0b11000111, (1, 0, 0, 0), 0, 0, 0, 0)
            link.inbox.append(wire(sp))
            if t == 500:  # a late repeat of an old answer: dropped, time does not move
                link.inbox.append(wire(mavlink.MAVLink_set_attitude_target_message(450, 1, 1, 0b11000111, (1, 0, 0, 0), 0, 0, 0, 0)))

    link = FakeLink(clock, client)
    stats = run_lockstep(plant, link, stop=lambda: plant.time_ms >= 1000, clock=clock)  # type: ignore[arg-type]
    assert answered == list(range(0, 1001, 50))[: len(answered)] and plant.time_ms == 1000
    assert stats.periods == 20
    assert plant.counters.stale_answers == 1
    assert link.keepalives == 0  # the client always answered: no keepalive needed


def test_lockstep_keepalive_while_nobody_answers():
    clock = FakeClock()
    plant = make_plant(lockstep=True)
    link = FakeLink(clock)
    start = clock.now
    run_lockstep(plant, link, stop=lambda: clock.now - start >= 1.0, clock=clock)  # type: ignore[arg-type]
    assert plant.time_ms == 0  # time stands still without answers
    assert link.resends == link.keepalives == pytest.approx(1.0 / KEEPALIVE_S, abs=1)


def test_lockstep_forces_attitude_and_position_every_period():
    plant = make_plant(lockstep=True, period_s=0.05)
    for _ in range(3):
        plant.advance(plant.tick_steps)
        kinds = {m.get_type() for m in plant.telemetry(API, force=(30, 32))}
        assert {"ATTITUDE", "LOCAL_POSITION_NED"} <= kinds


def test_stream_schedule_intervals():
    s = StreamSchedule(API)
    att = mavlink.MAVLINK_MSG_ID_ATTITUDE
    assert s.interval_us[att] == 10000 and s.interval_us[mavlink.MAVLINK_MSG_ID_HIGHRES_IMU] == 20000
    sent = sum(att in s.due(t) for t in range(0, 1_000_000, 4000))
    assert sent == 100
    assert s.set_interval(att, 100_000, 1_000_000)
    assert sum(att in s.due(t) for t in range(1_000_000, 2_000_001, 4000)) == 10
    assert s.set_interval(att, -1, 0) and att not in s.due(5_000_000)
    assert not s.set_interval(12345, 1000, 0)


def test_a_broken_down_simulation_stops_the_motors_not_the_program():
    import math

    import numpy as np

    plant = make_plant(lockstep=True)
    plant.autopilot.arm(0.0, forced=True)
    plant.sim.x[4] = 10.0  # 10 m up
    before = plant.sim.x.copy()
    model = plant.sim.model

    def overflowing(x, thrust, torque, wind):  # a dynamics that blows up, as a tilt past 90 deg would
        return np.full_like(x, math.inf)

    model.derivative = overflowing  # type: ignore[method-assign]
    t0 = plant.time_ms
    plant.advance(plant.tick_steps)
    assert plant.time_ms == t0 + 50
    np.testing.assert_array_equal(plant.sim.x, before)
    assert plant.counters.breakdowns >= 1 and not plant.autopilot.armed
    texts = [m.text for m in plant.outbox[API] if m.get_type() == "STATUSTEXT"]
    assert any("broke down" in t for t in texts)
    assert all(m.pack(_SENDER) for m in plant.telemetry(API, force=(30, 32)))


def test_a_message_that_raises_is_counted_not_fatal(monkeypatch):
    from sitl_plant import server

    plant = make_plant(lockstep=True)

    def explode(self, index, msg):
        raise RuntimeError("boom")

    monkeypatch.setitem(server._HANDLERS, "PING", explode)
    plant.handle(API, wire(mavlink.MAVLink_ping_message(1, 2, 0, 0)))
    assert plant.counters.internal_errors == 1 and "boom" in plant.counters.last_error
