"""MAV_CMD_PREFLIGHT_CALIBRATION (241) as PX4 v1.16 SITL answers it (commander's
``handle_command`` / ``calibration_routines``; measured, docs/parity/services.md).

Measured on PX4 v1.16 SITL (SIH), each in a fresh PX4 over its API link: gyro (param1 = 1),
baro (param3 = 1), accel (param5 = 1) and level (param5 = 2) are ACCEPTED; while armed the
command is TEMPORARILY_REJECTED. PX4 v1.16 reports progress with MAVLink events (EVENT), not
"[cal] ..." STATUSTEXTs: none came on the API link. A simulated vehicle has nothing to
calibrate, so here each calibration is done at once (PX4 SITL's baro calibration never ends
and keeps refusing arming and other calibrations; the plant does not copy that).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

#: (parameter index, value) -> what it calibrates (MAV_CMD_PREFLIGHT_CALIBRATION's params)
KINDS = {(0, 1): "gyro", (1, 1): "mag", (2, 1): "baro", (4, 1): "accel", (4, 2): "level"}


def calibration_kind(params: tuple[float, ...]) -> str | None:
    """Which calibration ``params`` ask for (the first set one), or None (none, or unknown)."""
    for i, p in enumerate(params[:7]):
        if not math.isfinite(p) or round(p) == 0:
            continue
        return KINDS.get((i, round(p)))
    return None


def calibration_result(params: tuple[float, ...], armed: bool) -> int:
    """The MAV_RESULT for a PREFLIGHT_CALIBRATION with ``params``."""
    if armed:
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    if calibration_kind(params) is None:
        return mavlink.MAV_RESULT_UNSUPPORTED
    return mavlink.MAV_RESULT_ACCEPTED
