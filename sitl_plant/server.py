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
from pathlib import Path

import numpy as np

from offboard.model.state import VehicleState
from offboard.model.vehicle import VehicleParams
from offboard.signing import SigningKey
from sitl_plant import calibration, codec, shell
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
    Status,
    StatusText,
)
from sitl_plant.codec import Home, Refused, mavlink
from sitl_plant.dynamics.integrate import steps_per_period
from sitl_plant.dynamics.rigid_body import rotor_speeds_for
from sitl_plant.dynamics.sensors import DeadReckoning, SensorModel
from sitl_plant.dynamics.wind import WindField
from sitl_plant.ftp import FtpFormatError, FtpServer
from sitl_plant.inner_loops import InnerLoops
from sitl_plant.link import Link
from sitl_plant.logserve import LogServer
from sitl_plant.mission import MissionManager, Reporter
from sitl_plant.navigator import DEFAULT_ORBIT_RADIUS_M, DEFAULT_ORBIT_SPEED_M_S
from sitl_plant.params import PHYSICAL, ParamTable, refresh_derived, vehicle_from_params
from sitl_plant.simulation import Model, PaperModel, VehicleSim, make_model

TICK_S = 0.004  # real-time granularity: streams up to 250 Hz, setpoints applied within 4 ms
KEEPALIVE_S = 0.25  # lockstep: wall-clock resend of heartbeat and telemetry while nobody answers
#: Real time: how much simulation time a plant that fell behind the wall clock runs at once to
#: catch up (s); a longer lag is dropped and the simulation's clock slips (an overrun). PX4 SIH's
#: lockstep loop never catches up (sih.cpp: each period sleeps what is left of it, or not at all). Half a second of the
#: wall clock, as here before, was two seconds of the vehicle's at --speed 4: a starved plant ran
#: 0.7 s of its time in 50 ms of the wall's once, which no client sampling at 20 Hz can follow;
#: 0.1 s is two of its samples at any speed.
CATCH_UP_SIM_S = 0.1
API, GCS = 0, 1
MAX_DISTANCE_M = 1e7  # beyond this from home the simulation is taken as broken down


def make_sim(model: Model, physics_dt_s: float, wind: WindField | None) -> VehicleSim:
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
    return VehicleSim(model, physics_dt_s=physics_dt_s, wind=wind)


# --- telemetry streams ---------------------------------------------------------------------------

#: message id -> (name, default rate Hz on the onboard/API link, on the GCS link), 0 = off: PX4
#: v1.16 SITL's, ``configure_streams_to_default`` (mavlink_main.cpp) for MAVLINK_MODE_ONBOARD (API)
#: and MAVLINK_MODE_NORMAL (GCS), with the GCS link's ``mavlink stream -r 50`` of px4-rc.mavlink
#: (attitude, positions, targets, servo outputs at 50 Hz). Measured on PX4 v1.16 SITL (SIH),
#: docs/parity/wire.md: the same set, each at ~75-90 % of these rates (its loop's granularity).
#: GPS_RAW_INT is "unlimited" on ONBOARD: sent as SIH's GPS updates, 8 Hz. TIME_ESTIMATE_TO_TARGET
#: and CURRENT_MODE go out as their topics update (measured ~0.5 Hz on both links).
STREAMS: dict[int, tuple[str, float, float]] = dict(sorted({
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: ("HEARTBEAT", 1.0, 1.0),
    8: ("LINK_NODE_STATUS", 1.0, 1.0),  # PX4's development dialect
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: ("SYS_STATUS", 5.0, 1.0),
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: ("SYSTEM_TIME", 1.0, 0.0),
    mavlink.MAVLINK_MSG_ID_PING: ("PING", 1.0, 0.1),
    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE: ("SCALED_PRESSURE", 1.0, 1.0),
    mavlink.MAVLINK_MSG_ID_ATTITUDE: ("ATTITUDE", 100.0, 50.0),
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: ("ATTITUDE_QUATERNION", 50.0, 50.0),
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: ("LOCAL_POSITION_NED", 30.0, 50.0),
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: ("GLOBAL_POSITION_INT", 50.0, 50.0),
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: ("GPS_RAW_INT", 8.0, 5.0),
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: ("SERVO_OUTPUT_RAW", 10.0, 50.0),
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: ("MISSION_CURRENT", 1.0, 1.0),
    mavlink.MAVLINK_MSG_ID_VFR_HUD: ("VFR_HUD", 10.0, 4.0),
    mavlink.MAVLINK_MSG_ID_TIMESYNC: ("TIMESYNC", 10.0, 0.0),  # PX4's own requests (tc1 = 0)
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: ("POSITION_TARGET_LOCAL_NED", 10.0, 50.0),
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: ("ATTITUDE_TARGET", 10.0, 50.0),
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: ("HIGHRES_IMU", 50.0, 0.0),
    mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: ("DISTANCE_SENSOR", 10.0, 0.5),
    mavlink.MAVLINK_MSG_ID_ALTITUDE: ("ALTITUDE", 10.0, 1.0),
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: ("BATTERY_STATUS", 0.5, 0.5),
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: ("ESTIMATOR_STATUS", 1.0, 0.5),
    mavlink.MAVLINK_MSG_ID_VIBRATION: ("VIBRATION", 0.5, 0.1),
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: ("HOME_POSITION", 0.5, 0.5),
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: ("EXTENDED_SYS_STATE", 5.0, 1.0),
    mavlink.MAVLINK_MSG_ID_ODOMETRY: ("ODOMETRY", 30.0, 0.0),
    380: ("TIME_ESTIMATE_TO_TARGET", 0.5, 0.5),  # PX4's development dialect
    436: ("CURRENT_MODE", 0.5, 0.5),  # development.xml
    mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_LOCATION: ("OPEN_DRONE_ID_LOCATION", 1.0, 1.0),
    mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_SYSTEM: ("OPEN_DRONE_ID_SYSTEM", 1.0, 1.0),
    # the simulator's truth, on request only (SET_MESSAGE_INTERVAL), as PX4 SITL
    mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION: ("HIL_STATE_QUATERNION", 0.0, 0.0),
}.items()))
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
    mavlink.MAVLINK_MSG_ID_ODOMETRY,
    mavlink.MAVLINK_MSG_ID_ALTITUDE,
    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE,
    mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_LOCATION,
}


class StreamSchedule:
    """Per-link message intervals (microseconds) and when each stream is next due."""

    def __init__(self, link_index: int) -> None:
        self.defaults = {mid: _interval_us(api_hz if link_index == API else gcs_hz) for mid, (_, api_hz, gcs_hz) in STREAMS.items()}
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
        """The streams due at ``now_us``, each then scheduled one interval on (from now, when it fell behind)."""
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
    start_epoch_s: float = 0.0  # tlog / SYSTEM_TIME origin; offboard.model.tlog.LOCKSTEP_EPOCH_S in lockstep
    log_path: Path | None = None  # the tlog (--log), served by log download
    ftp_root: Path | None = None  # the folder MAVLink FTP serves, read-only (--ftp-root)
    #: whether the links sign (--signing-key): without, SETUP_SIGNING is ignored, as PX4 v1.16
    #: (which has no signing) ignores it
    signing: bool = False
    seed: int = 0  # --seed: what the plant draws at random (a lost GPS's dead-reckoning error)


#: A setpoint stamped this little before the newest of its sender is a reordered or duplicated
#: datagram (refused); farther behind, the sender's clock restarted (taken).
REORDER_WINDOW_MS = 1000


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
    #: messages taken but ignored, by type, as PX4 v1.16 ignores them (SETUP_SIGNING without signing)
    ignored: dict[str, int] = field(default_factory=dict)
    statustexts_in: int = 0


class Plant:
    """The simulated PX4 vehicle without sockets or clocks.

    Parameters
    ----------
    config : PlantConfig
    vehicle : VehicleParams
        The vehicle file's values (``SIM_*`` parameters start from them).
    params : ParamTable
    autopilot : Autopilot
    wind : WindField or None
        The air's velocity (``velocity_ned(t, pos)``); None: calm.
    sensors : SensorModel or None
        What the estimate is made of (``measure(truth) -> VehicleState``); None: the truth.
    """

    def __init__(
        self,
        config: PlantConfig,
        vehicle: VehicleParams,
        params: ParamTable,
        autopilot: Autopilot,
        *,
        wind: WindField | None = None,
        sensors: SensorModel | None = None,
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
        self._ping_seq = 0
        self.outbox: list[list[mavlink.MAVLink_message]] = [[], []]
        self._newest_setpoint_ms: dict[tuple[int, int], int] = {}  # per sender (system, component)
        #: a SETUP_SIGNING key accepted, for the loop to apply to the links (then None)
        self.signing_change: SigningKey | None = None
        #: whether the links sign now (from --signing-key; off once SETUP_SIGNING switched it off)
        self.signing = config.signing
        # PX4's services, one of each per link as PX4 has per MAVLink instance (docs/parity/services.md)
        self.ftp = [FtpServer(config.ftp_root), FtpServer(config.ftp_root)]
        self.logs = [LogServer(config.log_path), LogServer(config.log_path)]
        self.shells = [shell.Shell(params, lambda: codec.PX4_FLIGHT_SW_VERSION) for _ in range(2)]
        self._statustext_id = 0
        self._heartbeat_status: Status | None = None  # the status the latest heartbeat reported
        self._truth = self.sim.truth()
        self._measured: VehicleState | None = None
        #: the estimate's error while the GPS is lost (None: it is not), drawn as it is lost
        self._dead_reckoning: DeadReckoning | None = None
        self._rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x6A5]))  # --seed's own stream here (tag 0x6A5)
        self._rigid = not isinstance(model, PaperModel)
        self._position_index = [0, 1, 2] if self._rigid else [0, 2, 4]  # either model keeps them first or interleaved
        self.autopilot.observe(self._truth)
        self.missions = MissionManager()
        self.autopilot.set_origin(config.home.lat_deg, config.home.lon_deg, config.home.alt_m)
        self._mission_reports = Reporter()
        self._mission_streams: list[list[mavlink.MAVLink_message]] = [[], []]  # go out with the telemetry
        #: the latest SET_ATTITUDE_TARGET taken, and its quaternion as it came (ATTITUDE_TARGET echoes it)
        self._sent_attitude: tuple[Setpoint | None, tuple[float, ...]] = (None, ())

    # -- time ------------------------------------------------------------------------------------

    @property
    def time_us(self) -> int:
        """Simulation time, microseconds: whole physics steps."""
        return self.sim.steps * self.dt_us

    @property
    def time_ms(self) -> int:
        """Simulation time, whole milliseconds (the streams' time_boot_ms)."""
        return self.time_us // 1000

    @property
    def time_s(self) -> float:
        """Simulation time, s."""
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
            broken = not self._sound(sim.x)
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
            self.autopilot.inject_failure("motor", self.time_s)
        self._truth = self.sim.truth()
        self._measured = None
        self._dead_reckon(n_steps * self.dt_us * 1e-6)
        ap = self.autopilot
        ap.observe(self._truth)
        for text in ap.update(self.time_s):
            self._announce(text)
        self._mission_tick()
        self._apply_task()

    def _dead_reckon(self, period_s: float) -> None:
        """The estimate's error while the GPS is lost, over the period just flown (from the loss
        when it came within it); the GPS back, EKF2 resets its position to it."""
        lost_s = self.autopilot.gps_lost_s(self.time_s)
        if lost_s is None:
            self._dead_reckoning = None
            return
        if self._dead_reckoning is None:
            self._dead_reckoning = DeadReckoning.drawn(self.params["SIM_DR_ACC_ERR"], self._rng)
        self._dead_reckoning.advance(min(lost_s, period_s))

    def _sound(self, x: np.ndarray) -> bool:
        """Whether a state is one the simulation goes on from: every entry finite and the position
        within ``MAX_DISTANCE_M`` of home. On plain floats: numpy's reductions over these 17
        numbers took 10 us of every lockstep period."""
        values = x.tolist()
        return all(map(math.isfinite, values)) and max(abs(values[i]) for i in self._position_index) < MAX_DISTANCE_M

    def _apply_task(self) -> None:
        self.sim.actuation = self.loops.actuation_for(self.autopilot.task(), self.sim.x, self.sim.on_ground)

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
        if kind not in _MISSION_MESSAGES and not codec.addressed_to(msg, self.config.sysid, self.config.compid):
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

    def _out_of_order(self, msg: mavlink.MAVLink_message, stamp_ms: int) -> bool:
        """A setpoint stamped before the newest one flown from its sender, by less than
        ``REORDER_WINDOW_MS``: a duplicated or reordered datagram, refused (issue 14: a link that
        reorders made the plant fly 103 setpoints older than the one before). A stamp far behind
        is a sender whose clock restarted (a new offboard process), and is taken."""
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        newest = self._newest_setpoint_ms.get(sender)
        if newest is not None and 0 < newest - stamp_ms <= REORDER_WINDOW_MS:
            self._refuse("out-of-order setpoint")
            return True
        self._newest_setpoint_ms[sender] = stamp_ms
        return False

    def _on_attitude_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            sp = codec.decode_attitude_target(msg)
        except Refused as exc:
            self._refuse(str(exc))
            return
        if not self._out_of_order(msg, int(msg.time_boot_ms)):
            self._sent_attitude = (sp, tuple(float(v) for v in msg.q))  # as sent, for the ATTITUDE_TARGET echo
            self._on_setpoint(sp)

    def _on_actuator_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            sp = codec.decode_actuator_target(msg)
        except Refused as exc:
            self._refuse(str(exc))
            return
        if not self._out_of_order(msg, int(msg.time_usec) // 1000):
            self._on_setpoint(sp)

    def _on_position_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            sp = codec.decode_position_target(msg, yaw_rad=float(self._truth.euler_rad[2]))
        except Refused as exc:
            self._refuse(str(exc))
            return
        if not self._out_of_order(msg, int(msg.time_boot_ms)):
            self._on_setpoint(sp)

    def _on_setpoint(self, sp: Setpoint) -> None:
        if self.autopilot.on_setpoint(sp, self.time_s):
            self._apply_task()

    def _on_command(self, index: int, msg: mavlink.MAVLink_message) -> None:
        cmd = codec.decode_command(msg)
        reply = self._link_command(index, cmd)
        if reply is None:
            reply = self._nav_command(msg, cmd)
            if reply is not None:
                self._apply_task()
        if reply is None:
            reply = self.autopilot.on_command(cmd, self.time_s)
            if reply is not None:
                self._apply_task()
        if reply is None:
            reply = Reply(mavlink.MAV_RESULT_UNSUPPORTED)
        if cmd.command == mavlink.MAV_CMD_DO_SET_MODE:
            # PX4 acknowledges a mode change twice: ACCEPTED from its MAVLink receiver, then the
            # commander's result (mostly in that order: a loaded PX4 has sent the commander's
            # first, so a client takes a refusal in either)
            self.outbox[index].append(codec.command_ack(cmd.command, mavlink.MAV_RESULT_ACCEPTED, cmd.source_system, cmd.source_component))
        self.outbox[index].append(codec.command_ack(cmd.command, reply.result, cmd.source_system, cmd.source_component))
        for text in reply.texts:
            self._announce(text)
        follow = getattr(reply, "follow_up", None)
        if follow:
            self.outbox[index].extend(follow)

    # -- the mission protocol and the navigation commands (sitl_plant/mission.py, navigator.py) --

    def _on_mission(self, index: int, msg: mavlink.MAVLink_message) -> None:
        """MISSION_* messages, addressed as PX4 checks them (our system; our component, the
        mission planner's or 0)."""
        if not MissionManager.addressed_to_us(msg, self.config.sysid, self.config.compid):
            self.counters.foreign += 1
            return
        self._send_mission(index, self.missions.handle(msg, self.time_s, index))
        nav = self.autopilot.navigator
        if self.missions.changed:
            self.missions.changed = False
            nav.load(self.missions.mission, self.missions.current_seq)
        elif msg.get_type() == "MISSION_SET_CURRENT" and self.missions.current_seq != nav.current_seq:
            nav.set_current(self.missions.current_seq)
        self._mission_tick(force=True)

    def _send_mission(self, index: int, outs: list) -> None:
        for out in outs:
            if out.kind == "STATUSTEXT":
                self._announce(StatusText(*out.fields))
            else:
                self.outbox[index].append(codec.mission_message(out))

    def mission_current(self) -> mavlink.MAVLink_message:
        """MISSION_CURRENT as PX4 v1.16 fills it (for a stream: seq, total, state, mode)."""
        return mavlink.MAVLink_mission_current_message(*self.missions.mission_current())

    def _mission_tick(self, *, force: bool = False) -> None:
        """Transfer retries and timeouts; the navigator's current item into the mission list; the
        MISSION_CURRENT / MISSION_ITEM_REACHED due (``mission.Reporter``), sent with the telemetry."""
        mm, nav = self.missions, self.autopilot.navigator
        if not force:
            link = mm.busy_link
            outs = mm.update(self.time_s)
            if outs:
                self._send_mission(link if link is not None else API, outs)
        if nav.items and nav.current_seq != mm.current_seq and not force:
            mm.current_seq = nav.current_seq
        outs = self._mission_reports.due(self.time_s, mm.mission_current(), nav.reached_seq, nav.reached_count, bool(mm.mission))
        for pending in self._mission_streams:
            pending.extend(codec.mission_message(o) for o in outs)

    def _nav_command(self, msg: mavlink.MAVLink_message, cmd: Command) -> Reply | None:
        """MAV_CMD_DO_REPOSITION and MAV_CMD_DO_ORBIT, whose global position the plant turns into
        local NED here; None for the other commands."""
        if cmd.command not in (mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_CMD_DO_ORBIT):
            return None
        target = codec.command_position_ned(msg, self.autopilot.frame(), self._truth.pos_ned_m)
        if target is None:
            return Reply(mavlink.MAV_RESULT_DENIED)
        p = cmd.params
        if cmd.command == mavlink.MAV_CMD_DO_REPOSITION:
            yaw = math.radians(p[3]) if math.isfinite(p[3]) else None
            return self.autopilot.reposition(target, p[0] if math.isfinite(p[0]) and p[0] > 0 else -1.0, yaw, self.time_s)
        radius = p[0] if math.isfinite(p[0]) and p[0] != 0 else DEFAULT_ORBIT_RADIUS_M
        speed = abs(p[1]) if math.isfinite(p[1]) and p[1] != 0 else DEFAULT_ORBIT_SPEED_M_S
        return self.autopilot.orbit(target, radius, speed, self.time_s)

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
        if c == mavlink.MAV_CMD_PREFLIGHT_CALIBRATION:
            return Reply(calibration.calibration_result(p, self.autopilot.armed))
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

    def _on_follow_target(self, index: int, msg: mavlink.MAVLink_message) -> None:
        """FOLLOW_TARGET (#144): the target's latitude, longitude (degE7), altitude AMSL (m) and
        velocity NED (m/s), as PX4's receiver takes them (every field, whatever est_capabilities
        says), for Follow Target (sitl_plant/follow.py)."""
        pos = self.autopilot.frame().to_ned(msg.lat * 1e-7, msg.lon * 1e-7, float(msg.alt), relative=False)
        vel = (float(msg.vel[0]), float(msg.vel[1]), float(msg.vel[2]))
        self.autopilot.on_follow_target(pos, vel, self.time_s)

    def _on_heartbeat(self, index: int, msg: mavlink.MAVLink_message) -> None:
        pass  # a client's presence; nothing to do (the link already learnt its address)

    def _on_setup_signing(self, index: int, msg: mavlink.MAVLink_message) -> None:
        """A new signing key for every link (applied by the loop, which owns the links); refused
        while armed, as a key change in flight would cut the link to the vehicle.

        Only a plant that signs takes it (then only signed with the current key, so only the
        key's owner can send it). A plant that does not sign ignores it, as PX4 v1.16 does
        (it has no signing: measured, ``tests/e2e/test_px4_parity_signing.py``): else anyone's
        unsigned SETUP_SIGNING would switch signing on with the sender's key and lock the owner
        out. Counted in ``counters.ignored``."""
        if not self.signing:
            self.counters.ignored["SETUP_SIGNING"] = self.counters.ignored.get("SETUP_SIGNING", 0) + 1
            return
        if self.autopilot.armed:
            self.counters.refusals["SETUP_SIGNING"] = self.counters.refusals.get("SETUP_SIGNING", 0) + 1
            self._announce(StatusText(mavlink.MAV_SEVERITY_WARNING, "SETUP_SIGNING refused: vehicle armed"))
            return
        self.signing_change = SigningKey(bytes(msg.secret_key), int(msg.initial_timestamp))
        self.signing = not self.signing_change.disables
        self._announce(StatusText(mavlink.MAV_SEVERITY_INFO, "MAVLink signing " + ("disabled" if self.signing_change.disables else "key updated via SETUP_SIGNING")))

    # -- services: FTP, log download, shell, STATUSTEXT in -----------------------------------------

    def _on_ftp(self, index: int, msg: mavlink.MAVLink_message) -> None:
        try:
            replies = self.ftp[index].handle(msg.payload)
        except FtpFormatError as exc:
            self._refuse(str(exc))
            return
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        self.outbox[index].extend(mavlink.MAVLink_file_transfer_protocol_message(0, *src, list(r)) for r in replies)

    def _on_log_request_list(self, index: int, msg: mavlink.MAVLink_message) -> None:
        self.outbox[index].extend(self.logs[index].request_list(int(msg.start), int(msg.end)))

    def _on_log_request_data(self, index: int, msg: mavlink.MAVLink_message) -> None:
        self.outbox[index].extend(self.logs[index].request_data(int(msg.id), int(msg.ofs), int(msg.count)))

    def _on_log_request_end(self, index: int, msg: mavlink.MAVLink_message) -> None:
        self.logs[index].request_end()

    def _on_log_erase(self, index: int, msg: mavlink.MAVLink_message) -> None:
        self.logs[index].erase()

    def _on_serial_control(self, index: int, msg: mavlink.MAVLink_message) -> None:
        if int(msg.device) != mavlink.SERIAL_CONTROL_DEV_SHELL:
            self.counters.unhandled += 1  # a serial port: the simulation has none
            return
        count = min(int(msg.count), len(msg.data))
        output = self.shells[index].feed(bytes(msg.data[:count]))
        self.outbox[index].extend(shell.replies(output))

    def _on_statustext(self, index: int, msg: mavlink.MAVLink_message) -> None:
        self.counters.statustexts_in += 1  # taken without a reply, as PX4 (which forwards it to its other links)

    def service_output(self, index: int) -> list[mavlink.MAVLink_message]:
        """What a running service sends next on link ``index`` (a log download's next LOG_DATA)."""
        return self.logs[index].pump()

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
            measured = truth if self.sensors is None else self.sensors.measure(truth)
            if self._dead_reckoning is not None:
                measured = self._dead_reckoning.measure(measured)
            self._measured = measured
        return self._measured

    def status_changed(self) -> bool:
        """Whether the vehicle's status (mode, arming, failsafe...) differs from what the latest
        heartbeat said (lockstep: a heartbeat then goes out at once, see ``run_lockstep``)."""
        return self._heartbeat_status is not None and self.autopilot.status() != self._heartbeat_status

    def heartbeat_now(self) -> None:
        """A heartbeat of the current status on every link (in the outbox)."""
        for box in self.outbox:
            box.append(self._build(mavlink.MAVLINK_MSG_ID_HEARTBEAT))

    def telemetry(self, index: int, *, force: tuple[int, ...] = ()) -> list[mavlink.MAVLink_message]:
        """The streams due now on link ``index`` (plus ``force``d ones), all stamped now."""
        due = self.streams[index].due(self.time_us)
        for mid in force:
            if mid not in due:
                due.append(mid)
        out = [m for m in (self._build(mid) for mid in due) if m is not None]
        if index < len(self._mission_streams) and self._mission_streams[index]:
            out += self._mission_streams[index]
            self._mission_streams[index] = []
        return out

    def _build(self, mid: int) -> mavlink.MAVLink_message | None:
        t_ms, t_us = self.time_ms, self.time_us
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            status = self.autopilot.status()
            self._heartbeat_status = status
            return codec.heartbeat(status)
        if mid == mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION:
            return codec.hil_state_quaternion(self._truth, self.config.home)
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
            if mid == mavlink.MAVLINK_MSG_ID_ODOMETRY:
                return codec.odometry(t_us, st)
            if mid == mavlink.MAVLINK_MSG_ID_ALTITUDE:
                return codec.altitude(t_us, st, self.config.home, self.config.home.alt_m - self.autopilot.home_ned_m[2])
            if mid == mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE:
                return codec.scaled_pressure(t_ms, st, self.config.home)
            if mid == mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_LOCATION:
                return codec.open_drone_id_location(st, self.config.home, not self._truth_on_ground())
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
            return codec.attitude_target(self._attitude_target_ms(t_ms), q, rates, thrust)
        if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return codec.autopilot_version(self.config.sysid)
        return self._build_px4_extra(mid, t_ms, t_us)

    def _build_px4_extra(self, mid: int, t_ms: int, t_us: int) -> mavlink.MAVLink_message | None:
        """The streams PX4 v1.16 sends that carry no simulated state worth the name (docs/parity/wire.md)."""
        if mid == mavlink.MAVLINK_MSG_ID_TIMESYNC:
            return codec.timesync_request(max(t_us * 1000, 1))
        if mid == mavlink.MAVLINK_MSG_ID_PING:
            self._ping_seq += 1
            return codec.ping_request(t_us, self._ping_seq)
        if mid == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
            return self.mission_current()  # the stream at 1 Hz; on every change too (mission.Reporter)
        if mid == mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:
            return self._position_target(t_ms)
        if mid == mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR:
            return codec.distance_sensor(t_ms)
        if mid == mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS:
            return codec.estimator_status(t_us, self.autopilot.status())
        if mid == mavlink.MAVLINK_MSG_ID_VIBRATION:
            return codec.vibration(t_us)
        if mid == mavlink.MAVLINK_MSG_ID_OPEN_DRONE_ID_SYSTEM:
            return codec.open_drone_id_system(self.config.home, self.epoch_us() * 1e-6)
        if mid == 8:
            return codec.link_node_status(t_ms, 0, 0)
        if mid == 380:
            return codec.time_estimate_to_target()
        if mid == 436:
            custom = self.autopilot.status().mode.custom_mode
            return codec.current_mode(custom, custom)
        return None

    def _truth_on_ground(self) -> bool:
        return bool(self.sim.on_ground)

    def _position_target(self, t_ms: int) -> mavlink.MAVLink_message:
        """What the position controller flies: the offboard position setpoint or the auto
        mode's target; NaN (ignored) where nothing is commanded, as PX4 sends it."""
        task = self.autopilot.task()
        none3 = (None, None, None)
        if not self.autopilot.armed:  # PX4 on the ground, disarmed: everything ignored (measured)
            return codec.position_target_local_ned(t_ms, none3, none3, none3, float(self._truth.euler_rad[2]))
        if isinstance(task, OffboardTask) and isinstance(task.setpoint, PositionSetpoint):
            sp = task.setpoint
            yaw = sp.yaw_rad if sp.yaw_rad is not None else float(self._truth.euler_rad[2])
            return codec.position_target_local_ned(t_ms, sp.pos_ned_m, sp.vel_ned_m_s, none3, yaw)
        if isinstance(task, PositionTask):
            vel = task.vel_ned_m_s if task.descend_m_s is None else (task.vel_ned_m_s[0], task.vel_ned_m_s[1], task.descend_m_s)
            return codec.position_target_local_ned(t_ms, task.pos_ned_m, vel, none3, task.yaw_rad)
        return codec.position_target_local_ned(t_ms, none3, none3, none3, float(self._truth.euler_rad[2]))

    def _motor_speeds(self) -> np.ndarray:
        if self._rigid:
            return self._truth.motor_speeds_rad_s

        thrust, torque = self.loops.last_output(self.sim.x)
        return rotor_speeds_for(thrust, torque, self.vehicle)

    def _attitude_target(self) -> tuple[tuple[float, float, float, float], tuple[float, float, float], float]:
        task = self.autopilot.task()
        thr_max = self.params["SIM_THR_MAX"]
        if isinstance(task, OffboardTask) and isinstance(task.setpoint, AttitudeSetpoint):
            sp = task.setpoint
            q = sp.q_wxyz if sp.q_wxyz is not None else tuple(float(v) for v in self._truth.quat_wxyz)
            sent, sent_q = self._sent_attitude
            if sent is sp and sp.q_wxyz is not None:
                q = sent_q  # PX4 echoes the quaternion float for float as it came, not normalised
            rates = tuple(0.0 if r is None else r for r in sp.body_rates_frd_rad_s)
            return q, rates, min(max(sp.thrust_norm or 0.0, 0.0), 1.0)  # type: ignore[return-value]
        if isinstance(task, OffboardTask) and isinstance(task.setpoint, ActuatorSetpoint):
            return tuple(float(v) for v in self._truth.quat_wxyz), (0.0, 0.0, 0.0), task.setpoint.controls[3]  # type: ignore[return-value]
        if isinstance(task, PositionTask) or (isinstance(task, OffboardTask) and isinstance(task.setpoint, PositionSetpoint)):
            px4 = self.loops.px4
            return px4._q_sp, (0.0, 0.0, 0.0), px4._thrust_n / thr_max
        return tuple(float(v) for v in self._truth.quat_wxyz), (0.0, 0.0, 0.0), 0.0  # type: ignore[return-value]

    def _attitude_target_ms(self, now_ms: int) -> int:
        """ATTITUDE_TARGET's time_boot_ms as PX4 stamps it: the attitude setpoint's own time
        (PX4's ATTITUDE_TARGET.hpp sends vehicle_attitude_setpoint's timestamp), which for an
        offboard attitude setpoint is when it was taken; a position mode makes one every tick."""
        task = self.autopilot.task()
        taken_s = self.autopilot.setpoint_time_s
        if isinstance(task, OffboardTask) and isinstance(task.setpoint, AttitudeSetpoint) and taken_s is not None:
            return int(round(taken_s * 1000.0))
        return now_ms

    def status_line(self) -> str:
        """One line for the terminal: time, mode, arming, failsafe, where the vehicle is."""
        st = self.autopilot.status()
        p = self._truth.pos_ned_m
        arm = "ARMED" if st.armed else "disarmed"
        fs = " FAILSAFE" if st.failsafe else ""
        return f"t={self.time_s:8.2f}s {st.mode.label:<8} {arm:<8}{fs} N={p[0]:7.2f} E={p[1]:7.2f} D={p[2]:7.2f}"


#: The mission protocol's messages (sitl_plant/mission.py), addressed by PX4's own rule.
_MISSION_MESSAGES = frozenset({
    "MISSION_COUNT", "MISSION_ITEM", "MISSION_ITEM_INT", "MISSION_REQUEST", "MISSION_REQUEST_INT",
    "MISSION_REQUEST_LIST", "MISSION_ACK", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
})  # fmt: skip

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
    "SETUP_SIGNING": Plant._on_setup_signing,
    "HEARTBEAT": Plant._on_heartbeat,
    "FILE_TRANSFER_PROTOCOL": Plant._on_ftp,
    "LOG_REQUEST_LIST": Plant._on_log_request_list,
    "LOG_REQUEST_DATA": Plant._on_log_request_data,
    "LOG_REQUEST_END": Plant._on_log_request_end,
    "LOG_ERASE": Plant._on_log_erase,
    "SERIAL_CONTROL": Plant._on_serial_control,
    "STATUSTEXT": Plant._on_statustext,
    **{kind: Plant._on_mission for kind in _MISSION_MESSAGES},
    "MANUAL_CONTROL": Plant._on_manual_control,
    "FOLLOW_TARGET": Plant._on_follow_target,
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
            box.extend(self.plant.service_output(i))
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
        self.flush_outbox()  # a running log download goes on while time stands still
        for i in range(len(self.link.endpoints)):
            self.link.send_keepalive(i, [mavlink.MAVLINK_MSG_ID_HEARTBEAT])

    def housekeeping(self) -> None:
        now = self.clock()
        if self.status is not None and now >= self._next_status:
            self.status(self.plant.status_line() + self.link.impairment_status())
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
    as it can and the lag is dropped once it exceeds ``CATCH_UP_SIM_S`` of simulation time
    (counted as an overrun): the vehicle's clock slips rather than jumps.
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
            if lag_us > CATCH_UP_SIM_S * 1e6 + tick_us:
                stats.overruns += 1
                # the lag dropped but for the next tick: a plant that cannot keep up goes on at
                # once, as fast as it can, without waiting a tick first (at --speed 50 that wait
                # made a mission test 50 % slower)
                wall0, sim0 = clock(), plant.time_us + tick_us
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
                _apply_signing_change(d)
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
        _apply_signing_change(d)


def _apply_signing_change(d: _Driver) -> None:
    """A SETUP_SIGNING the plant took: the new key (or signing off) on every link, after the
    replies so far went out under the old key, as their receiver expects."""
    key = d.plant.signing_change
    if key is not None:
        d.flush_outbox()
        if key.disables:
            d.link.unsign()
        else:
            d.link.rekey(key)
        d.plant.signing_change = None
