"""Every offboard-loss action (COM_OBL_RC_ACT 1..7) flown on the real PX4 v1.16 SITL and on
``sitl-plant``, side by side, with no manual control input.

One PX4 (``--speed 4``) and one plant serve the module; the same client script
(tests/helpers/commander.py) runs against both at once. For each value of COM_OBL_RC_ACT it
climbs to 10 m in Offboard (taking off again first when the last action left the vehicle on the
ground), sets the parameter, stops the setpoints and records, on the vehicle's clock: the heartbeat
(base_mode, custom mode, system status) after "Failsafe activated", the STATUSTEXTs, the vertical
speed between 1.5 and 5.5 s after the failsafe, and the heartbeat and height ``END_S`` after it (the
estimate's, and the simulator's truth: HIL_STATE_QUATERNION). The default (0,
Position) is compared in test_px4_parity_commander.py. Terminate (6) is flown last: PX4 stays in
flight termination until rebooted.

Figures measured while this was written are in docs/parity/commander.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest
from pymavlink import mavutil

from helpers.commander import (
    ALTCTL,
    AUTO_LAND,
    AUTO_LOITER,
    AUTO_RTL,
    OFFBOARD,
    Client,
    fly_side_by_side,
    heartbeat_state,
    heartbeat_text,
    settle_heartbeat,
)

pytestmark = [pytest.mark.px4, pytest.mark.e2e, pytest.mark.slow]  # skipped without a PX4: tests/conftest.py

mavlink = mavutil.mavlink
SPEED = 4.0
NAN = math.nan
HEIGHT_M = 10.0
STABILIZED, TERMINATION = (7, 0), (10, 0)
#: when the end is read, after "Failsafe activated" (vehicle's clock): PX4's fall after Terminate
#: began 1-3 s after the failsafe, and once in a loaded make test later, 2.3 m up still at 8 s
END_S = 12.0
ACTIONS = (1, 2, 3, 4, 5, 7, 6)  # Terminate last: only a reboot ends it
ACTION_NAMES = {1: "Altitude", 2: "Stabilized", 3: "Return", 4: "Land", 5: "Hold", 6: "Terminate", 7: "Disarm"}


@dataclass
class Loss:
    """What one vehicle did when the setpoints stopped under one COM_OBL_RC_ACT."""

    heartbeat: tuple[int, tuple[int, int], int] = (0, (0, 0), 0)
    final: tuple[int, tuple[int, int], int] = (0, (0, 0), 0)
    texts: list[str] = field(default_factory=list)
    sink_m_s: float = NAN  # mean descent speed 1.5-5.5 s after the failsafe (down +)
    height_at_failsafe_m: float = NAN
    height_at_end_m: float = NAN  # the vehicle's estimate (LOCAL_POSITION_NED)
    true_height_at_end_m: float = NAN  # the simulator's truth (HIL_STATE_QUATERNION) above its start




def _airborne_in_offboard(c: Client, ground_down_m: float) -> None:
    if not c.armed:
        c.setpoint = None
        c.set_mode(AUTO_LOITER)
        c.pump(0.3)
        c.take_off(ground_down_m, SPEED)
    c.setpoint = (0.0, 0.0, ground_down_m - HEIGHT_M)
    c.pump(0.3)
    # PX4 answers TEMPORARILY_REJECTED while its offboard signal is not yet fresh; on a loaded
    # machine (a cold make test) 0.3 s of setpoints were once not enough: retry while they stream
    # (a refusal that persists still fails the test)
    results = c.set_mode(OFFBOARD)
    for _ in range(3):
        if results[-1:] != [mavlink.MAV_RESULT_TEMPORARILY_REJECTED]:
            break
        c.pump(1.0)
        results = c.set_mode(OFFBOARD)
    assert results[-1:] == [mavlink.MAV_RESULT_ACCEPTED], f"Offboard: {results}"
    assert c.wait(lambda: abs(c.down_m - (ground_down_m - HEIGHT_M)) < 0.3, 40.0, SPEED), "no climb in Offboard"
    c.wait_sim(1.0)


def fly_script(c: Client) -> dict[int, Loss]:
    out: dict[int, Loss] = {}
    c.connect()
    c.pump(1.0)
    # the ground from the vehicle's own estimate: a loaded machine can take longer than the
    # second above for the first LOCAL_POSITION_NED (down_m reads 0.0 until then)
    assert c.wait(lambda: len(c.samples) >= 10, 30.0, SPEED), "no LOCAL_POSITION_NED"
    ground = c.down_m
    # the simulator's truth at 10 Hz: after Terminate PX4 SIH's vehicle tumbles on the ground, and
    # EKF2's height of a tumbling vehicle is no measure of where it is (-0.6 to -1.1 m in an idle
    # run, SIH's truth 0.0; 2.3 and 2.56 m 8-12 s after the failsafe in two loaded runs)
    assert c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 100000)[-1:] == [
        mavlink.MAV_RESULT_ACCEPTED]  # fmt: skip
    assert c.wait(lambda: len(c.truths) >= 3, 5.0, SPEED), "no HIL_STATE_QUATERNION"
    ground_alt_m = c.truths[-1][3]
    for action in ACTIONS:
        _airborne_in_offboard(c, ground)
        c.set_param("COM_OBL_RC_ACT", action, integer=True)
        assert c.get_param("COM_OBL_RC_ACT") == action
        loss = out[action] = Loss()
        c.setpoint = None
        t_stop = c.t_s
        assert c.wait(lambda: any("Failsafe activated" in x for x in c.texts_since(t_stop)), 15.0, SPEED), \
            f"no failsafe (COM_OBL_RC_ACT {action}, client on {c.port}, mode {c.mode}, texts {c.texts_since(t_stop)})"
        t_fs = c.t_s
        loss.height_at_failsafe_m = ground - c.down_m
        settle_heartbeat(c)
        loss.heartbeat = heartbeat_state(c)
        c.wait_sim(max(0.0, t_fs + END_S - c.t_s))
        window = [s for s in c.samples if t_fs + 1.5 <= s.t_s <= t_fs + 5.5]
        loss.sink_m_s = (window[-1].pos_ned_m[2] - window[0].pos_ned_m[2]) / (window[-1].t_s - window[0].t_s)
        loss.height_at_end_m = ground - c.down_m
        loss.true_height_at_end_m = c.truths[-1][3] - ground_alt_m
        loss.final = heartbeat_state(c)
        loss.texts = [x.strip() for x in c.texts_since(t_stop)]
        if not c.armed:
            c.wait_sim(2.0)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(PX4, plant): every action flown on both, side by side."""
    result = fly_side_by_side(tmp_path_factory.mktemp("px4"), SPEED, fly_script)
    for action in ACTIONS:
        a, b = result[0][action], result[1][action]
        for who, o in (("PX4", a), ("plant", b)):
            print(f"COM_OBL_RC_ACT {action} {who:5}: {o.heartbeat} -> {o.final}, sink {o.sink_m_s:5.2f} m/s, height at the "
                  f"end {o.height_at_end_m:.2f} m (truth {o.true_height_at_end_m:.2f} m), {o.texts}")  # fmt: skip
    return result


def test_every_offboard_loss_action_ends_in_px4s_mode_and_heartbeat(runs, parity_finding):
    px4, plant = runs
    for action in ACTIONS:
        parity_finding(f"commander.obl_rc_act.{action}.heartbeat", f"offboard loss, COM_OBL_RC_ACT {action} "
                       f"({ACTION_NAMES[action]}), no sticks: heartbeat after \"Failsafe activated\"",
                       heartbeat_text(px4[action].heartbeat), heartbeat_text(plant[action].heartbeat))  # fmt: skip
    # measured: none of them falls back for the missing sticks
    expected = {1: (209, ALTCTL, 5), 2: (209, STABILIZED, 5), 3: (157, AUTO_RTL, 5), 4: (157, AUTO_LAND, 5),
                5: (157, AUTO_LOITER, 5), 7: (17, OFFBOARD, 0), 6: (129, TERMINATION, 8)}  # fmt: skip
    for action in ACTIONS:
        assert px4[action].heartbeat == expected[action], action
        assert plant[action].heartbeat == px4[action].heartbeat, action
        assert "Failsafe activated" in plant[action].texts, action


def test_the_actions_fly_as_px4s(runs, parity_finding):
    """Descend or hold, as PX4: Altitude at MPC_LAND_SPEED (PX4 0.70 m/s), Stabilized level at the
    hover thrust (PX4 sank 0.07-0.15 m/s, the plant 0.0), Land and Return (from above home) down
    (PX4 1.03-1.04 m/s between 1.5 and 5.5 s, the plant 0.92-0.93), Hold held."""
    px4, plant = runs
    for action in (1, 2, 3, 4, 5):
        parity_finding(f"commander.obl_rc_act.{action}.sink", f"offboard loss, COM_OBL_RC_ACT {action} ({ACTION_NAMES[action]}): "
                       "descent 1.5-5.5 s after the failsafe (m/s)", px4[action].sink_m_s, plant[action].sink_m_s)  # fmt: skip
    for action in (1, 4):
        # the vehicles' states in the message: a CI run (loaded machine) saw PX4 sink 0.37 m/s in
        # Altitude and end landed and disarmed 8 s after the failsafe, which from 10 m at 0.7 m/s
        # cannot be; not reproduced on an idle or a loaded machine since
        assert plant[action].sink_m_s == pytest.approx(px4[action].sink_m_s, rel=0.35), (action, px4[action], plant[action])
    for action in (2, 5):
        assert abs(px4[action].sink_m_s) < 0.35 and abs(plant[action].sink_m_s) < 0.35, action
    assert px4[3].sink_m_s > 0.4 and plant[3].sink_m_s > 0.4


def test_disarm_and_terminate_as_px4(runs, parity_finding):
    px4, plant = runs
    for action in (7, 6):
        parity_finding(f"commander.obl_rc_act.{action}.end", f"offboard loss, COM_OBL_RC_ACT {action} ({ACTION_NAMES[action]}): "
                       f"{END_S:g} s after the failsafe, heartbeat; height (m, the simulator's truth)",
                       *(f"{heartbeat_text(o[action].final)}; {o[action].true_height_at_end_m:.1f} m" for o in runs))  # fmt: skip
    for obs in runs:
        assert "Disarmed by failsafe" in obs[7].texts
        # it fell: on the ground by the simulator's truth (the estimate's height is in the message)
        assert obs[7].true_height_at_end_m < 1.0, (obs[7].true_height_at_end_m, obs[7].height_at_end_m)
        # flight termination: the motors stop, and PX4 stays armed in it on the ground
        assert obs[6].true_height_at_end_m < 1.0, (obs[6].true_height_at_end_m, obs[6].height_at_end_m)
        assert obs[6].final == (129, TERMINATION, 8)
    assert plant[7].final == px4[7].final
