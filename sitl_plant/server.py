"""The plant's loop: clock, simulation, autopilot and links tied together.

``Plant`` holds everything but sockets and clocks: the ``VehicleSim``, the ``Autopilot``, the
inner loops, the parameter table and the telemetry streams. It turns each received message into
replies (``handle``), advances the simulation (``advance``) and says which telemetry is due
(``telemetry``). ``run_realtime`` and ``run_lockstep`` drive a ``Plant`` with a ``Link`` and an
injected clock (``time.monotonic`` by default), so tests can drive them with a fake one.

Time: the simulation advances in whole physics steps; ``time_boot_ms`` in every message is
simulation time. Real time (``speed`` x wall clock) advances in ticks of ``TICK_S``; lockstep
advances one period when the setpoint that echoes the latest telemetry's time arrives
(docs/plant.md, "Lockstep").
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sitl_plant import codec
from sitl_plant.autopilot import (
    ActuatorSetpoint,
    AttitudeSetpoint,
    Autopilot,
    Command,
    ManualInput,
    OffboardTask,
    PositionSetpoint,
    PositionTask,
    Reply,
    Setpoint,
    StatusText,
)
from sitl_plant.codec import Home, Refused, mavlink
from sitl_plant.dynamics.integrate import steps_per_period
from sitl_plant.inner_loops import InnerLoops
from sitl_plant.link import Link
from sitl_plant.params import PHYSICAL, ParamTable, refresh_derived, vehicle_from_params
from sitl_plant.simulation import MODELS, Model, PaperModel, VehicleSim, make_model
from sitl_plant.state import VehicleState
from sitl_plant.vehicle import VehicleParams

TICK_S = 0.004  # real-time granularity: streams up to 250 Hz, setpoints applied within 4 ms
KEEPALIVE_S = 0.25  # lockstep: wall-clock resend of heartbeat and telemetry while nobody answers
LOCKSTEP_EPOCH_S = 1_577_836_800  # 2020-01-01T00:00:00Z: tlog and SYSTEM_TIME origin in lockstep
API, GCS = 0, 1
MAX_DISTANCE_M = 1e7  # beyond this from home the simulation is taken as broken down


def make_sim(model: Model, physics_dt_s: float, wind: object | None) -> VehicleSim:
    """The stepper: for the rigid body, ``FastRigidBodySim`` (the same equations compiled, equal
    to ``VehicleSim`` to 1e-12; the PX4 attitude and rate loops fused into it) when numba is
    installed and its kernels are already compiled in numba's cache (``python -m
    sitl_plant.px4_kernel`` compiles them, ~10 s once; the test suite and the benchmarks do it
    too); else the reference ``VehicleSim``. Compiling here would keep a starting plant silent
    for seconds, longer than a client waits for its first heartbeat."""
    if not isinstance(model, PaperModel):
        from sitl_plant import px4_kernel
        from sitl_plant.dynamics import batch

        if px4_kernel.compiled_ready():
            px4_kernel.compile_all()  # load now, before any link opens: the first period is not late
            return batch.FastRigidBodySim(model, physics_dt_s=physics_dt_s, wind=wind)  # type: ignore[arg-type]
    return VehicleSim(model, physics_dt_s=physics_dt_s, wind=wind)  # type: ignore[arg-type]


# --- telemetry streams ---------------------------------------------------------------------------

#: message id -> (name, default rate Hz on the onboard/API link, on the GCS link); PX4's
#: ``configure_streams_to_default`` for MAVLINK_MODE_ONBOARD and MAVLINK_MODE_NORMAL.
STREAMS: dict[int, tuple[str, float, float]] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: ("HEARTBEAT", 1.0, 1.0),
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: ("SYS_STATUS", 5.0, 1.0),
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: ("SYSTEM_TIME", 1.0, 0.0),
    mavlink.MAVLINK_MSG_ID_ATTITUDE: ("ATTITUDE", 100.0, 15.0),
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: ("ATTITUDE_QUATERNION", 50.0, 10.0),
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: ("LOCAL_POSITION_NED", 30.0, 1.0),
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: ("GLOBAL_POSITION_INT", 50.0, 5.0),
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: ("GPS_RAW_INT", 10.0, 5.0),  # ONBOARD: as the GPS updates (10 Hz)
    mavlink.MAVLINK_MSG_ID_VFR_HUD: ("VFR_HUD", 10.0, 4.0),
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: ("SERVO_OUTPUT_RAW", 10.0, 1.0),
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: ("ATTITUDE_TARGET", 10.0, 2.0),
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: ("HIGHRES_IMU", 50.0, 0.0),
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: ("BATTERY_STATUS", 0.5, 0.5),
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: ("HOME_POSITION", 0.5, 0.5),
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: ("EXTENDED_SYS_STATE", 5.0, 1.0),
}
#: Sent every lockstep period on the API link whatever their interval: the lockstep contract.
LOCKSTEP_STREAMS = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
_STATE_STREAMS = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink.MAVLINK_MSG_ID_VFR_HUD,
}


class StreamSchedule:
    """Per-link message intervals (microseconds) and when each stream is next due."""

    def __init__(self, link_index: int) -> None:
        column = 1 if link_index == API else 2
        self.defaults = {mid: _interval_us(spec[column]) for mid, spec in STREAMS.items()}
        self.interval_us = dict(self.defaults)
        self.next_us = {mid: 0 for mid in STREAMS}

    def set_interval(self, message_id: int, interval_us: int, now_us: int) -> bool:
        """SET_MESSAGE_INTERVAL: -1 off, 0 default, > 0 the interval (the next one is due one
        interval from now); False for unknown streams."""
        if message_id not in STREAMS:
            return False
        if interval_us == 0:
            self.interval_us[message_id] = self.defaults[message_id]
        elif interval_us < 0:
            self.interval_us[message_id] = -1
        else:
            self.interval_us[message_id] = interval_us
        self.next_us[message_id] = now_us + max(self.interval_us[message_id], 0)
        return True

    def due(self, now_us: int) -> list[int]:
        out = []
        for mid, interval in self.interval_us.items():
            if interval <= 0:
                continue
            nxt = self.next_us[mid]
            if now_us >= nxt:
                out.append(mid)
                nxt += interval
                self.next_us[mid] = nxt if nxt > now_us else now_us + interval
        return out


def _interval_us(rate_hz: float) -> int:
    return int(round(1e6 / rate_hz)) if rate_hz > 0 else -1


# --- the plant -----------------------------------------------------------------------------------


@dataclass
class PlantConfig:
    """What the command line chose (see ``sitl-plant --help``)."""

    model: str = "rigid-body"
    inner_loop: str = "px4"
    physics_dt_s: float = 0.001
    lockstep: bool = False
    lockstep_period_s: float = 0.05
    home: Home = field(default_factory=Home)
    sysid: int = 1
    compid: int = mavlink.MAV_COMP_ID_AUTOPILOT1
    start_epoch_s: float = 0.0  # tlog / SYSTEM_TIME origin; LOCKSTEP_EPOCH_S in lockstep


@dataclass
class Counters:
    refused_setpoints: int = 0
    foreign: int = 0
    unhandled: int = 0
    stale_answers: int = 0
    breakdowns: int = 0
    internal_errors: int = 0
    last_error: str = ""
    refusals: dict[str, int] = field(default_factory=dict)


class Plant:
    """The simulated PX4 vehicle without sockets or clocks.

    Parameters
    ----------
    config : PlantConfig
    vehicle : VehicleParams
        The vehicle file's values (``SIM_*`` parameters start from them).
    params : ParamTable
    autopilot : Autopilot
    wind : object with ``velocity_ned(t, pos)``, or None
    sensors : object with ``measure(truth) -> VehicleState``, or None (clean)
    """

    def __init__(
        self,
        config: PlantConfig,
        vehicle: VehicleParams,
        params: ParamTable,
        autopilot: Autopilot,
        *,
        wind: object | None = None,
        sensors: object | None = None,
    ) -> None:
        self.config = config
        self.vehicle = vehicle
        self.params = params
        self.autopilot = autopilot
        self.sensors = sensors
        dt_us = config.physics_dt_s * 1e6
        if abs(dt_us - round(dt_us)) > 1e-6 or round(dt_us) < 1:
            raise ValueError(f"physics step must be a whole number of microseconds, got {config.physics_dt_s} s")
        self.dt_us = int(round(dt_us))
        if not config.lockstep:
            self.tick_steps = max(1, round(TICK_S / config.physics_dt_s))
        else:
            self.tick_steps = steps_per_period(config.lockstep_period_s, config.physics_dt_s)
            period_ms = config.lockstep_period_s * 1e3
            if abs(period_ms - round(period_ms)) > 1e-9:
                raise ValueError(f"the lockstep period must be a whole number of milliseconds, got {config.lockstep_period_s} s")
        model = make_model(config.model, vehicle)
        self.sim = make_sim(model, config.physics_dt_s, wind)
        self.loops = InnerLoops(params, model, config.physics_dt_s, config.inner_loop)
        self.streams = [StreamSchedule(API), StreamSchedule(GCS)]
        self.counters = Counters()
        self.outbox: list[list[mavlink.MAVLink_message]] = [[], []]
        self._statustext_id = 0
        self._heartbeat_status: object = None  # the status the latest heartbeat reported
        self._truth = self.sim.truth()
        self._measured: VehicleState | None = None
        self._rigid = not isinstance(model, PaperModel)
        self._position_index = [0, 1, 2] if self._rigid else [0, 2, 4]
        self.autopilot.observe(self._truth)

    # -- time ------------------------------------------------------------------------------------

    @property
    def time_us(self) -> int:
        return self.sim.steps * self.dt_us

    @property
    def time_ms(self) -> int:
        return self.time_us // 1000

    @property
    def time_s(self) -> float:
        return self.time_us * 1e-6

    def epoch_us(self) -> int:
        """Microseconds since the Unix epoch on the plant's clock (start epoch + sim time)."""
        return int(round(self.config.start_epoch_s * 1e6)) + self.time_us

    # -- advancing -------------------------------------------------------------------------------

    def advance(self, n_steps: int) -> None:
        """Step the physics, then let the autopilot react (failsafe, landing, disarm).

        A simulation that breaks down (non-finite state, a singular model, beyond 10 km) is a
        crash, not a crash of the program: the state goes back to the last good one, the motors
        stop (forced disarm) and a STATUSTEXT says so; time goes on.
        """
        sim = self.sim
        steps_before, x_before = sim.steps, sim.x.copy()
        try:
            with np.errstate(all="ignore"):
                sim.step(n_steps)
            broken = not (np.all(np.isfinite(sim.x)) and np.max(np.abs(self.model_position(sim.x))) < MAX_DISTANCE_M)
        except (ArithmeticError, np.linalg.LinAlgError, ValueError):
            broken = True
        if broken:
            sim.x = x_before
            sim.steps = steps_before + n_steps
            sim.time_s = sim.steps * sim.physics_dt_s
            self.counters.breakdowns += 1
            if self.autopilot.armed or self.counters.breakdowns == 1:
                self._announce(StatusText(mavlink.MAV_SEVERITY_EMERGENCY, "Simulation broke down (state not finite): motors stopped"))
            self.autopilot.disarm(self.time_s, forced=True)
            self.autopilot.failures.add("motor")
        self._truth = self.sim.truth()
        self._measured = None
        ap = self.autopilot
        ap.observe(self._truth)
        for text in ap.update(self.time_s):
            self._announce(text)
        self._apply_task()

    def model_position(self, x: np.ndarray) -> np.ndarray:
        """Position entries of the model's state (either model keeps them first or interleaved)."""
        return x[self._position_index]

    def _apply_task(self) -> None:
        self.sim.actuation = self.loops.actuation_for(self.autopilot.task(), self.sim.x, self.sim.on_ground)  # type: ignore[assignment]

    # -- incoming --------------------------------------------------------------------------------

    def lockstep_stamp_ms(self, msg: mavlink.MAVLink_message) -> float | None:
        """The telemetry time (ms) a setpoint answers, or None for other messages."""
        kind = msg.get_type()
        if kind in ("SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED"):
            return int(msg.time_boot_ms)
        if kind == "SET_ACTUATOR_CONTROL_TARGET":
            return int(msg.time_usec) / 1000.0
        return None

    def lockstep_echo(self, msg: mavlink.MAVLink_message) -> bool:
        """Whether ``msg`` is the lockstep answer to the telemetry stamped now."""
        return self.lockstep_stamp_ms(msg) == self.time_ms

    def lockstep_stale(self, msg: mavlink.MAVLink_message) -> bool:
        """Whether ``msg`` answers telemetry older than now (a repeat after a keepalive resend)."""
        stamp = self.lockstep_stamp_ms(msg)
        return stamp is not None and stamp < self.time_ms

    def handle(self, index: int, msg: mavlink.MAVLink_message) -> None:
        """React to one message from link ``index``; replies go to ``self.outbox``."""
        kind = msg.get_type()
        handler = _HANDLERS.get(kind)
        if handler is None:
            self.counters.unhandled += 1
            return
        if not codec.addressed_to(msg, self.config.sysid, self.config.compid):
            self.counters.foreign += 1
            return
        try:
            handler(self, index, msg)
        except Exception as exc:  # noqa: BLE001 - one bad message must never stop the vehicle
            self.counters.internal_errors += 1
            self.counters.last_error = f"{kind}: {type(exc).__name__}: {exc}"

    def _refuse(self, reason: str) -> None:
        self.counters.refused_setpoints += 1
        key = reason.split(" ")[0] if reason else "refused"
        self.counters.refusals[key] = self.counters.refusals.get(key, 0) + 1

    def _on_attitude_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            sp = codec.decode_attitude_target(msg)
        except Refused as exc:
            self._refuse(str(exc))
            return
        self._on_setpoint(sp)

    def _on_actuator_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            sp = codec.decode_actuator_target(msg)
        except Refused as exc:
            self._refuse(str(exc))
            return
        self._on_setpoint(sp)

    def _on_position_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            sp = codec.decode_position_target(msg)
        except Refused as exc:
            self._refuse(str(exc))
            return
        self._on_setpoint(sp)

    def _on_setpoint(self, sp: Setpoint) -> None:
        if self.autopilot.on_setpoint(sp, self.time_s):
            self._apply_task()

    def _on_command(self, index: int, msg: mavlink.MAVLink_message) -> None:
        cmd = codec.decode_command(msg)
        reply = self._link_command(index, cmd)
        if reply is None:
            reply = self.autopilot.on_command(cmd, self.time_s)
            if reply is not None:
                self._apply_task()
        if reply is None:
            reply = Reply(mavlink.MAV_RESULT_UNSUPPORTED)
        if cmd.command == mavlink.MAV_CMD_DO_SET_MODE:
            # PX4 acknowledges a mode change twice: ACCEPTED from its MAVLink receiver at once, then
            # the commander's result (clients must take the last one)
            self.outbox[index].append(codec.command_ack(cmd.command, mavlink.MAV_RESULT_ACCEPTED, cmd.source_system, cmd.source_component))
        self.outbox[index].append(codec.command_ack(cmd.command, reply.result, cmd.source_system, cmd.source_component))
        for text in reply.texts:
            self._announce(text)
        follow = getattr(reply, "follow_up", None)
        if follow:
            self.outbox[index].extend(follow)

    def _link_command(self, index: int, cmd: Command) -> Reply | None:
        """Commands about the link itself (streams, requested messages); None for the others."""
        c, p = cmd.command, cmd.params
        if c == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not (math.isfinite(p[0]) and math.isfinite(p[1])):
                return Reply(mavlink.MAV_RESULT_DENIED)
            ok = self.streams[index].set_interval(int(p[0]), int(p[1]), self.time_us)
            return Reply(mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED)
        if c == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            if not math.isfinite(p[0]) or int(p[0]) not in STREAMS:
                return Reply(mavlink.MAV_RESULT_DENIED)
            interval = self.streams[index].interval_us[int(p[0])]
            return _FollowedReply(mavlink.MAV_RESULT_ACCEPTED, follow_up=[codec.message_interval(int(p[0]), interval)])
        if c == mavlink.MAV_CMD_REQUEST_MESSAGE:
            message = self._build(int(p[0])) if math.isfinite(p[0]) else None
            if message is None:
                return Reply(mavlink.MAV_RESULT_DENIED)
            return _FollowedReply(mavlink.MAV_RESULT_ACCEPTED, follow_up=[message])
        if c == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return _FollowedReply(mavlink.MAV_RESULT_ACCEPTED, follow_up=[codec.autopilot_version(self.config.sysid)])
        return None

    def _on_set_message_interval(self, index: int, msg: mavlink.MAVLink_message) -> None:
        # the deprecated message form of MAV_CMD_SET_MESSAGE_INTERVAL: no ACK (it has none)
        self.streams[index].set_interval(int(msg.message_id), int(msg.interval_us), self.time_us)

    def _on_set_mode(self, index: int, msg: mavlink.MAVLink_message) -> None:
        reply = self.autopilot.set_mode(codec.decode_set_mode(msg), self.time_s)
        self._apply_task()
        for text in reply.texts:
            self._announce(text)

    def _on_param_request_list(self, index: int, msg: mavlink.MAVLink_message) -> None:
        table = self.params
        self.outbox[index].extend(self._param_value(name) for name in table)

    def _on_param_request_read(self, index: int, msg: mavlink.MAVLink_message) -> None:
        name = self.params.name_at(int(msg.param_index)) if msg.param_index >= 0 else codec.param_name(msg.param_id)
        if name is None or name not in self.params:
            self.counters.unhandled += 1
            return
        self.outbox[index].append(self._param_value(name))

    def _on_param_set(self, index: int, msg: mavlink.MAVLink_message) -> None:
        name = codec.param_name(msg.param_id)
        table = self.params
        if name not in table:
            self._announce(StatusText(mavlink.MAV_SEVERITY_ERROR, f"[pm] unknown param: {name}"))
            return
        value = codec.param_set_value(msg)
        if name in PHYSICAL and self.autopilot.armed:
            self._announce(StatusText(mavlink.MAV_SEVERITY_WARNING, f"{name}: disarm before changing the vehicle"))
        else:
            outcome = table.set(name, value)
            if not outcome.accepted:
                self._announce(StatusText(mavlink.MAV_SEVERITY_WARNING, outcome.reason))
            elif name in PHYSICAL:
                self._rebuild_vehicle()
        # PX4 answers on every link, so ground stations see the change too
        for box in self.outbox:
            box.append(self._param_value(name))

    def _param_value(self, name: str) -> mavlink.MAVLink_message:
        t = self.params
        return codec.param_value(name, t[name], t.spec(name).kind == "int", len(t), t.index(name))

    def _rebuild_vehicle(self) -> None:
        self.vehicle = vehicle_from_params(self.params, self.vehicle)
        refresh_derived(self.params, self.vehicle)
        model = make_model(self.config.model, self.vehicle)
        self.sim.model = model
        self.loops.bind(model)
        self._apply_task()

    def _on_timesync(self, index: int, msg: mavlink.MAVLink_message) -> None:
        if msg.tc1 == 0:
            # tc1 = 0 marks a request, so a reply at simulation time 0 says 1 ns (still deterministic)
            self.outbox[index].append(codec.timesync_reply(max(self.time_us * 1000, 1), msg.ts1))

    def _on_ping(self, index: int, msg: mavlink.MAVLink_message) -> None:
        if msg.target_system == 0 and msg.target_component == 0:
            reply = mavlink.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent())
            self.outbox[index].append(reply)

    def _on_manual_control(self, index: int, msg: mavlink.MAVLink_message) -> None:
        # virtual sticks, as PX4's MAVLink receiver scales them (x, y, r -1000..1000, z 0..1000);
        # NaN-free by the wire format (int16), out-of-range values are clipped by the autopilot
        if int(msg.target) not in (0, self.config.sysid):
            self.counters.foreign += 1
            return
        sticks = ManualInput(msg.x / 1000.0, msg.y / 1000.0, msg.z / 1000.0, msg.r / 1000.0)
        self.autopilot.on_manual_input(sticks, self.time_s)

    def _on_heartbeat(self, index: int, msg: mavlink.MAVLink_message) -> None:
        pass  # a client's presence; nothing to do (the link already learnt its address)

    def _announce(self, text: StatusText) -> None:
        self._statustext_id = self._statustext_id % 65535 + 1
        messages = codec.statustext(text.severity, text.text, self._statustext_id)
        for box in self.outbox:
            box.extend(messages)

    # -- outgoing --------------------------------------------------------------------------------

    def measured(self) -> VehicleState:
        """The sensor model's measurement of the current truth (once per telemetry sample)."""
        if self._measured is None:
            truth = self._truth
            self._measured = truth if self.sensors is None else self.sensors.measure(truth)  # type: ignore[attr-defined]
        return self._measured

    def status_changed(self) -> bool:
        """Whether the vehicle's status (mode, arming, failsafe...) differs from what the latest
        heartbeat said (lockstep: a heartbeat then goes out at once, see ``run_lockstep``)."""
        return self._heartbeat_status is not None and self.autopilot.status() != self._heartbeat_status

    def heartbeat_now(self) -> None:
        """A heartbeat of the current status on every link (in the outbox)."""
        for box in self.outbox:
            box.append(self._build(mavlink.MAVLINK_MSG_ID_HEARTBEAT))  # type: ignore[arg-type]

    def telemetry(self, index: int, *, force: tuple[int, ...] = ()) -> list[mavlink.MAVLink_message]:
        """The streams due now on link ``index`` (plus ``force``d ones), all stamped now."""
        due = self.streams[index].due(self.time_us)
        for mid in force:
            if mid not in due:
                due.append(mid)
        return [m for m in (self._build(mid) for mid in due) if m is not None]

    def _build(self, mid: int) -> mavlink.MAVLink_message | None:
        t_ms, t_us = self.time_ms, self.time_us
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            status = self.autopilot.status()
            self._heartbeat_status = status
            return codec.heartbeat(status)
        if mid in _STATE_STREAMS:
            st = self.measured()
            if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
                return codec.attitude(t_ms, st)
            if mid == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                return codec.local_position_ned(t_ms, st)
            if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
                return codec.attitude_quaternion(t_ms, st)
            if mid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
                return codec.global_position_int(t_ms, st, self.config.home)
            if mid == mavlink.MAVLINK_MSG_ID_GPS_RAW_INT:
                return codec.gps_raw_int(t_us, st, self.config.home, "gps" not in self.autopilot.failures)
            if mid == mavlink.MAVLINK_MSG_ID_VFR_HUD:
                return codec.vfr_hud(st, self.config.home, self._attitude_target()[2])
            return codec.highres_imu(t_us, st, self.config.home, self.vehicle.gravity_m_s2)
        if mid == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            return codec.sys_status(self.autopilot.status(), bad_packets=self.counters.refused_setpoints)
        if mid == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return codec.extended_sys_state(self.autopilot.status())
        if mid == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:
            return codec.system_time(self.epoch_us(), t_ms)
        if mid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            return codec.home_position(t_us, self.config.home, self.autopilot.home_ned_m)
        if mid == mavlink.MAVLINK_MSG_ID_BATTERY_STATUS:
            return codec.battery_status(self.autopilot.status())
        if mid == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
            return codec.servo_output_raw(t_us, self._motor_speeds(), self.vehicle.rotor_speed_max_rad_s, self.autopilot.armed)
        if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET:
            q, rates, thrust = self._attitude_target()
            return codec.attitude_target(t_ms, q, rates, thrust)
        if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return codec.autopilot_version(self.config.sysid)
        return None

    def _motor_speeds(self) -> np.ndarray:
        if self._rigid:
            return self._truth.motor_speeds_rad_s
        from sitl_plant.dynamics.rigid_body import rotor_speeds_for

        thrust, torque = self.loops.last_output(self.sim.x)
        return rotor_speeds_for(thrust, torque, self.vehicle)

    def _attitude_target(self) -> tuple[tuple[float, float, float, float], tuple[float, float, float], float]:
        task = self.autopilot.task()
        thr_max = self.params["SIM_THR_MAX"]
        if isinstance(task, OffboardTask) and isinstance(task.setpoint, AttitudeSetpoint):
            sp = task.setpoint
            q = sp.q_wxyz if sp.q_wxyz is not None else tuple(float(v) for v in self._truth.quat_wxyz)
            rates = tuple(0.0 if r is None else r for r in sp.body_rates_frd_rad_s)
            return q, rates, min(max(sp.thrust_norm or 0.0, 0.0), 1.0)  # type: ignore[return-value]
        if isinstance(task, OffboardTask) and isinstance(task.setpoint, ActuatorSetpoint):
            return tuple(float(v) for v in self._truth.quat_wxyz), (0.0, 0.0, 0.0), task.setpoint.controls[3]  # type: ignore[return-value]
        if isinstance(task, PositionTask) or (isinstance(task, OffboardTask) and isinstance(task.setpoint, PositionSetpoint)):
            px4 = self.loops.px4
            return px4._q_sp, (0.0, 0.0, 0.0), px4._thrust_n / thr_max
        return tuple(float(v) for v in self._truth.quat_wxyz), (0.0, 0.0, 0.0), 0.0  # type: ignore[return-value]

    def status_line(self) -> str:
        st = self.autopilot.status()
        p = self._truth.pos_ned_m
        arm = "ARMED" if st.armed else "disarmed"
        fs = " FAILSAFE" if st.failsafe else ""
        return f"t={self.time_s:8.2f}s {st.mode.label:<8} {arm:<8}{fs} N={p[0]:7.2f} E={p[1]:7.2f} D={p[2]:7.2f}"


_HANDLERS: dict[str, Callable[[Plant, int, mavlink.MAVLink_message], None]] = {
    "SET_ATTITUDE_TARGET": Plant._on_attitude_target,
    "SET_ACTUATOR_CONTROL_TARGET": Plant._on_actuator_target,
    "SET_POSITION_TARGET_LOCAL_NED": Plant._on_position_target,
    "COMMAND_LONG": Plant._on_command,
    "COMMAND_INT": Plant._on_command,
    "SET_MODE": Plant._on_set_mode,
    "SET_MESSAGE_INTERVAL": Plant._on_set_message_interval,
    "PARAM_REQUEST_LIST": Plant._on_param_request_list,
    "PARAM_REQUEST_READ": Plant._on_param_request_read,
    "PARAM_SET": Plant._on_param_set,
    "TIMESYNC": Plant._on_timesync,
    "PING": Plant._on_ping,
    "HEARTBEAT": Plant._on_heartbeat,
    "MANUAL_CONTROL": Plant._on_manual_control,
}


@dataclass(frozen=True)
class _FollowedReply(Reply):
    """A reply whose ACK is followed by messages (a requested message, MESSAGE_INTERVAL)."""

    follow_up: list = field(default_factory=list)


# --- the loops -----------------------------------------------------------------------------------


@dataclass
class RunStats:
    """What a run did (printed at exit)."""

    periods: int = 0
    overruns: int = 0
    wall_s: float = 0.0
    sim_s: float = 0.0


class _Driver:
    """Shared plumbing of the two loops: dispatch, outbox flushing, status line, tlog flushing."""

    def __init__(self, plant: Plant, link: Link, clock: Callable[[], float], status: Callable[[str], None] | None) -> None:
        self.plant = plant
        self.link = link
        self.clock = clock
        self.status = status
        self._next_status = clock()
        self._next_flush = clock() + 1.0

    def flush_outbox(self) -> None:
        for i, box in enumerate(self.plant.outbox):
            if box:
                if i < len(self.link.endpoints):
                    self.link.send(i, box)
                box.clear()

    def send_telemetry(self, *, lockstep: bool = False) -> None:
        """Replies first, then the due streams (in lockstep the streams are also kept for the
        keepalive, which repeats them byte for byte, and carry a heartbeat whenever the status
        changed since the last one, so that what the keepalive repeats is current)."""
        self.flush_outbox()
        plant = self.plant
        changed = lockstep and plant.status_changed()
        for i in range(len(self.link.endpoints)):
            force = LOCKSTEP_STREAMS if (lockstep and i == API) else ()
            if changed:
                force = (*force, mavlink.MAVLINK_MSG_ID_HEARTBEAT)
            msgs = plant.telemetry(i, force=force)
            self.link.send(i, msgs, remember="telemetry" if lockstep else None)

    def keepalive(self) -> None:
        """Lockstep, nobody answering: the latest telemetry and heartbeat again, byte for byte."""
        self.link.resend_remembered()
        for i in range(len(self.link.endpoints)):
            self.link.send_keepalive(i, [mavlink.MAVLINK_MSG_ID_HEARTBEAT])

    def housekeeping(self) -> None:
        now = self.clock()
        if self.status is not None and now >= self._next_status:
            self.status(self.plant.status_line())
            self._next_status = now + 0.5
        if now >= self._next_flush:
            self.link.flush()
            self._next_flush = now + 1.0


def run_realtime(
    plant: Plant,
    link: Link,
    *,
    speed: float = 1.0,
    stop: Callable[[], bool],
    clock: Callable[[], float] = time.monotonic,
    status: Callable[[str], None] | None = None,
    max_sim_s: float | None = None,
) -> RunStats:
    """Run at ``speed`` times the wall clock until ``stop()`` (or ``max_sim_s`` of sim time).

    Each tick (``TICK_S`` of simulation time): receive and handle messages, advance the physics,
    send the streams that are due. When the computer cannot keep up, the simulation runs as fast
    as it can and the lag is dropped once it exceeds half a second (counted as an overrun).
    """
    d = _Driver(plant, link, clock, status)
    stats = RunStats()
    tick_steps = plant.tick_steps
    tick_us = tick_steps * plant.dt_us
    start = clock()
    d.send_telemetry()
    wall0, sim0 = clock(), plant.time_us
    while not stop():
        if max_sim_s is not None and plant.time_s >= max_sim_s:
            break
        target_us = sim0 + (clock() - wall0) * speed * 1e6
        lag_us = target_us - plant.time_us
        if lag_us >= tick_us:
            _dispatch(d, link.receive())
            plant.advance(tick_steps)
            stats.periods += 1
            d.send_telemetry()
            if lag_us > 0.5e6 * speed + tick_us:
                stats.overruns += 1
                wall0, sim0 = clock(), plant.time_us
        else:
            if link.wait((tick_us - lag_us) / (1e6 * speed)):
                _dispatch(d, link.receive())
                d.flush_outbox()
        d.housekeeping()
    stats.wall_s = clock() - start
    stats.sim_s = plant.time_s
    return stats


def run_lockstep(
    plant: Plant,
    link: Link,
    *,
    stop: Callable[[], bool],
    clock: Callable[[], float] = time.monotonic,
    status: Callable[[str], None] | None = None,
    keepalive_s: float = KEEPALIVE_S,
    max_sim_s: float | None = None,
) -> RunStats:
    """Advance one period each time the setpoint echoing the latest telemetry's stamp arrives.

    Other messages are handled at once, without advancing. While nobody answers, the last
    telemetry and a current heartbeat are sent every ``keepalive_s`` of wall time (not logged;
    answers to older telemetry are dropped unlogged, so a client may answer every repeat).
    """
    d = _Driver(plant, link, clock, status)
    stats = RunStats()
    steps = plant.tick_steps
    wall0 = clock()
    d.send_telemetry(lockstep=True)
    last_send = clock()
    while not stop():
        if max_sim_s is not None and plant.time_s >= max_sim_s:
            break
        now = clock()
        if link.wait(min(0.05, max(0.0, last_send + keepalive_s - now))):
            for index, msg in link.receive():
                if index == API and plant.lockstep_stale(msg):
                    plant.counters.stale_answers += 1  # a repeated answer: dropped, not logged
                    continue
                link.log_received(msg)
                echo = index == API and plant.lockstep_echo(msg)
                plant.handle(index, msg)
                if echo:
                    plant.advance(steps)
                    stats.periods += 1
                    d.send_telemetry(lockstep=True)
                    last_send = clock()
                else:
                    if plant.status_changed():  # a command changed it while time stands still
                        plant.heartbeat_now()
                    d.flush_outbox()
        elif clock() - last_send >= keepalive_s:
            d.keepalive()
            last_send = clock()
        d.housekeeping()
    stats.wall_s = clock() - wall0
    stats.sim_s = plant.time_s
    return stats


def _dispatch(d: _Driver, received: list[tuple[int, mavlink.MAVLink_message]]) -> None:
    for index, msg in received:
        d.link.log_received(msg)
        d.plant.handle(index, msg)
