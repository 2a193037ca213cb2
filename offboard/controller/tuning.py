"""The law's gains designed for a vehicle from its published parameters, as a controller file.

``design.py`` does the analysis; this module reads what it needs from a vehicle's parameters
(sitl-plant's ``SIM_*`` or PX4 SIH's ``SIH_*``, and PX4's ``MC_*``/``MPC_*``), puts the designed
gains and the bounds the design assumes into ``ControllerParams``, and writes them as a
controller file (``offboard tune``; ``offboard fly`` without ``--controller`` does the same at
start-up). Pure: no I/O beyond returning text.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

from offboard.baselines.se3 import SE3Gains
from offboard.controller.design import (
    AxisGains,
    Design,
    InnerLoopModel,
    MarginSpec,
    analyse_axis,
    angle_stage_plants,
    axis_plants,
    design_gains,
    inner_loop_from_params,
    pd_analysis,
    rate_carry_s,
    step_hold_s,
)
from offboard.controller.params import ControllerGains, ControllerParams

#: PX4's attitude/rate gains and speed limits the design reads (PX4's defaults where missing).
AUTOPILOT_PARAMS = (
    "MC_ROLL_P", "MC_PITCH_P", "MC_ROLLRATE_P", "MC_ROLLRATE_I", "MC_ROLLRATE_D",
    "MC_PITCHRATE_P", "MC_PITCHRATE_I", "MC_PITCHRATE_D",
    "MPC_XY_VEL_MAX", "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN", "MPC_YAWRAUTO_MAX",
)  # fmt: skip
#: sitl-plant's physical values.
PLANT_PARAMS = ("SIM_THR_MAX", "SIM_TQ_RP_MAX", "SIM_TQ_Y_MAX", "SIM_MASS", "SIM_ARM_LEN", "SIM_IXX", "SIM_IYY",
                "SIM_IZZ", "SIM_KM_KF", "SIM_MOT_TAU", "SIM_KDV")  # fmt: skip
#: PX4 SIH's (its README: SIH_T_MAX is per rotor, CA_ROTOR_COUNT rotors).
SIH_PARAMS = ("SIH_MASS", "SIH_T_MAX", "SIH_Q_MAX", "SIH_IXX", "SIH_IYY", "SIH_IZZ", "SIH_L_ROLL", "SIH_L_PITCH",
              "SIH_T_TAU", "SIH_KDV", "CA_ROTOR_COUNT")  # fmt: skip

#: T of the designed controller's velocity filter (``[law] velocity_from_position_s``,
#: ``offboard.controller.velocity``), s. PX4 SIH's EKF2 velocity departs from its position's
#: derivative by 0.12-0.20 m/s RMS with a correlation time of 1.5-2 s (docs/controller-design.md);
#: T a quarter of that removes the slow part, and spans 10 samples at 20 Hz, so that a
#: derivative's white noise is averaged over them. Where the two agree it changes nothing.
#: (``velocity_from_position_identify`` chooses T in flight from the estimates' noise instead: on
#: PX4 SIH it reads the velocity closer to the truth but has not held steadier; the same
#: document has the flights.)
VELOCITY_FROM_POSITION_S = 0.5

#: PX4's defaults of the speed limits (mc_pos_control params).
PX4_SPEED_DEFAULTS = {"MPC_XY_VEL_MAX": 12.0, "MPC_Z_VEL_MAX_UP": 3.0, "MPC_Z_VEL_MAX_DN": 1.5, "MPC_YAWRAUTO_MAX": 45.0}


def vehicle_values(params: Mapping[str, float]) -> dict[str, float]:
    """The vehicle's physical values under sitl-plant's names, from SIM_* or PX4 SIH's SIH_*.

    SIH: ``SIM_MASS = SIH_MASS``, ``SIM_I** = SIH_I**``, ``SIM_ARM_LEN = SIH_L_ROLL``,
    ``SIM_THR_MAX = SIH_T_MAX * CA_ROTOR_COUNT`` (4 when not published), ``SIM_MOT_TAU =
    SIH_T_TAU``, ``SIM_KDV = SIH_KDV`` (linear drag, N s/m). Values already under SIM_* names win.
    """
    out = {k: float(v) for k, v in params.items()}
    if "SIH_MASS" in params:
        rotors = float(params.get("CA_ROTOR_COUNT", 4))
        mapping = {"SIM_MASS": "SIH_MASS", "SIM_IXX": "SIH_IXX", "SIM_IYY": "SIH_IYY", "SIM_IZZ": "SIH_IZZ",
                   "SIM_ARM_LEN": "SIH_L_ROLL", "SIM_MOT_TAU": "SIH_T_TAU", "SIM_KDV": "SIH_KDV"}  # fmt: skip
        for sim, sih in mapping.items():
            if sih in params and sim not in out:
                out[sim] = float(params[sih])
        if "SIH_T_MAX" in params and "SIM_THR_MAX" not in out:
            out["SIM_THR_MAX"] = float(params["SIH_T_MAX"]) * rotors
    return out


def design_for_vehicle(params: Mapping[str, float], *, sample_time_s: float, latency_s: float = 0.0,
                       spec: MarginSpec | None = None, velocity_integral: bool = True, body_rates: bool = False,
                       predict: bool = False, observe: bool = False) -> Design:  # fmt: skip
    """The design for a vehicle's parameters (``design.inner_loop_from_params``, ``design_gains``),
    with the velocity integral unless ``velocity_integral`` is False; with ``body_rates``, for a
    body-rate output (the law's angle gains designed too); with ``predict`` (an attitude output
    and a latency > 0), for the law handed the state predicted over the latency
    (``offboard.controller.prediction``), with ``observe`` its rate loop observed
    (``InnerLoopModel.observe``).

    Raises
    ------
    KeyError
        The parameters lack the inertia or torque scale (a real airframe: use a vehicle file).
    ValueError
        No gains meet the margins.
    """
    model: InnerLoopModel = inner_loop_from_params(params, latency_s)
    if predict and latency_s > 0.0 and not body_rates:
        model = replace(model, predict=True, observe=observe)
    return design_gains(model, sample_time_s, spec, velocity_integral=velocity_integral, body_rates=body_rates)


def tuned_params(base: ControllerParams, design: Design, params: Mapping[str, float]) -> ControllerParams:
    """``base`` with the designed gains (kx1..kx6) and the bounds the design assumes.

    The integral action and the tilt lead are the design's. The bounds: the thrust axis's tilt as a cone (``ActionLimits.tilt_cone``) and the desired
    speeds bounded by the autopilot's own MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN and
    the yaw reference's rate by MPC_YAWRAUTO_MAX (PX4's defaults when not published), so that a
    step in the reference is flown in the range the linear design holds for (a pi yaw step
    while tilted to the bound made the attitude loop overshoot it by 5 deg). The angle gains
    kx7..kx12 stay, unless the design is for a body-rate output: through an attitude setpoint the
    autopilot closes the attitude loop, and they act only with the paper's own inner loop; with
    body rates the law closes it, with the designed kx7..kx10 (``design.model.angle_gains``).
    """
    h, v = design.horizontal, design.vertical
    gains = replace(base.gains, kx1=float(h.k_pos), kx2=float(h.k_vel), kx3=float(h.k_pos), kx4=float(h.k_vel),
                    kx5=float(v.k_pos), kx6=float(v.k_vel))  # fmt: skip
    angle = design.model.angle_gains
    if angle is not None:
        k7, k8 = float(angle.k_pos), float(angle.k_vel)
        gains = replace(gains, kx7=k7, kx8=k8, kx9=k7, kx10=k8)
    speed = {k: float(params.get(k, v)) for k, v in PX4_SPEED_DEFAULTS.items()}
    m = design.model
    limits = replace(
        base.limits,
        tilt_cone=True,
        speed_xy_max_m_s=speed["MPC_XY_VEL_MAX"],
        speed_up_max_m_s=speed["MPC_Z_VEL_MAX_UP"],
        speed_down_max_m_s=speed["MPC_Z_VEL_MAX_DN"],
        yaw_rate_max_rad_s=math.radians(speed["MPC_YAWRAUTO_MAX"]),
        # the body-rate output bounds the rates it hands on by what the rate loop carries past them
        rate_carry_s=round(max(rate_carry_s(m.roll), rate_carry_s(m.pitch)) + m.latency_s, 4) if angle is not None else 0.0,
    )
    return base.with_changes(gains=gains, limits=limits, sample_time_s=design.sample_time_s, tilt_lead=float(h.lead),
                             integral_gain_per_s=float(h.integral_per_s),
                             velocity_integral_gain_per_s2=float(h.velocity_integral_per_s2),
                             vertical_velocity_integral_gain_per_s2=float(v.velocity_integral_per_s2),
                             reference_lead_s2=tuple(round(v, 6) for v in design.reference_lead_s2),
                             velocity_integral_hold_s=round(step_hold_s(design), 4) if h.velocity_integral_per_s2 else 0.0,
                             velocity_from_position_s=VELOCITY_FROM_POSITION_S,
                             setpoint_output="attitude" if angle is None else "rates")


def design_summary(design: Design) -> list[str]:
    """One line per axis: gains, poles, margins (what ``offboard tune`` prints); first, for a
    body-rate output, the law's angle stage."""
    lines = []
    angle = design.model.angle_gains
    if angle is not None:
        to = design.sample_time_s
        a = analyse_axis(angle_stage_plants(design.model, to)[0], angle, to)
        lines.append(
            f"{'angles (rates)':14s} kx7 = kx9 {float(angle.k_pos):.4g} kx8 = kx10 {float(angle.k_vel):.4g} on the rate loop: "
            f"|pole| max {a.spectral_radius:.3f} (2 % in {a.settling_time_s:.2f} s), gain margin {a.gain_margin:.2f}, "
            f"phase margin {a.phase_margin_deg:.1f} deg, delay margin {a.delay_margin_s * 1000:.0f} ms, sensitivity peak "
            f"{a.sensitivity_peak:.2f}"
        )
    for name, a in (("north (pitch)", design.north), ("east (roll)", design.east), ("up (thrust)", design.up)):
        g = a.gains
        lines.append(
            f"{name:14s} k_pos {float(g.k_pos):.4g} k_vel {float(g.k_vel):.4g} tilt lead {float(g.lead):g} velocity "
            f"integral {float(g.velocity_integral_per_s2):.3g}/s^2: |pole| max {a.spectral_radius:.3f} "
            f"(2 % in {a.settling_time_s:.2f} s), gain margin {a.gain_margin:.2f}, phase margin "
            f"{a.phase_margin_deg:.1f} deg, delay margin {a.delay_margin_s * 1000:.0f} ms, sensitivity peak {a.sensitivity_peak:.2f}"
        )
    return lines


def paper_gains_summary(design: Design) -> str:
    """One line: Table I's horizontal gains on the same model, for comparison."""

    table1 = ControllerGains()
    model = design.model
    if model.angle_gains is not None:  # body rates: Table I's own angle stage too
        model = replace(model, angle_gains=AxisGains(table1.kx7, table1.kx8))
    north, _, _ = axis_plants(model, design.sample_time_s)
    a = analyse_axis(north, AxisGains(table1.kx1, table1.kx2), design.sample_time_s)
    angles = f", kx7 {table1.kx7:g}, kx8 {table1.kx8:g}" if design.model.angle_gains is not None else ""
    head = f"Table I (kx1 {table1.kx1:g}, kx2 {table1.kx2:g}{angles}) on this loop:"
    if a.spectral_radius >= 1.0:
        return f"{head} UNSTABLE, |pole| max {a.spectral_radius:.3f}"
    return f"{head} |pole| max {a.spectral_radius:.3f}, gain margin {a.gain_margin:.2f}, phase margin {a.phase_margin_deg:.1f} deg"


def se3_gains_summary(design: Design) -> str:
    """One line: SE(3)'s horizontal position loop (RotorPy's gains, ``offboard.baselines.SE3Gains``)
    on the same model, for comparison (``design.pd_analysis``)."""

    gains = SE3Gains()
    north, _, _ = axis_plants(design.model, design.sample_time_s)
    rho, gm, pm, dm = pd_analysis(north, gains.kx[0], gains.kv[0], design.sample_time_s)
    head = f"SE(3) (kx {gains.kx[0]:g}/s^2, kv {gains.kv[0]:g}/s) on this loop:"
    if rho >= 1.0:
        return f"{head} UNSTABLE, |pole| max {rho:.3f}"
    return f"{head} |pole| max {rho:.3f}, gain margin {gm:.2f}, phase margin {pm:.1f} deg, delay margin {dm * 1000:.0f} ms"


def _fmt(value: float) -> str:
    return repr(float(value)) if math.isfinite(value) else "nan"


def controller_file_text(params: ControllerParams, design: Design, *, source: str) -> str:
    """A controller file (the layout of ``paper.toml``) with the design's figures as comments."""
    g, lim = params.gains, params.limits
    m = design.model
    lines = [
        "# The law's gains designed by `offboard tune` for a vehicle and its inner loop",
        f"# (docs/controller-design.md), from {source}.",
        f"# Model: {m.source}; latency {m.latency_s * 1000:.0f} ms; roll P {m.roll.attitude_p_per_s:g}/s, rate P/I/D "
        f"{m.roll.rate_p:g}/{m.roll.rate_i:g}/{m.roll.rate_d:g}, {m.roll.torque_per_unit_nm:.4g} N m at torque 1, "
        f"Ixx {m.roll.inertia_kg_m2:.4g} kg m^2, motor lag {m.roll.motor_time_constant_s * 1000:.0f} ms"
        + (" (the roll P unused: designed for a body-rate output, fly it with --output rates)." if m.angle_gains is not None else "."),
        f"# Required: gain margin {design.spec.gain_margin:g}, phase margin {design.spec.phase_margin_deg:g} deg, "
        f"delay margin {design.spec.delay_margin_s * 1000:.0f} ms, sensitivity peak {design.spec.sensitivity_peak:g}. Achieved:",
        *(f"#   {line}" for line in design_summary(design)),
        "",
        "[law]",
        *([f"# the setpoint these gains were designed for: offboard fly flies them with --output {params.setpoint_output}",
           f'setpoint_output = "{params.setpoint_output}"'] if params.setpoint_output is not None else []),
        f"sample_time_s = {_fmt(params.sample_time_s)}",
        f"yaw_aware = {'true' if params.yaw_aware else 'false'}",
        f"integral_gain_per_s = {_fmt(params.integral_gain_per_s)}",
        f"integral_limit_m_s = {_fmt(params.integral_limit_m_s)}",
        f"velocity_integral_gain_per_s2 = {_fmt(params.velocity_integral_gain_per_s2)}",
        *([] if params.vertical_velocity_integral_gain_per_s2 is None else [
            "# the vertical axis's own (designed with the vertical loop)",
            f"vertical_velocity_integral_gain_per_s2 = {_fmt(params.vertical_velocity_integral_gain_per_s2)}"]),
        f"velocity_integral_limit_m_s2 = {_fmt(params.velocity_integral_limit_m_s2)}",
        "# after a reference step the velocity integral holds until settled, at most this long (s)",
        f"velocity_integral_hold_s = {_fmt(params.velocity_integral_hold_s)}",
        "# the attitude setpoint is x7ez, x9ez led past the measured angles by this factor",
        f"tilt_lead = {_fmt(params.tilt_lead)}",
        "# c2 of the closed loop's reference response T = 1 + c2 s^2: the law is handed r - c2 r''",
        f"reference_lead_s2 = [{_fmt(params.reference_lead_s2[0])}, {_fmt(params.reference_lead_s2[1])}]",
        "# T of the filter that makes the velocity read consistent with the position tracked (0: as measured)",
        f"velocity_from_position_s = {_fmt(params.velocity_from_position_s)}",
        "# T chosen in flight from the estimates' own noise (the Kalman filter of their velocity bias), the above until then",
        f"velocity_from_position_identify = {'true' if params.velocity_from_position_identify else 'false'}",
        "",
        "[model]                # the vehicle as the controller believes it",
        f"mass_kg = {_fmt(params.mass_kg)}",
        f"arm_length_m = {_fmt(params.arm_length_m)}",
        f"inertia_kg_m2 = [{', '.join(_fmt(v) for v in params.inertia_kg_m2)}]",
        f"gravity_m_s2 = {_fmt(params.gravity_m_s2)}",
        f'euler_rate_form = "{params.euler_rate_form}"',
        f"drag_to_thrust_m = {_fmt(params.drag_to_thrust_m)}",
        f"linear_drag_n_s_m = {_fmt(params.linear_drag_n_s_m)}",
        "",
        "[gains]                # kx1..kx6 designed; kx7..kx12 Table I's (the autopilot closes the attitude loop)"
        if m.angle_gains is None else "[gains]                # kx1..kx10 designed (body rates: the law closes the attitude loop); kx11, kx12 Table I's",
        *(f"kx{i} = {_fmt(getattr(g, f'kx{i}'))}" for i in range(1, 13)),
        "",
        "[limits]               # the range the linear design holds for",
    ]
    if lim.thrust_min_n is not None:
        lines.append(f"thrust_min_n = {_fmt(lim.thrust_min_n)}")
    if lim.thrust_max_n is not None:
        lines.append(f"thrust_max_n = {_fmt(lim.thrust_max_n)}")
    if lim.tilt_max_rad is not None:
        lines.append(f"tilt_max_deg = {_fmt(round(math.degrees(lim.tilt_max_rad), 6))}")
    lines.append(f"tilt_cone = {'true' if lim.tilt_cone else 'false'}")
    for name in ("speed_xy_max_m_s", "speed_up_max_m_s", "speed_down_max_m_s", "yaw_rate_max_rad_s"):
        value = getattr(lim, name)
        if value is not None:
            lines.append(f"{name} = {_fmt(value)}")
    if lim.rate_carry_s > 0.0:
        lines += ["# the body rates are bounded so that neither angle passes tilt_max_deg: the rate loop carries a",
                  "# rate this long after its setpoint drops, latency included", f"rate_carry_s = {_fmt(lim.rate_carry_s)}"]
    return "\n".join(lines) + "\n"


__all__ = [
    "AUTOPILOT_PARAMS",
    "PLANT_PARAMS",
    "SIH_PARAMS",
    "controller_file_text",
    "design_for_vehicle",
    "design_summary",
    "tuned_params",
    "vehicle_values",
]
