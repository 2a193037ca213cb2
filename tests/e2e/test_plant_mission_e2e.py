"""The bundled box mission uploaded to ``sitl-plant`` over real UDP and flown in Mission mode.

The client is the one that flies it on PX4 too (tests/helpers/mission_client.py,
tests/e2e/test_px4_parity_mission.py). The plant runs faster than real time (``--speed``); the
assertions are on what was reached and where, never on wall-clock speed.
"""

from __future__ import annotations

import math

import pytest

from helpers.mission_client import MissionClient, fly_mission, items_from_file, start_plant
from offboard.demo import stop_process
from offboard.missions import MISSIONS_DIR

pytestmark = pytest.mark.e2e

BOX = MISSIONS_DIR / "px4-sitl-box.waypoints"


def test_the_box_mission_uploads_downloads_and_flies_in_mission_mode():
    conn, proc = start_plant("--speed", "50", "--physics-dt", "0.004")
    try:
        client = MissionClient(conn, 1)
        items = items_from_file(BOX)
        up = client.upload(items)
        assert up.ack == 0 and up.log[1] == ("MISSION_REQUEST", 0)  # float mode first, as PX4 1.16
        down = client.download()
        assert [i.key() for i in down.items] == [i.key() for i in items]
        flight = fly_mission(conn, 1, timeout_s=90.0)
    finally:
        stop_process(proc)
        conn.close()
    # PX4 v1.16 flew the same file reporting 1, 2, 3, 4, 5, 6: test_px4_parity_mission's
    # test_the_bundled_missions_fly_on_both_as_px4_flies_them flies it on PX4 and the plant
    assert flight.reached == [1, 2, 3, 4, 5, 6]
    assert flight.current[-1] == 6 and flight.disarmed_at_ms is not None
    assert ((4, 4), True) in flight.modes and flight.modes[-1] == ((4, 4), False)  # lands, disarms, stays in Mission
    north_east = {(round(n), round(e)) for _, n, e, _ in flight.track}
    top = -min(d for _, _, _, d in flight.track)
    assert top == pytest.approx(15.0, abs=1.0)  # items 3 and 4 at 15 m
    assert any(math.hypot(n - 20, e - 20) < 2.0 for n, e in north_east)  # the far corner (20 N, 20 E)
    last = flight.track[-1]
    assert math.hypot(last[1], last[2]) < 2.0 and last[3] > -0.2  # landed at home
