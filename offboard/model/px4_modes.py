"""PX4's flight modes as its HEARTBEAT carries them (``px4_custom_mode.h``): the main and sub mode
numbers, their names, and the ``custom_mode`` word that packs them. One table for both sides:
the offboard reads a vehicle's modes with it (``offboard.codec``, ``offboard.replay``), the plant
publishes its own (``sitl_plant.autopilot.Mode``).
"""

from __future__ import annotations

#: PX4_CUSTOM_MAIN_MODE_*
MAIN_MANUAL = 1
MAIN_ALTCTL = 2
MAIN_POSCTL = 3
MAIN_AUTO = 4
MAIN_ACRO = 5
MAIN_OFFBOARD = 6
MAIN_STABILIZED = 7
MAIN_RATTITUDE = 8
MAIN_TERMINATION = 10  # PX4 v1.15+: flight termination
#: PX4_CUSTOM_SUB_MODE_AUTO_*
SUB_AUTO_READY = 1
SUB_AUTO_TAKEOFF = 2
SUB_AUTO_LOITER = 3
SUB_AUTO_MISSION = 4
SUB_AUTO_RTL = 5
SUB_AUTO_LAND = 6
SUB_AUTO_FOLLOW_TARGET = 8
SUB_AUTO_PRECLAND = 9
#: PX4_CUSTOM_SUB_MODE_POSCTL_ORBIT (entered by MAV_CMD_DO_ORBIT)
SUB_POSCTL_ORBIT = 1

#: Names of PX4's main modes, and of the sub modes that name a mode of their own (as QGroundControl
#: shows them).
MAIN_MODE_NAMES = {MAIN_MANUAL: "Manual", MAIN_ALTCTL: "Altitude", MAIN_POSCTL: "Position", MAIN_AUTO: "Auto",
                   MAIN_ACRO: "Acro", MAIN_OFFBOARD: "Offboard", MAIN_STABILIZED: "Stabilized", MAIN_RATTITUDE: "Rattitude",
                   MAIN_TERMINATION: "Termination"}  # fmt: skip
AUTO_SUB_MODE_NAMES = {SUB_AUTO_READY: "Ready", SUB_AUTO_TAKEOFF: "Takeoff", SUB_AUTO_LOITER: "Hold", SUB_AUTO_MISSION: "Mission",
                       SUB_AUTO_RTL: "Return", SUB_AUTO_LAND: "Land", SUB_AUTO_FOLLOW_TARGET: "Follow",
                       SUB_AUTO_PRECLAND: "Precland"}  # fmt: skip
POSCTL_SUB_MODE_NAMES = {SUB_POSCTL_ORBIT: "Orbit"}


def custom_mode(main_mode: int, sub_mode: int) -> int:
    """The HEARTBEAT's custom_mode of PX4's (main, sub): ``main << 16 | sub << 24``."""
    return (main_mode << 16) | (sub_mode << 24)


def main_sub(custom: int) -> tuple[int, int]:
    """PX4's (main, sub) mode of a HEARTBEAT custom_mode."""
    return (custom >> 16) & 0xFF, (custom >> 24) & 0xFF


def mode_name(main_mode: int, sub_mode: int) -> str:
    """PX4's name of (main, sub): the AUTO sub modes and Orbit by their own names."""
    if main_mode == MAIN_AUTO:
        return AUTO_SUB_MODE_NAMES.get(sub_mode, f"Auto/{sub_mode}")
    if main_mode == MAIN_POSCTL and sub_mode in POSCTL_SUB_MODE_NAMES:
        return POSCTL_SUB_MODE_NAMES[sub_mode]
    return MAIN_MODE_NAMES.get(main_mode, f"mode {main_mode}")
