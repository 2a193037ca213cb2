"""The controller a flight flies: the user's choice (``ControllerChoice``), which of the vehicle's
parameters it needs (``params_to_read``), and the controller resolved from both
(``resolve_controller``). Pure: no link, no clock; ``offboard tune``, ``offboard replay``'s re-run
and the benchmarks resolve a controller the way ``offboard fly`` does through these.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

from offboard import codec
from offboard.codec import Scaling, SetpointOutput
from offboard.controller import ControllerParams
from offboard.controller.design import SENSITIVITY_PEAK, MarginSpec
from offboard.controller.tuning import AUTOPILOT_PARAMS, SIH_PARAMS, design_for_vehicle, design_summary, tuned_params, vehicle_values
from offboard.controllers import CONTROLLER_KINDS, ControllerKind
from offboard.flight.config import FlightConfig, HeadingHoldMode
from offboard.flight.heading_hold import HEADING_ALIGN_PARAMS
from offboard.model.vehicle import VehicleModel

#: Tilt limit on x7ez, x9ez when neither the command line nor the controller file gives one (deg).
DEFAULT_TILT_MAX_DEG = 35.0
#: Default lower bound of u on a rigid body, as a fraction of SIM_THR_MAX: PX4's MPC_THR_MIN.
#: With rotors, zero thrust means zero torque authority; at the paper's descent step the law asks
#: for u < 0 and a vehicle at u = 0 tumbles (docs/offboard.md). The paper's model has no rotors: 0.
RIGID_BODY_THRUST_MIN_FRACTION = 0.12


@dataclass(frozen=True)
class ControllerChoice:
    """The controller as the user chose it, before the vehicle's parameters are known.

    Attributes
    ----------
    base : ControllerParams
        The controller file's parameters (``paper.toml`` when none was given).
    from_file : bool
        Whether the user gave ``--controller``: its mass, arm and inertia are then the
        controller's belief (Table II makes them differ from the vehicle on purpose).
    mass_from_vehicle : bool
        Use SIM_MASS even with a controller file.
    yaw_aware : bool or None
        Explicit choice; None: the file's when given, else on for a rigid body, off for the
        paper's model.
    tilt_max_deg : float or None
        Explicit tilt limit on x7ez, x9ez (>= 90: none); None: the file's, else 35 degrees.
    thrust_min_fraction : float or None
        Explicit lower bound of u as a fraction of SIM_THR_MAX; None: the file's, else 0.12 on a
        rigid body (PX4's MPC_THR_MIN) and 0 on the paper's model.
    sample_time_s : float or None
        Explicit To; None: the file's.
    tuned : bool
        Design kx1..kx6 for the vehicle's inner loop from its parameters (``offboard fly``
        without ``--controller``; docs/controller-design.md) instead of flying the base's gains.
    latency_s : float or None
        The latency the design assumes (s); None: measured at start-up, the TIMESYNC round trip
        plus one telemetry period (0 in lockstep, where the vehicle waits for each setpoint).
    velocity_integral : bool
        With ``tuned``: design the law's velocity integral too (``--no-integral``: without).
    sensitivity_peak : float
        With ``tuned``: the design's bound on max |1/(1+L)| (``--sensitivity-peak``; inf: none).
    body_rates : bool
        With ``tuned``: design for a body-rate output (``--output rates``: the law closes the
        attitude loop, its kx7..kx10 designed too).
    predict : bool
        With ``tuned``, an attitude output and a latency > 0: hand the law the state predicted
        over the latency and design the gains for that (``offboard.controller.prediction``;
        ``--no-predict``: the measured state, the gains designed for the latency).
    observe : bool
        With ``predict``: observe the autopilot's rate-loop integral and motor torque from how the
        tilt and the body rate moved against the inner loop's model (``InnerLoopModel.observe``;
        ``--no-observe``: taken at hover).
    kind : ControllerKind
        Which controller flies (``offboard.controllers``): ``paper`` (the law, with ``base``'s
        gains or the designed ones), ``se3`` or ``px4``; all believe the resolved parameters.
    """

    base: ControllerParams
    kind: ControllerKind = ControllerKind.PAPER
    from_file: bool = False
    tuned: bool = False
    latency_s: float | None = None
    mass_from_vehicle: bool = False
    yaw_aware: bool | None = None
    tilt_max_deg: float | None = None
    thrust_min_fraction: float | None = None
    sample_time_s: float | None = None
    velocity_integral: bool = True
    sensitivity_peak: float = SENSITIVITY_PEAK
    body_rates: bool = False
    predict: bool = True
    observe: bool = True

    @property
    def predicts(self) -> bool:
        """Whether the flight hands the law the predicted state (``predict``'s conditions)."""
        return self.predict and self.tuned and not self.body_rates and (self.latency_s or 0.0) > 0.0

    @property
    def observes(self) -> bool:
        """Whether the prediction observes the rate loop (``observe``, when it ``predicts``)."""
        return self.observe and self.predicts

    def __post_init__(self) -> None:
        if self.kind not in CONTROLLER_KINDS:
            raise ValueError(f"controller must be one of {CONTROLLER_KINDS}, got {self.kind!r}")
        object.__setattr__(self, "kind", ControllerKind(self.kind))  # a caller's word: its enum


#: Parameters read from the vehicle: name -> why.
VEHICLE_PARAMS = {
    "SIM_THR_MAX": "thrust at normalised thrust 1 (N)",
    "SIM_TQ_RP_MAX": "roll/pitch torque at normalised torque 1 (N m)",
    "SIM_TQ_Y_MAX": "yaw torque at normalised torque 1 (N m)",
    "SIM_MASS": "vehicle mass (kg)",
    "SIM_ARM_LEN": "arm length (m)",
    "SIM_IXX": "inertia (kg m^2)",
    "SIM_IYY": "inertia (kg m^2)",
    "SIM_IZZ": "inertia (kg m^2)",
    "SIM_KM_KF": "rotor drag-to-thrust (m)",
    "COM_OF_LOSS_T": "the vehicle's offboard-loss timeout (s)",
    "PAP_TO": "the paper inner loop's To (s)",
    "SIM_MOT_TAU": "motor time constant (s)",
    "SIM_KDV": "linear drag (N s/m)",
    "SIH_MASS": "PX4 SIH vehicle mass (kg)",
    "SIH_T_MAX": "PX4 SIH thrust of one rotor at full throttle (N)",
}
VEHICLE_PARAMS.update({name: "PX4's inner loop and speed limits (the tuned design)" for name in AUTOPILOT_PARAMS})
VEHICLE_PARAMS.update({name: "whether EKF2 aligns its heading in flight (the take-off heading hold)" for name in HEADING_ALIGN_PARAMS})
VEHICLE_PARAMS.update({name: "PX4 SIH's vehicle" for name in SIH_PARAMS if name not in VEHICLE_PARAMS})

def params_to_read(choice: ControllerChoice, config: FlightConfig, thrust_max_given: bool,
                   family: str = "SIM") -> tuple[list[str], list[str]]:  # fmt: skip
    """(required, optional) parameter names for this flight, for a vehicle of ``family``."""
    required: list[str] = []
    optional = ["COM_OF_LOSS_T"] + (["PAP_TO"] if family == "SIM" else [])
    if not thrust_max_given:
        required.append("SIH_T_MAX" if family == "SIH" else "SIM_THR_MAX")
    if config.output == SetpointOutput.ACTUATOR:
        required += ["SIM_TQ_RP_MAX", "SIM_TQ_Y_MAX"]
    mass = "SIH_MASS" if family == "SIH" else "SIM_MASS"
    if not choice.from_file:
        if family == "SIH":
            optional = [n for n in SIH_PARAMS if n not in required] + optional
        elif family == "SIM":
            optional = ["SIM_MASS", "SIM_ARM_LEN", "SIM_IXX", "SIM_IYY", "SIM_IZZ", "SIM_KM_KF", "SIM_KDV", *optional]
    elif choice.mass_from_vehicle:
        required.append(mass)
    if choice.tuned:
        if family == "SIM":
            optional += ["SIM_TQ_RP_MAX", "SIM_MOT_TAU"]
        optional += list(AUTOPILOT_PARAMS)
    if config.takeoff_heading_hold == HeadingHoldMode.AUTO and family != "SIM":  # sitl-plant has no EKF2 to ask about
        optional += list(HEADING_ALIGN_PARAMS)
    return required, [n for n in dict.fromkeys(optional) if n not in required]


def resolve_controller(
    choice: ControllerChoice, model: VehicleModel, vehicle: Mapping[str, float], scaling: Scaling
) -> tuple[ControllerParams, list[str]]:
    """The controller flown, from the user's choice and the vehicle's parameters.

    Precedence (docs/offboard.md): an explicit command-line option, then the controller file,
    then the vehicle (without a controller file the controller believes the vehicle's SIM_*
    values: Simulation 1), then the paper's values. Thrust is always bounded to what the vehicle
    can do, ``[max(file's min, 0), min(file's max, SIM_THR_MAX)]``, so that the law and the
    vehicle agree on u; without a file's minimum, a rigid body keeps 12 % of SIM_THR_MAX (PX4's
    MPC_THR_MIN: torque authority) and the paper's model 0; the tilt limit defaults to 35 degrees.

    With ``choice.tuned`` the gains kx1..kx6 are then designed for the vehicle's inner loop
    (``offboard.controller.tuning``), with the tilt bounded as a cone and the desired speeds by
    the vehicle's MPC_*_VEL_MAX.

    Returns
    -------
    (ControllerParams, notes)
        ``notes`` say, one line each, where the believed values came from.

    Raises
    ------
    ValueError
        ``choice.tuned`` and the vehicle publishes no model to design for (a real airframe).
    """
    vehicle = vehicle_values(vehicle)
    base = choice.base
    notes: list[str] = []
    changes: dict[str, object] = {"euler_rate_form": codec.euler_rate_form_for(model, base.euler_rate_form)}
    use_vehicle_model = not choice.from_file
    if use_vehicle_model or choice.mass_from_vehicle:
        if "SIM_MASS" in vehicle:
            changes["mass_kg"] = float(vehicle["SIM_MASS"])
            notes.append(f"mass {vehicle['SIM_MASS']:.4g} kg from the vehicle (SIM_MASS)")
        else:
            notes.append(f"the vehicle publishes no SIM_MASS: mass {base.mass_kg:.4g} kg from the controller file")
    if use_vehicle_model:
        if "SIM_ARM_LEN" in vehicle:
            changes["arm_length_m"] = float(vehicle["SIM_ARM_LEN"])
        if all(k in vehicle for k in ("SIM_IXX", "SIM_IYY", "SIM_IZZ")):
            changes["inertia_kg_m2"] = (float(vehicle["SIM_IXX"]), float(vehicle["SIM_IYY"]), float(vehicle["SIM_IZZ"]))
        if "SIM_KM_KF" in vehicle:
            changes["drag_to_thrust_m"] = float(vehicle["SIM_KM_KF"])
        if "SIM_KDV" in vehicle:  # the linear drag: sitl-plant's, or PX4 SIH's SIH_KDV (tuning.vehicle_values)
            changes["linear_drag_n_s_m"] = float(vehicle["SIM_KDV"])
    if choice.sample_time_s is not None:
        changes["sample_time_s"] = float(choice.sample_time_s)
    if choice.yaw_aware is not None:
        changes["yaw_aware"] = choice.yaw_aware
    elif not choice.from_file:
        changes["yaw_aware"] = model == VehicleModel.RIGID_BODY
    limits = base.limits
    if choice.thrust_min_fraction is not None:
        thrust_min = choice.thrust_min_fraction * scaling.thrust_max_n
    elif limits.thrust_min_n is not None:
        thrust_min = max(limits.thrust_min_n, 0.0)
    else:
        thrust_min = (RIGID_BODY_THRUST_MIN_FRACTION if model == VehicleModel.RIGID_BODY else 0.0) * scaling.thrust_max_n
    thrust_max = scaling.thrust_max_n if limits.thrust_max_n is None else min(limits.thrust_max_n, scaling.thrust_max_n)
    if choice.tilt_max_deg is not None:
        tilt = None if choice.tilt_max_deg >= 90.0 else math.radians(choice.tilt_max_deg)
    elif limits.tilt_max_rad is not None:
        tilt = limits.tilt_max_rad
    else:
        tilt = math.radians(DEFAULT_TILT_MAX_DEG)
    # the file's other bounds (a tuned file's tilt cone, speed and yaw-rate bounds) stay as it has them
    changes["limits"] = replace(limits, thrust_min_n=thrust_min, thrust_max_n=thrust_max, tilt_max_rad=tilt)
    params = base.with_changes(**changes)
    if choice.tuned:
        try:
            design = design_for_vehicle(vehicle, sample_time_s=params.sample_time_s, latency_s=choice.latency_s or 0.0,
                                        velocity_integral=choice.velocity_integral, body_rates=choice.body_rates,
                                        predict=choice.predicts, observe=choice.observes,
                                        spec=MarginSpec(sensitivity_peak=choice.sensitivity_peak))  # fmt: skip
        except KeyError as exc:
            raise ValueError(f"cannot design the gains: {exc.args[0]}; fly a controller file (offboard tune "
                             "--params FILE writes one) or --controller paper") from None
        params = tuned_params(params, design, vehicle)
        predicted = (", the law handed the state predicted over it" + (", the rate loop observed" if design.model.observe else "")
                     if design.model.predict else "")  # fmt: skip
        notes.append(f"gains designed for the vehicle's inner loop ({design.model.source}, latency "
                     f"{(choice.latency_s or 0.0) * 1000:.0f} ms{predicted}; docs/controller-design.md):")
        notes.extend(f"  {line}" for line in design_summary(design))
    tilt_text = "none" if tilt is None else f"{math.degrees(tilt):.0f} deg"
    notes.append(
        f"controller: To {params.sample_time_s:g} s, W_eta {params.euler_rate_form}, yaw-aware {'on' if params.yaw_aware else 'off'}, "
        f"u in [{thrust_min:.3g}, {thrust_max:.4g}] N, tilt limit {tilt_text}"
    )
    return params, notes
