"""PX4's own position controller flying a bundled mission: what EKF2 leaves any controller on PX4 SIH.

Issue 11 asks the designed law to hold within 5° of tilt in the second half of every hold on a
real PX4 SITL, and to fly the helix within 0.10 m. Both figures are read from EKF2's estimates
(ATTITUDE, LOCAL_POSITION_NED), and on PX4 SIH those wander: the vehicle follows its estimated
position, and EKF2's attitude is itself off the truth (docs/controller-design.md). This flies the
same mission with PX4's own controller instead of the law, as a MAVSDK or QGroundControl user
would: OFFBOARD with SET_POSITION_TARGET_LOCAL_NED carrying the mission's reference (position,
velocity and acceleration feed-forward, yaw and yaw rate) at the law's 20 Hz on the vehicle's
clock, and reads the same figures the same way (``bench.design.flight_figures``): the helix's
5-11.9 s RMS, the largest tilt in the second half of every hold in the air.

The mission starts at the arm's ACK; its references are flown in PX4's local frame as they are
(as ``offboard fly`` flies a TOML mission), and each sample records the latest estimate and
ATTITUDE before it is sent (as ``offboard fly``'s series.csv does).

    python bench/px4_own.py [--speed F] [--mission FILE] [--repeat N] [--start-after S]

Needs a PX4 SITL (``$PX4_SITL`` or ``../shared/px4-sitl/px4-sitl``); says so in one line without.
``make bench``'s design part flies it beside the law (rows ``px4-own``).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.design import MISSIONS, flight_figures  # noqa: E402
from bench.px4sitl import SKIP_REASON, px4_launcher, running_px4  # noqa: E402

SAMPLE_TIME_S = 0.05  # the law's To: the setpoints' rate on the vehicle's clock
#: SET_POSITION_TARGET_LOCAL_NED's type_mask with nothing ignored: position, velocity and
#: acceleration (not force), yaw and yaw rate all used
EVERY_FIELD = 0
PX4_OFFBOARD = (6, 0)  # PX4's custom main mode OFFBOARD
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT_ACCEPTED = 0


@dataclass
class OwnFlight:
    """One flight's samples: mission time, the estimate and ATTITUDE read before each setpoint,
    the reference sent; and how it ended (``complete``, or what went wrong)."""

    t_s: list[float] = field(default_factory=list)
    pos_ned_m: list[tuple[float, float, float]] = field(default_factory=list)
    ref_ned_m: list[tuple[float, float, float]] = field(default_factory=list)
    roll_pitch_rad: list[tuple[float, float]] = field(default_factory=list)
    status: str = "complete"


class _Vehicle:
    """The API link to PX4: its latest estimate and attitude, on its own clock."""

    def __init__(self, port: int) -> None:
        from pymavlink import mavutil

        self.mavlink = mavutil.mavlink
        self.link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=245, source_component=190)
        self.boot_s = 0.0
        self.pos: tuple[float, float, float] | None = None
        self.roll_pitch: tuple[float, float] | None = None
        self.acks: list[tuple[int, int]] = []
        self._next_heartbeat = 0.0

    def pump(self, wall_s: float) -> None:
        """Read what arrived for up to ``wall_s``; a ground-station heartbeat every second."""
        end = time.monotonic() + wall_s
        while True:
            now = time.monotonic()
            if now >= self._next_heartbeat:
                self.link.mav.heartbeat_send(self.mavlink.MAV_TYPE_GCS, self.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self._next_heartbeat = now + 1.0
            msg = self.link.recv_match(blocking=True, timeout=max(0.0, min(0.002, end - now)))
            while msg is not None:
                self._take(msg)
                msg = self.link.recv_match(blocking=False)
            if time.monotonic() >= end:
                return

    def _take(self, msg) -> None:  # noqa: ANN001 - a pymavlink message
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            self.boot_s = max(self.boot_s, msg.time_boot_ms / 1000.0)
            self.pos = (msg.x, msg.y, msg.z)
        elif kind == "ATTITUDE":
            self.boot_s = max(self.boot_s, msg.time_boot_ms / 1000.0)
            self.roll_pitch = (msg.roll, msg.pitch)
        elif kind == "COMMAND_ACK":
            self.acks.append((int(msg.command), int(msg.result)))

    def command(self, command: int, *params: float) -> bool:
        """COMMAND_LONG, up to three tries of 2 s each; whether PX4 accepted it."""
        p = [*params, *([0.0] * (7 - len(params)))]
        for confirmation in range(3):
            first = len(self.acks)
            self.link.mav.command_long_send(self.link.target_system, self.link.target_component, command, confirmation, *p)
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:
                self.pump(0.02)
                answers = [result for c, result in self.acks[first:] if c == command]
                if answers:
                    return answers[0] == MAV_RESULT_ACCEPTED
        return False

    def setpoint(self, ref) -> None:  # noqa: ANN001 - offboard.trajectory.base.Reference
        """The reference as PX4's position controller takes it (local NED)."""
        (n, e, d), (vn, ve, vd), (an, ae, ad) = ref.pos_ned_m, ref.vel_ned_m_s, ref.acc_ned_m_s2
        self.link.mav.set_position_target_local_ned_send(
            int(self.boot_s * 1000), self.link.target_system, self.link.target_component, self.mavlink.MAV_FRAME_LOCAL_NED,
            EVERY_FIELD, n, e, d, vn, ve, vd, an, ae, ad, ref.yaw_rad, ref.yaw_rate_rad_s)  # fmt: skip


def fly(trajectory, vehicle: _Vehicle, speed: float) -> OwnFlight:  # noqa: ANN001 - a Trajectory
    """The mission on PX4's own controller (module docstring)."""
    out = OwnFlight()
    deadline = time.monotonic() + 60.0
    while vehicle.pos is None or vehicle.roll_pitch is None:
        if time.monotonic() > deadline:
            out.status = "no estimate from PX4"
            return out
        vehicle.pump(0.1)
    start = trajectory.reference(0.0)
    for _ in range(20):  # PX4 takes OFFBOARD only once setpoints stream
        vehicle.setpoint(start)
        vehicle.pump(0.05 / speed)
    mode = vehicle.command(MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *PX4_OFFBOARD)
    armed = mode and vehicle.command(MAV_CMD_COMPONENT_ARM_DISARM, 1)
    if not armed:
        out.status = "PX4 refused " + ("the arm" if mode else "OFFBOARD")
        return out
    t0 = vehicle.boot_s
    samples = int(round(trajectory.duration_s / SAMPLE_TIME_S))
    wall_deadline = time.monotonic() + 4.0 * trajectory.duration_s / speed + 60.0
    for n in range(samples + 1):
        t = n * SAMPLE_TIME_S
        while vehicle.boot_s < t0 + t:  # the sample's time on the vehicle's clock
            if time.monotonic() > wall_deadline:
                out.status = f"PX4's clock stopped at t = {vehicle.boot_s - t0:.2f} s"
                return out
            vehicle.pump(0.001)
        ref = trajectory.reference(t)
        out.t_s.append(t)
        out.pos_ned_m.append(vehicle.pos)  # type: ignore[arg-type]
        out.roll_pitch_rad.append(vehicle.roll_pitch)  # type: ignore[arg-type]
        out.ref_ned_m.append(tuple(float(v) for v in ref.pos_ned_m))  # type: ignore[arg-type]
        vehicle.setpoint(ref)
    return out


def figures(flight: OwnFlight, trajectory) -> dict:  # noqa: ANN001 - a Trajectory
    """``bench.design.flight_figures`` of the flight, with its status."""
    out: dict = {"status": flight.status}
    if len(flight.t_s) < 2:
        return out
    rp = np.array(flight.roll_pitch_rad)
    phases = [(p.start_s, p.end_s, p.kind == "hold") for p in trajectory.phases()]
    return {**out, **flight_figures(np.array(flight.t_s), np.array(flight.pos_ned_m), np.array(flight.ref_ned_m),
                                    rp[:, 0], rp[:, 1], phases)}  # fmt: skip


def fly_px4_own(mission: Path, folder: Path, speed: float = 1.0, start_after_s: float = 0.0) -> dict:
    """One flight of ``mission`` on a fresh PX4 SITL with PX4's own controller, started
    ``start_after_s`` of PX4's clock after PX4 is ready (EKF2's errors follow PX4's clock:
    ``bench.design.PX4_START_STAGGER_S``): ``figures``.

    Raises
    ------
    offboard.errors.MissionFormatError
        The mission file cannot be flown (named in one line), before any PX4 is started.
    """
    from offboard.missions import load_mission

    trajectory = load_mission(mission).trajectory
    with running_px4(folder / "px4", speed=speed) as px4:
        time.sleep(start_after_s / speed)
        vehicle = _Vehicle(px4.api_listen_port)
        try:
            flight = fly(trajectory, vehicle, speed)
        finally:
            vehicle.link.close()
    return figures(flight, trajectory)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=1.0, help="PX4 SITL's --speed (default 1: real time)")
    parser.add_argument("--mission", type=Path, default=MISSIONS / "paper-helix.toml", help="a TOML mission (default the paper helix)")
    parser.add_argument("--repeat", type=int, default=1, help="flights, each on a fresh PX4 (default 1)")
    parser.add_argument("--start-after", type=float, default=0.0, metavar="S",
                        help="start each flight S s of PX4's clock after PX4 is ready (default 0): its hold then "
                             "falls on other seconds of PX4's clock, whose EKF2 errors are other ones")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be at least 1, got {args.repeat}")
    if not (math.isfinite(args.start_after) and args.start_after >= 0):
        parser.error(f"--start-after must be >= 0, got {args.start_after}")
    if not (math.isfinite(args.speed) and args.speed > 0):
        parser.error(f"--speed must be > 0, got {args.speed}")
    from offboard.errors import UserError
    from offboard.missions import load_mission

    try:
        load_mission(args.mission)
    except UserError as exc:  # a bad file: one line, before any PX4 is started
        print(f"px4_own: {exc}", file=sys.stderr)
        return 2
    if px4_launcher() is None:
        print(f"px4_own: {SKIP_REASON}", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="bench-px4-own-"))
    for k in range(args.repeat):
        f = fly_px4_own(args.mission, work / f"flight-{k + 1}", args.speed, args.start_after)
        print(f"{args.mission.name} --speed {args.speed:g} flight {k + 1}: {f['status']}; moving RMS "
              f"{_f(f.get('moving_rms_m'), '.3f')} m, hold tilt max {_f(f.get('hold_tilt_max_deg'), '.2f')} deg, "
              f"hold RMS {_f(f.get('hold_rms_m'), '.3f')} m, peak tilt {_f(f.get('peak_tilt_deg'), '.1f')} deg", flush=True)
    return 0


def _f(value, fmt: str) -> str:  # noqa: ANN001
    return "n/a" if value is None or not math.isfinite(value) else format(value, fmt)


if __name__ == "__main__":
    sys.exit(main())
