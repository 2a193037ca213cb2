"""The aligned series of a scanned log: ``build_record`` makes the ``FlightRecord`` (one row a
control sample) that ``offboard.metrics`` and ``offboard.plots`` take; pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from offboard import codec
from offboard.clockrate import STALLED_RATE, ClockRateMeter
from offboard.controller.tuning import vehicle_values
from offboard.errors import LogFormatError
from offboard.model.rotations import euler_from_quat
from offboard.record import COLUMNS, FlightRecord, FlightStatus
from offboard.replay.scan import OFFBOARD_MODE_NAME, LogScan, arm_accepted, offboard_start_s
from offboard.trajectory.base import Phase, Trajectory


@dataclass(frozen=True)
class SetpointSeries:
    """The commands sent to the vehicle, one row per sample (``time_boot_ms`` echoes telemetry).

    ``kind`` is ``"attitude"`` (SET_ATTITUDE_TARGET), ``"actuator"`` (SET_ACTUATOR_CONTROL_TARGET),
    ``"attitude_target"`` (the vehicle's own ATTITUDE_TARGET report, for logs without the
    commands) or ``""`` (none). ``values`` columns: attitude: type_mask, q0..q3, p, q, r, thrust;
    actuator: c0..c3; attitude_target: q0..q3, thrust. ``source`` is the sender (system,
    component), (0, 0) for the vehicle's own report.
    """

    kind: str
    time_boot_ms: np.ndarray
    time_s: np.ndarray  # tlog time
    values: np.ndarray
    source: tuple[int, int] = (0, 0)
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # message number in the log

    def __len__(self) -> int:
        return len(self.time_boot_ms)


def _unique_by_time(rows: list[tuple]) -> list[tuple]:
    """First row of each ``time_boot_ms`` (a plant logs each telemetry message once per link),
    in time order."""
    seen: set[int] = set()
    out = []
    for row in rows:
        if row[0] not in seen:
            seen.add(row[0])
            out.append(row)
    out.sort(key=lambda r: r[0])
    return out


def _distinct_commands(rows: list[tuple]) -> list[tuple]:
    """Each command once, in ``time_boot_ms`` order (the log's among equal stamps).

    A command is a sample of the controller, named by the telemetry stamp it answered. Two
    samples may answer one stamp: a real-time sample that found no newer telemetry (a stream
    slower than the sample rate, a late datagram) reads the last again, and its command differs
    from the one before; both are kept, or a re-run would skip the second sample's step and
    differ from there on. A row repeating an earlier one's stamp *and* fields is the same command
    sent again (a client answering a repeated telemetry burst), dropped. Rows: (stamp, fields...,
    source, log time, message number), as ``LogScan`` keeps them.
    """
    seen: set[tuple] = set()
    out = []
    for row in rows:
        key = (row[0], *row[1:-3])
        if key not in seen:
            seen.add(key)
            out.append(row)
    out.sort(key=lambda r: r[0])
    return out


def _mission_window(scan: LogScan, sysid: int) -> tuple[float, float]:
    """Message numbers bounding the mission: the accepted arm of ``sysid`` (else the start) and
    the first MAV_CMD_NAV_LAND after it (else the end)."""
    arm = arm_accepted(scan, sysid)
    first = arm[0] if arm is not None else -math.inf
    lands = [c[0] for c in scan.commands if c[4] == mavlink.MAV_CMD_NAV_LAND and c[0] > first and c[3] in (sysid, 0)]
    return first, (min(lands) if lands else math.inf)


def setpoints_for(scan: LogScan, sysid: int) -> SetpointSeries:
    """The command stream to vehicle ``sysid`` (targeted at it or broadcast), the longer of the
    attitude and actuator streams; else the vehicle's ATTITUDE_TARGET reports."""
    att = scan.set_attitude.get(sysid, []) + scan.set_attitude.get(0, [])
    act = scan.set_actuator.get(sysid, []) + scan.set_actuator.get(0, [])
    if att or act:
        # the stream of the mission: between the accepted arm and the landing command, since an
        # actuator flight keeps a level attitude target going while the vehicle lands, which in a
        # long landing (PX4's: slower near the ground, ~3 s to detect it) outnumbers its setpoints
        first, last = _mission_window(scan, sysid)
        n_att = sum(1 for r in att if first < r[-1] < last)
        n_act = sum(1 for r in act if first < r[-1] < last)
        rows, kind, width = (att, "attitude", 9) if n_att >= n_act else (act, "actuator", 4)
        sources: dict[tuple[int, int], int] = {}
        for row in rows:
            sources[row[-3]] = sources.get(row[-3], 0) + 1
        source = max(sources, key=sources.__getitem__)  # the controller (others: a GCS, a test)
        # every command the controller computed (``_distinct_commands``), the pre-mission ones apart:
        # the mission's first sample may answer the very telemetry the last pre-mission setpoint
        # did (no new stamp came while the vehicle armed: PX4 at --speed 4)
        arm = arm_accepted(scan, sysid)
        split = arm[0] if arm is not None else -1
        ours = [r for r in rows if r[-3] == source]
        rows = _distinct_commands([r for r in ours if r[-1] < split]) + _distinct_commands([r for r in ours if r[-1] >= split])
        return SetpointSeries(
            kind,
            np.array([r[0] for r in rows], dtype=np.int64),
            np.array([r[-2] for r in rows]),
            np.array([r[1 : 1 + width] for r in rows], dtype=float).reshape(-1, width),
            source,
            np.array([r[-1] for r in rows], dtype=np.int64),
        )
    rows = _unique_by_time(scan.attitude_targets.get(sysid, []))
    if rows:
        return SetpointSeries(
            "attitude_target",
            np.array([r[0] for r in rows], dtype=np.int64),
            np.array([r[-1] for r in rows]),
            np.array([r[1:6] for r in rows], dtype=float),
        )
    return SetpointSeries("", np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 0)))


def _latest(times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Index of the latest ``times`` entry at or before each of ``at`` (-1: none yet)."""
    return np.searchsorted(times, at, side="right") - 1


def mode_phases(scan: LogScan, sysid: int, t0_s: float, clock_rate: float = 1.0) -> list[Phase]:
    """The vehicle's flight modes as report phases, times relative to ``t0_s`` (tlog time), in
    seconds of the record (``clock_rate`` of them per second of the log)."""
    changes = [((e.time_s - t0_s) * clock_rate, e.text) for e in scan.events if e.system == sysid and e.kind == "mode"]
    end = (scan.last_time_s - t0_s) * clock_rate
    phases: list[Phase] = []
    counts: dict[str, int] = {}
    for k, (start, name) in enumerate(changes):
        stop = changes[k + 1][0] if k + 1 < len(changes) else end + 1e-9
        counts[name] = counts.get(name, 0) + 1
        label = name if counts[name] == 1 else f"{name} {counts[name]}"
        if stop > max(start, 0.0):
            phases.append(Phase(label, max(start, 0.0), stop))
    return phases


def logged_scale(params: dict[str, float], thrust_max_n: float | None = None) -> tuple[float, float, float]:
    """(thrust [N], roll/pitch torque [N m], yaw torque [N m]) at normalised 1, as the vehicle
    published them in the log (``SIM_THR_MAX``, ``SIM_TQ_RP_MAX``, ``SIM_TQ_Y_MAX``; PX4 SITL's SIH:
    ``SIH_T_MAX`` x ``CA_ROTOR_COUNT``, as ``offboard fly`` reads it), NaN where it did not;
    ``thrust_max_n`` instead of the log's thrust (a real airframe publishes none).

    Plain numbers, NaN allowed: a record names what the log cannot tell as NaN, while
    ``offboard.codec.Scaling`` (what a command is encoded with) must know the thrust.
    """
    thrust = vehicle_values(params).get("SIM_THR_MAX", math.nan)
    return (
        thrust if thrust_max_n is None else thrust_max_n,
        params.get("SIM_TQ_RP_MAX", math.nan),
        params.get("SIM_TQ_Y_MAX", math.nan),
    )


def sample_numbers(elapsed_s: np.ndarray, sample_time_s: float) -> np.ndarray:
    """Sample numbers n of commands logged ``elapsed_s`` after the first, one command a sample.

    ``rint(elapsed / To)``, exact in lockstep. In real time a command goes out late now and then
    (the scheduler's jitter, a busy machine): one more than half a period late rounds onto the
    next sample's number, which then appears twice while its own number is "missing". Two
    commands never share a sample, so a collision is undone by moving the earlier one back to a
    free number (it was late), else the later one on (it was early); a real gap (no command for
    whole periods, a telemetry outage) keeps its numbers.
    """
    n = np.rint(np.asarray(elapsed_s, dtype=float) / sample_time_s).astype(np.int64)
    for k in range(len(n) - 1):
        if n[k + 1] != n[k]:
            continue
        if k == 0 and n[k] > 0 or k > 0 and n[k - 1] < n[k] - 1:
            n[k] -= 1
        elif k + 2 >= len(n) or n[k + 2] > n[k + 1] + 1:
            n[k + 1] += 1
    return n


def vehicle_clock_rate(log_time_s: np.ndarray, time_boot_ms: np.ndarray) -> float | None:
    """The vehicle's seconds per second of the log, where commands logged at ``log_time_s`` and
    echoing the vehicle's ``time_boot_ms`` were sampled on the vehicle's clock: its time ran at a
    rate other than the log's (``offboard fly --clock vehicle`` against PX4 SITL at ``--speed 4``,
    logged on the wall clock; ``clockrate.ClockRate.real_time``) and moved (not a lockstep vehicle
    waiting). None otherwise: a lockstep log, stamped with the vehicle's time, and a real-time one
    run at 1."""
    meter = ClockRateMeter()
    for t, boot in zip(np.asarray(log_time_s, dtype=float).tolist(), np.asarray(time_boot_ms).tolist()):
        meter.add(t, int(boot))
    rate = meter.measure() if len(log_time_s) > 1 else None
    return rate.rate if rate is not None and not rate.real_time and rate.rate > STALLED_RATE else None


def _mission_rows(scan: LogScan, vehicle: int, setpoints: SetpointSeries, sample_time_s: float | None,
                  duration_s: float | None) -> tuple[np.ndarray, np.ndarray, float, float | None]:
    """(rows of ``setpoints`` flown as the mission, their sample numbers n, To, and the vehicle's
    clock rate against the log's where they were sampled on the vehicle's clock, else None).

    The mission starts with the first command sent after the vehicle accepted the arm command
    (``offboard fly`` starts mission time there), or, without one in the log, with the first
    command once the vehicle reports OFFBOARD. n counts sample periods from there
    (``sample_numbers``: tlog time / To, exact in lockstep, the tick count in real time; the
    commands' ``time_boot_ms`` / To where the vehicle's clock ran at another rate than the log's,
    ``vehicle_clock_rate``). It ends after ``duration_s`` (the mission's), or when the controller
    sends its next command (land, mode) or the vehicle leaves OFFBOARD.
    """
    count = len(setpoints)
    arm = arm_accepted(scan, vehicle)
    start = 0
    if arm is not None:
        start = int(np.searchsorted(setpoints.index, arm[0], side="right"))
        if setpoints.kind == "attitude":
            # A plant's log may hold, after the ack, the last pre-mission setpoint the controller
            # sent before it read the ack: the vehicle's own attitude, zero rates, zero thrust.
            for _ in range(3):
                if start < count and not np.any(setpoints.values[start, 5:9]):
                    start += 1
    else:
        entered = offboard_start_s(scan, vehicle)
        if entered is not None:
            start = int(np.searchsorted(setpoints.time_s, entered, side="left"))
    if start >= count:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), sample_time_s or math.nan, None
    # the clock the samples were taken on: the log's, or the vehicle's when it ran at another rate
    elapsed = setpoints.time_s[start:] - setpoints.time_s[start]
    clock_rate = vehicle_clock_rate(setpoints.time_s[start:], setpoints.time_boot_ms[start:])
    if clock_rate is not None:
        elapsed = (setpoints.time_boot_ms[start:] - setpoints.time_boot_ms[start]) / 1000.0
    if sample_time_s is None:
        # the mean command period (whole milliseconds): exact in lockstep, robust to real-time jitter
        span = elapsed[-1]
        sample_time_s = round(1000.0 * span / (count - start - 1)) / 1000.0 if count - start > 1 else math.nan
        if not sample_time_s > 0:
            sample_time_s = 0.05
    n = sample_numbers(elapsed, sample_time_s)
    rows = np.arange(start, count)
    if duration_s is not None:
        keep = n <= int(round(duration_s / sample_time_s))
    else:
        stop_index = np.iinfo(np.int64).max
        for idx, _t, src, target, _cmd, _p1 in scan.commands:
            if src == setpoints.source and target in (vehicle, 0) and idx > setpoints.index[start]:
                stop_index = idx
                break
        keep = setpoints.index[start:] < stop_index
        left = [e.time_s for e in scan.events if e.system == vehicle and e.kind == "mode" and e.time_s > setpoints.time_s[start]
                and e.text != OFFBOARD_MODE_NAME]
        if left:
            keep &= setpoints.time_s[start:] < left[0]
    return rows[keep], n[keep], sample_time_s, clock_rate


def build_record(
    scan: LogScan,
    *,
    sysid: int | None = None,
    trajectory: Trajectory | None = None,
    sample_time_s: float | None = None,
    thrust_max_n: float | None = None,
    source: str = "",
) -> FlightRecord:
    """The aligned series of a log: one row per control sample.

    With the commands of a controller in the log (SET_ATTITUDE_TARGET or
    SET_ACTUATOR_CONTROL_TARGET), the rows are the mission's samples (``_mission_rows``), at
    ``t_s = n To`` as ``offboard fly`` counts them; the state of a row is the ATTITUDE and
    LOCAL_POSITION_NED its command answered (same ``time_boot_ms``; else the latest before).
    Without commands (a log from another system) the rows are every LOCAL_POSITION_NED, with the
    latest ATTITUDE, ``t_s`` from the first. References: the mission ``trajectory`` when given,
    else the vehicle's POSITION_TARGET_LOCAL_NED; the attitude reference and thrust are the
    commands' (q -> x7ez, x9ez, yaw; ``thrust * SIM_THR_MAX``, or ``thrust_max_n`` when given:
    ``logged_scale``), or the vehicle's ATTITUDE_TARGET.
    Columns a log cannot fill are NaN (torques and tau_tilde of attitude commands: ``rerun``
    recomputes them).

    Raises
    ------
    LogFormatError
        No system in the log reports both ATTITUDE and LOCAL_POSITION_NED.
    """
    vehicle = scan.vehicle_sysid() if sysid is None else sysid
    if vehicle is None or vehicle not in scan.attitude or vehicle not in scan.local_position:
        who = "any system" if sysid is None else f"system {sysid}"
        raise LogFormatError(f"{source or 'the log'}: no ATTITUDE and LOCAL_POSITION_NED from {who}; nothing to replay")
    thrust_max, torque_rp_max, torque_y_max = logged_scale(scan.params.get(vehicle, {}), thrust_max_n)
    setpoints = setpoints_for(scan, vehicle)
    commanded = setpoints.kind in ("attitude", "actuator")
    duration = trajectory.duration_s if trajectory is not None else None
    if commanded:
        rows, n_samples, to, clock_rate = _mission_rows(scan, vehicle, setpoints, sample_time_s, duration)
        grid = setpoints.time_boot_ms[rows]
        t_s = n_samples * to
        log_time = setpoints.time_s[rows]
    else:
        rows = np.zeros(0, dtype=np.int64)
        pos = np.array(_unique_by_time(scan.local_position[vehicle]), dtype=float)
        grid = pos[:, 0].astype(np.int64)
        t_s = (grid - grid[0]) / 1000.0
        log_time = pos[:, 7]
        if duration is not None:
            keep = t_s <= duration + 1e-9
            grid, t_s, log_time = grid[keep], t_s[keep], log_time[keep]
        to = sample_time_s if sample_time_s is not None else math.nan
    i_att, i_pos, att, pos = _telemetry_rows(scan, vehicle, grid, setpoints.index[rows] if commanded else None)
    keep = (i_att >= 0) & (i_pos >= 0)
    grid, t_s, log_time, i_att, i_pos = grid[keep], t_s[keep], log_time[keep], i_att[keep], i_pos[keep]
    if commanded and clock_rate is not None and len(i_pos):
        # offboard fly on the vehicle's clock ticks every To of it (from the first position it
        # heard: not always the log's first), samples at the first position at or after each
        # tick and takes the references at that position's time, n To plus how late after its
        # tick the position came. The ticks lie To apart at or before every sampled position:
        # at the latest, where the least late sample was on its tick (exact where positions
        # often fall on a tick, as sitl-plant's every 100 ms; PX4's stamps within a millisecond
        # or two)
        stamp_ms = pos[i_pos, 0]
        n_kept = np.rint(t_s / to)
        tick0_ms = float(np.min(stamp_ms - n_kept * 1000.0 * to))
        t_s = (stamp_ms - tick0_ms) / 1000.0
    if commanded:
        rows = rows[keep]
    n = len(grid)
    nan3 = np.full((n, 3), np.nan)
    columns: dict[str, np.ndarray] = {
        "t_s": np.asarray(t_s, dtype=float),
        "pos_ned_m": pos[i_pos, 1:4],
        "vel_ned_m_s": pos[i_pos, 4:7],
        "euler_rad": att[i_att, 1:4],
        "ref_pos_ned_m": nan3.copy(),
        "ref_yaw_rad": np.full(n, np.nan),
        "ref_euler_rad": nan3.copy(),
        "thrust_n": np.full(n, np.nan),
        "torques_nm": nan3.copy(),
        "tau_tilde": nan3.copy(),
    }
    reference_source = "none"
    if trajectory is not None:
        reference_source = "mission"
        for k, t in enumerate(columns["t_s"]):
            ref = trajectory.reference(float(t))
            columns["ref_pos_ned_m"][k] = ref.pos_ned_m
            columns["ref_yaw_rad"][k] = ref.yaw_rad
    elif scan.position_targets.get(vehicle):
        targets = np.array(_unique_by_time(scan.position_targets[vehicle]), dtype=float)
        j = _latest(targets[:, 0], grid)
        ok = j >= 0
        if ok.any():  # targets the vehicle flew during the samples (not only after them, e.g. landing)
            reference_source = "POSITION_TARGET_LOCAL_NED"
            columns["ref_pos_ned_m"][ok] = targets[j[ok], 1:4]
            columns["ref_yaw_rad"][ok] = targets[j[ok], 4]

    if len(setpoints) and n:
        j = rows if commanded else _latest(setpoints.time_boot_ms, grid)
        ok = j >= 0
        v = setpoints.values[j[ok]]
        if setpoints.kind in ("attitude", "attitude_target"):
            q = v[:, 1:5] if setpoints.kind == "attitude" else v[:, 0:4]
            thrust = v[:, 8] if setpoints.kind == "attitude" else v[:, 4]
            mask = v[:, 0].astype(int) if setpoints.kind == "attitude" else np.zeros(len(v), dtype=int)
            euler = np.array([euler_from_quat(row) for row in q]).reshape(-1, 3)
            euler[(mask & 128) != 0] = np.nan  # attitude ignored
            columns["ref_euler_rad"][ok] = euler
            columns["thrust_n"][ok] = np.where((mask & 64) != 0, np.nan, thrust * thrust_max)
        else:
            columns["thrust_n"][ok] = v[:, 3] * thrust_max
            columns["torques_nm"][ok] = v[:, 0:3] * np.array(
                [torque_rp_max, torque_rp_max, torque_y_max]
            )

    rate = clock_rate if commanded and clock_rate is not None else 1.0
    t0_log = float(log_time[0] - columns["t_s"][0] / rate) if n else scan.first_time_s
    phases = trajectory.phases() if trajectory is not None else mode_phases(scan, vehicle, t0_log, rate)
    status, detail = FlightStatus.COMPLETE, ""
    end_log = float(log_time[-1]) if n else scan.last_time_s
    failsafes = [e for e in scan.events if e.kind == "failsafe" and e.system == vehicle and e.time_s <= end_log + 1.0]
    if failsafes:
        status, detail = FlightStatus.FAILSAFE, f"at t = {(failsafes[0].time_s - t0_log) * rate:.2f} s: {failsafes[0].text}"
    return FlightRecord(
        columns={name: columns[name] for name in COLUMNS},
        phases=phases,
        status=status,
        status_detail=detail,
        meta={
            "source": source,
            "vehicle_sysid": vehicle,
            "commands": setpoints.kind or "none",
            "commands_from": list(setpoints.source) if commanded else None,
            "references": reference_source,
            "sample_time_s": to,
            "start_log_time_s": t0_log,
            # the record's seconds per second of the log (not 1: sampled on a vehicle's clock that ran faster)
            "clock_rate": rate,
            "thrust_max_n": thrust_max,
            "setpoint_rows": rows,  # rows of setpoints_for(scan, vehicle) behind each sample
            "time_boot_ms": grid,
        },
    )


def _telemetry_rows(scan: LogScan, vehicle: int, time_boot_ms: np.ndarray, before: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the ATTITUDE and LOCAL_POSITION_NED behind each sample (-1: none yet), and
    the two tables (``LogScan`` row layout) they index.

    With ``before`` (the message numbers of the commands) a sample's telemetry is the latest
    finite ATTITUDE and LOCAL_POSITION_NED logged before its command: what the controller had
    handled when it sampled (``offboard fly`` logs a message as it handles it), exact in real
    time too; this is used when those ATTITUDEs carry the ``time_boot_ms`` the commands echo
    (the controller's own log). Otherwise, the latest at or before ``time_boot_ms``.
    """
    def table(rows: list[tuple], dedupe: bool) -> np.ndarray:
        arr = np.array(_unique_by_time(rows) if dedupe else rows, dtype=float).reshape(-1, 9)
        return arr[np.all(np.isfinite(arr[:, 1:7]), axis=1)]

    if before is not None:
        att = table(scan.attitude[vehicle], False)
        pos = table(scan.local_position[vehicle], False)
        i_att = np.searchsorted(att[:, 8], before, side="left") - 1
        i_pos = np.searchsorted(pos[:, 8], before, side="left") - 1
        echoed = (i_att >= 0) & (att[np.maximum(i_att, 0), 0] == time_boot_ms)
        # offboard fly samples the attitude of the position's own instant when it has it
        # (``Flight._sample``): an ATTITUDE newer than the position may be logged before the
        # command that answered an older one; the command's echo names which it was, and the
        # latest position before the command is of that very instant (PX4 in real time: a
        # tenth of the samples; sitl-plant, which stamps both alike, seldom)
        paired = echoed.copy()
        for j in np.flatnonzero(~echoed & (i_att >= 0) & (i_pos >= 0)):
            if pos[i_pos[j], 0] != time_boot_ms[j]:
                continue
            for k in range(int(i_att[j]) - 1, max(int(i_att[j]) - codec.RECENT_ATTITUDES, -1), -1):
                if att[k, 0] == time_boot_ms[j]:
                    i_att[j], paired[j] = k, True
                    break
        if len(paired) and np.mean(paired) >= 0.99:
            return i_att, i_pos, att, pos
        # not the controller's own log (a plant's, in real time: telemetry newer than what the
        # command answered is logged before it): the command's echo of time_boot_ms decides
    att = table(scan.attitude[vehicle], True)
    pos = table(scan.local_position[vehicle], True)
    return _latest(att[:, 0], time_boot_ms), _latest(pos[:, 0], time_boot_ms), att, pos
