"""The controller re-run on the recorded telemetry, sample by sample, against the logged commands;
and which controller that is (``flight_controller``, resolved as ``offboard fly`` resolves it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from offboard import codec
from offboard.codec import SetpointOutput
from offboard.controller import PAPER_CONTROLLER_FILE, ActionLimits, ControllerGains, load_controller
from offboard.controller.design import inner_loop_from_params
from offboard.controller.params import ControllerParams
from offboard.controller.prediction import LatencyPredictor
from offboard.controller.tuning import vehicle_values
from offboard.controllers import ControllerKind, make_controller
from offboard.errors import LogFormatError, ParameterFileError
from offboard.flight import ControllerChoice, resolve_controller
from offboard.model.rotations import euler_from_quat
from offboard.model.vehicle import VehicleModel
from offboard.record import FlightRecord, RecordBuilder, control_row
from offboard.replay.prediction import PredictionCheck, check_prediction
from offboard.replay.record import _telemetry_rows, setpoints_for
from offboard.replay.scan import LogScan
from offboard.flight.heading_hold import TakeoffHeadingHold
from offboard.trajectory.base import ReferencePairs, Trajectory

#: The setpoint fields compared, per output kind (message units).
RERUN_FIELDS = {
    "attitude": ("q_w", "q_x", "q_y", "q_z", "roll_rate_rad_s", "pitch_rate_rad_s", "yaw_rate_rad_s", "thrust_norm"),
    "actuator": ("roll_torque_norm", "pitch_torque_norm", "yaw_torque_norm", "thrust_norm"),
}


@dataclass(frozen=True)
class RerunResult:
    """The controller fed the recorded telemetry sample by sample, against the logged commands.

    Attributes
    ----------
    output : SetpointOutput
        ``attitude``, ``rates`` or ``actuator``: the commands compared, as ``offboard fly --output`` sent them.
    fields : tuple of str
        Names of the compared message fields (``RERUN_FIELDS``).
    logged, rerun : ndarray (samples, fields)
        The logged fields, and the re-run's as the message would carry them (float32).
    record : FlightRecord
        The re-run as a flight record: the logged state and the re-run's law outputs (u, the
        angle references, eq. 16 torques, tau_tilde), as ``offboard fly`` records a flight.
    gaps : int
        Missing samples in the log (the controller in flight stepped on them; the re-run cannot).
    prediction : PredictionCheck or None
        Of a flight that predicted its state over the latency: how close that prediction came to
        what the vehicle reported then (``offboard.replay.prediction``).
    """

    output: SetpointOutput
    fields: tuple[str, ...]
    t_s: np.ndarray
    logged: np.ndarray
    rerun: np.ndarray
    record: FlightRecord
    gaps: int
    prediction: PredictionCheck | None = None

    @property
    def difference(self) -> np.ndarray:
        """|re-run - logged| of every compared field, a row per sample."""
        return np.abs(self.rerun.astype(np.float64) - self.logged.astype(np.float64))

    @property
    def max_difference(self) -> dict[str, float]:
        """The largest difference of each compared field."""
        d = self.difference
        return {name: float(np.max(d[:, i])) if len(d) else 0.0 for i, name in enumerate(self.fields)}

    @property
    def mismatched_samples(self) -> int:
        """How many samples differ in some field."""
        return int(np.count_nonzero(np.any(self.rerun != self.logged, axis=1)))

    @property
    def exact(self) -> bool:
        """Every compared field equal to the logged one after float32 rounding."""
        return len(self.t_s) > 0 and self.mismatched_samples == 0

    def first_mismatch(self) -> tuple[float, str, float, float] | None:
        """(t_s, field, logged, re-run) of the first difference, or None."""
        rows = np.nonzero(np.any(self.rerun != self.logged, axis=1))[0]
        if not len(rows):
            return None
        k = int(rows[0])
        i = int(np.argmax(self.rerun[k] != self.logged[k]))
        return float(self.t_s[k]), self.fields[i], float(self.logged[k, i]), float(self.rerun[k, i])

    def to_dict(self) -> dict:
        """The comparison for summary.json (fields, largest differences, the first mismatch)."""
        first = self.first_mismatch()
        return {
            "output": self.output,
            "samples": int(len(self.t_s)),
            "exact": self.exact,
            "mismatched_samples": self.mismatched_samples,
            "max_difference": self.max_difference,
            "first_mismatch": None if first is None else dict(zip(("t_s", "field", "logged", "rerun"), first)),
            "missing_samples": self.gaps,
            "prediction": None if self.prediction is None else self.prediction.to_dict(),
        }


class _Msg:
    """A telemetry message rebuilt from a scanned row, with the fields the codec reads."""

    def __init__(self, **fields: float) -> None:
        self.__dict__.update(fields)


def rerun_controller(
    scan: LogScan,
    record: FlightRecord,
    params: ControllerParams,
    trajectory: Trajectory,
    scaling: codec.Scaling,
    model: VehicleModel = VehicleModel.RIGID_BODY,
    encoding: SetpointOutput | None = None,
    kind: ControllerKind = ControllerKind.PAPER,
    heading_hold: TakeoffHeadingHold | None = None,
    predicted_latency_s: float | None = None,
    observed_rate_loop: bool = False,
    observer_memory_s: float | None = None,
    vehicle_params: Mapping[str, float] | None = None,
    telemetry_age_s: np.ndarray | None = None,
) -> RerunResult:
    """Feed the controller the telemetry of ``record``'s samples, as ``offboard fly`` did.

    ``encoding``: the ``offboard fly --output`` that was flown when the message alone does not say
    (``rates`` travels in SET_ATTITUDE_TARGET like ``attitude``); None: the message's kind.

    Each sample: the ATTITUDE and LOCAL_POSITION_NED the logged command answered become the
    controller's state by ``offboard.codec.measured_state``, the references are the mission's at
    ``t`` and ``t + To``, the controller (``offboard.controllers.make_controller``, as ``offboard
    fly`` builds it) steps, and its command becomes the message fields by
    ``codec.command_setpoint`` (the encoding ``offboard fly`` sends) and ``codec.setpoint_fields``,
    rounded to float32 as the message carries them.

    Parameters
    ----------
    scan : LogScan
    record : FlightRecord
        From ``build_record`` on the same scan, with the mission's trajectory.
    params : ControllerParams
        The controller to run (the flight's, or another to compare).
    trajectory : Trajectory
    scaling : offboard.codec.Scaling
        The vehicle's scaling the commands were normalised by.
    model : VehicleModel
        ``rigid-body`` or ``paper`` (the attitude and torque forms).
    kind : ControllerKind
        Which controller flew (``paper``, ``se3``, ``px4``).
    heading_hold : TakeoffHeadingHold or None
        The flight's take-off heading hold (``TakeoffHeadingHold.as_flown`` from summary.json):
        the references' yaw held as the flight held it.
    predicted_latency_s : float or None
        The latency the flight predicted the law's state over (summary.json's
        ``predicted_latency_s``; an attitude output of the paper's law): the same
        ``LatencyPredictor``, built from ``vehicle_params`` (the vehicle's, as logged), and the
        references taken that far ahead, as ``offboard fly`` does. None: the measured state.
    observed_rate_loop : bool
        Whether that prediction observed the rate loop (summary.json's ``observed_rate_loop``;
        flights before it did not).
    observer_memory_s : float or None
        The observer's memory (summary.json's ``observer_memory_s``; 0, deadbeat, for the flights
        that observed before it); None: ``offboard fly``'s (``InnerLoopModel.observer_memory_s``).
    telemetry_age_s : ndarray or None
        Per sample of ``record``, the telemetry's age the flight handed the prediction (series.csv's
        ``telemetry_age_s``; NaN: none), which the log does not carry to the microsecond.
    """

    output = record.meta.get("commands")
    if output not in RERUN_FIELDS:
        raise LogFormatError(f"{record.meta.get('source') or 'the log'}: no controller commands to compare with "
                             "(SET_ATTITUDE_TARGET or SET_ACTUATOR_CONTROL_TARGET)")
    sent = SetpointOutput(encoding or output)  # the log's message kind is an output's name
    vehicle = record.meta["vehicle_sysid"]
    if not isinstance(vehicle, int):
        raise LogFormatError(f"{record.meta.get('source') or 'the log'}: no vehicle to re-run the controller against")
    setpoints = setpoints_for(scan, vehicle)
    rows = np.asarray(record.meta["setpoint_rows"], dtype=np.int64)
    grid = np.asarray(record.meta["time_boot_ms"], dtype=np.int64)
    i_att, i_pos, att_table, pos_table = _telemetry_rows(scan, vehicle, grid, setpoints.index[rows])
    att, pos = att_table[i_att], pos_table[i_pos]
    to = params.sample_time_s
    predictor = None
    if predicted_latency_s is not None and predicted_latency_s > 0.0 and sent is SetpointOutput.ATTITUDE \
            and kind is ControllerKind.PAPER:  # fmt: skip
        inner = replace(inner_loop_from_params(vehicle_values(dict(vehicle_params or {})), predicted_latency_s),
                        observe=observed_rate_loop, observer_memory_s=observer_memory_s)  # fmt: skip
        predictor = LatencyPredictor(inner, to, params.mass_kg, params.gravity_m_s2)
    controller = make_controller(kind, params, vehicle_model=model, predictor=predictor)
    t_all = record["t_s"]
    builder = RecordBuilder()
    references = ReferencePairs(trajectory, to)
    ahead = ReferencePairs(trajectory, to)
    logged = setpoints.values[rows]
    logged = logged[:, 1:9] if output == "attitude" else logged[:, 0:4]
    rerun = np.full(logged.shape, np.nan, dtype=np.float32)
    states = []  # as the flight's predictor saw them, for the prediction's check
    for k in range(len(rows)):
        a, p = att[k], pos[k]
        measured = codec.measured_state(
            _Msg(time_boot_ms=int(a[0]), roll=a[1], pitch=a[2], yaw=a[3], rollspeed=a[4], pitchspeed=a[5], yawspeed=a[6]),
            _Msg(time_boot_ms=int(p[0]), x=p[1], y=p[2], z=p[3], vx=p[4], vy=p[5], vz=p[6]),
        )
        t = float(t_all[k])
        ref_n, ref_n1 = references.pair(t)
        if heading_hold is not None:
            heading_hold.update(t, float(measured.pos_ned_m[2]))
            ref_n, ref_n1 = heading_hold.apply(ref_n), heading_hold.apply(ref_n1)
        if predictor is not None:  # as Flight._mission_source: the predicted state meets the references of its time
            age = float(telemetry_age_s[k]) if telemetry_age_s is not None else math.nan
            if math.isfinite(age):
                measured = replace(measured, age_s=age)
            states.append(measured)
            ahead_n, ahead_n1 = ahead.pair(t + predictor.latency_s)
            if heading_hold is not None:
                ahead_n, ahead_n1 = heading_hold.apply(ahead_n), heading_hold.apply(ahead_n1)
            command = controller.step(measured, ahead_n, ahead_n1)
        else:
            command = controller.step(measured, ref_n, ref_n1)
        builder.append(**control_row(t, measured, ref_n, command))
        if not command.is_finite():
            continue
        sp = codec.command_setpoint(command, scaling, output=sent, model=model, controller=controller.name)
        rerun[k] = np.array(codec.setpoint_fields(sp), dtype=np.float32)
    steps = np.diff(np.rint(t_all / to).astype(np.int64)) if len(t_all) > 1 else np.zeros(0, dtype=np.int64)
    gaps = int(np.sum(np.maximum(steps - 1, 0)))
    rerun_record = builder.build(phases=record.phases, meta={**record.meta, "rerun": True})
    check = None
    if predictor is not None:  # the flight's prediction against what the vehicle reported then, its setpoints in flight
        headings = np.array([float(m.euler_rad[2]) if params.yaw_aware else 0.0 for m in states])
        check = check_prediction(LatencyPredictor(inner, to, params.mass_kg, params.gravity_m_s2), states,
                                 logged[:, 0:4].astype(float), logged[:, 7].astype(float) * scaling.thrust_max_n, headings,
                                 att_table, pos_table, t_s=t_all, phases=record.phases)  # fmt: skip
    return RerunResult(sent, RERUN_FIELDS[output], np.asarray(t_all, dtype=float), logged.astype(np.float32), rerun,
                       rerun_record, gaps, check)  # fmt: skip


def format_rerun(result: RerunResult, label: str) -> str:
    """The comparison table: per field, logged and re-run ranges, largest and RMS difference."""
    d = result.difference
    if not len(d):
        return f"re-run ({label}): no mission samples in the log to compare"
    lines = [f"re-run ({label}): {len(result.t_s)} samples of {result.output} commands; "
             + ("outputs equal the log exactly (to float32)" if result.exact
                else f"{result.mismatched_samples} samples differ")]
    if result.gaps:
        lines.append(f"  note: {result.gaps} samples are missing from the log; the re-run's memory differs after them")
    lines.append(f"  {'field':<18} {'logged min':>11} {'logged max':>11} {'re-run min':>11} {'re-run max':>11} {'max |diff|':>11} {'rms diff':>10}")
    for i, name in enumerate(result.fields):
        lo, ro = result.logged[:, i].astype(float), result.rerun[:, i].astype(float)
        rms = float(np.sqrt(np.nanmean(d[:, i] ** 2))) if len(d) else 0.0
        lines.append(f"  {name:<18} {np.nanmin(lo):>11.5g} {np.nanmax(lo):>11.5g} {np.nanmin(ro):>11.5g} {np.nanmax(ro):>11.5g} "
                     f"{np.nanmax(d[:, i]):>11.3g} {rms:>10.3g}")
    first = result.first_mismatch()
    if first is not None:
        lines.append(f"  first difference at t = {first[0]:.2f} s in {first[1]}: logged {first[2]:.7g}, re-run {first[3]:.7g}")
    if result.prediction is not None:
        lines += [f"  {line}" for line in result.prediction.describe().splitlines()]
    return "\n".join(lines)


def flight_controller(
    vehicle_params: dict[str, float],
    scaling: codec.Scaling,
    *,
    model: VehicleModel = VehicleModel.RIGID_BODY,
    output: str = "attitude",
    controller_file: Path | None = None,
    summary: dict | None = None,
) -> tuple[ControllerParams, str]:
    """The controller to re-run, and where it came from (docs/replay.md).

    - ``controller_file`` given: that file as ``offboard fly --controller FILE`` would fly it on
      this vehicle (``offboard.flight.resolve_controller``: the file's mass and inertia, thrust
      bounded by the vehicle, its tilt limit or 35 degrees);
    - else the flight's own ``summary.json`` (``summary``): the controller file it names
      (``controller_file``; null or absent: the paper's file believing the vehicle's SIM_*
      values) resolved as ``offboard fly`` resolved it, then overridden by the resolved
      controller the summary records, field by field (older summaries lack some fields);
    - else ``offboard fly``'s default: the paper's file believing the vehicle's SIM_* values,
      read back from the PARAM_VALUE messages in the log, with (attitude or rates output on a
      rigid body) the gains designed for the vehicle's inner loop from the same parameters.

    Returns
    -------
    (ControllerParams, str)
    """

    if controller_file is not None:
        choice = ControllerChoice(base=load_controller(controller_file), from_file=True)
        return resolve_controller(choice, model, vehicle_params, scaling)[0], f"{controller_file} (as offboard fly --controller flies it)"
    recorded = (summary or {}).get("controller")
    flown_file = (summary or {}).get("controller_file")
    flown_choice = (summary or {}).get("controller_choice")
    # offboard fly's default designs the gains where the design applies (offboard.commands.fly)
    default_tuned = model == VehicleModel.RIGID_BODY and output in (SetpointOutput.ATTITUDE, SetpointOutput.RATES)
    tuned = flown_choice == "tuned" or (flown_choice is None and default_tuned and not isinstance(recorded, dict))
    choice = ControllerChoice(base=load_controller(PAPER_CONTROLLER_FILE), tuned=tuned, body_rates=output == SetpointOutput.RATES)
    file_note = f"{PAPER_CONTROLLER_FILE.name} believing the vehicle's SIM_* values" + (", gains designed for it" if choice.tuned else "")
    if isinstance(flown_file, str) and flown_file:
        if Path(flown_file).is_file():
            choice = ControllerChoice(base=load_controller(flown_file), from_file=True)
            file_note = f"controller file {flown_file}"
        elif isinstance(recorded, dict):
            file_note = f"controller file {flown_file} no longer there: the values summary.json records"
        else:
            raise ParameterFileError(f"summary.json: the flight's controller file {flown_file} no longer exists and the "
                                     "summary records no controller; pass --controller FILE (a copy of it)")
    params = resolve_controller(choice, model, vehicle_params, scaling)[0]
    if not isinstance(recorded, dict):
        if summary is not None and "controller_file" in summary:
            return params, f"the flight's ({file_note}, named in summary.json)"
        return params, f"offboard fly's default ({PAPER_CONTROLLER_FILE.name}, the vehicle's SIM_* values from the log)"
    changes: dict[str, object] = {}
    for key in ("sample_time_s", "mass_kg", "arm_length_m", "gravity_m_s2", "euler_rate_form", "drag_to_thrust_m", "yaw_aware",
                "integral_gain_per_s", "integral_limit_m_s", "velocity_integral_gain_per_s2", "velocity_integral_limit_m_s2",
                "tilt_lead", "linear_drag_n_s_m", "velocity_from_position_s", "velocity_integral_hold_s",
                "setpoint_output"):  # fmt: skip
        if key in recorded and recorded[key] is not None:
            changes[key] = recorded[key]
    # a flight recorded before the key existed flew one velocity integral gain on every axis
    up = recorded.get("vertical_velocity_integral_gain_per_s2")
    changes["vertical_velocity_integral_gain_per_s2"] = None if up is None else float(up)
    # a flight recorded before the key existed read its velocity filter at the fixed T
    changes["velocity_from_position_identify"] = bool(recorded.get("velocity_from_position_identify", False))
    if "inertia_kg_m2" in recorded:
        changes["inertia_kg_m2"] = tuple(float(v) for v in recorded["inertia_kg_m2"])
    if "reference_lead_s2" in recorded:
        changes["reference_lead_s2"] = tuple(float(v) for v in recorded["reference_lead_s2"])
    if isinstance(recorded.get("gains"), dict):
        changes["gains"] = ControllerGains(**{k: float(v) for k, v in recorded["gains"].items()})
    if any(k in recorded for k in ("thrust_min_n", "thrust_max_n", "tilt_max_deg")):
        tilt = recorded.get("tilt_max_deg")
        changes["limits"] = ActionLimits(
            thrust_min_n=recorded.get("thrust_min_n"),
            thrust_max_n=recorded.get("thrust_max_n"),
            tilt_max_rad=None if tilt is None else math.radians(float(tilt)),
            tilt_cone=bool(recorded.get("tilt_cone", False)),
            speed_xy_max_m_s=recorded.get("speed_xy_max_m_s"),
            speed_up_max_m_s=recorded.get("speed_up_max_m_s"),
            speed_down_max_m_s=recorded.get("speed_down_max_m_s"),
            yaw_rate_max_rad_s=recorded.get("yaw_rate_max_rad_s"),
            rate_carry_s=float(recorded.get("rate_carry_s") or 0.0),  # a flight before the key: none
        )
    return params.with_changes(**changes), f"the flight's (summary.json beside the log; {file_note})"


def rerun_panels(result: RerunResult, thrust_max_n: float) -> list[tuple[str, np.ndarray, np.ndarray, tuple[str, ...]]]:
    """The comparison figure's panels in physical units (``offboard.plots.comparison_figure``)."""
    def euler_deg(values: np.ndarray) -> np.ndarray:
        return np.degrees(np.array([euler_from_quat(q) for q in values[:, 0:4]]).reshape(-1, 3))

    scale = thrust_max_n if math.isfinite(thrust_max_n) else 1.0
    thrust_label = "u [N]" if math.isfinite(thrust_max_n) else "thrust (normalised)"
    logged, rerun = result.logged.astype(float), result.rerun.astype(float)
    if result.output in (SetpointOutput.ATTITUDE, SetpointOutput.RATES):  # both SET_ATTITUDE_TARGET
        a, b = euler_deg(logged), euler_deg(rerun)
        return [
            ("x7ez roll ref [deg]", a[:, 0], b[:, 0], ("roll",)),
            ("x9ez pitch ref [deg]", a[:, 1], b[:, 1], ("pitch",)),
            ("yaw ref [deg]", a[:, 2], b[:, 2], ("yaw",)),
            ("body rate refs [rad/s]", logged[:, 4:7], rerun[:, 4:7], ("p", "q", "r")),
            (thrust_label, logged[:, 7] * scale, rerun[:, 7] * scale, ("u",)),
        ]
    return [
        ("torques (normalised)", logged[:, 0:3], rerun[:, 0:3], ("roll", "pitch", "yaw")),
        (thrust_label, logged[:, 3] * scale, rerun[:, 3] * scale, ("u",)),
    ]
