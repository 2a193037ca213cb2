"""The sampler's account of a real-time mission: every tick of the mission, from its first sample
to its last, is one of a recorded sample, an overrun (skipped: the loop was late by whole periods)
or a missed period (no setpoint: telemetry stale), and nothing outside the mission is counted."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from offboard.flight.config import FlightConfig
from offboard.flight.sampler import Sampler
from offboard.flight.supervisor import Supervisor

TO = 0.05
LAST = 80  # the mission's last sample: 81 ticks, 4 s at 20 Hz


class ScriptedSampler(Sampler):
    """A sample does what ``Flight``'s mission step does with the sampler (start the mission, record
    samples 0 ... ``mission_samples``, end after the last), and sends a setpoint when ``sends(now)``."""

    def __init__(self, clock: Callable[[], float], sends: Callable[[float], bool]) -> None:
        config = FlightConfig()
        super().__init__(link=None, config=config, sample_time_s=TO, clock=clock, supervisor=Supervisor(config, lambda _: None))  # type: ignore[arg-type]
        self.source = object()  # type: ignore[assignment]
        self.mission_samples = LAST
        self._sends = sends

    def sample(self, now: float) -> bool:
        if not self._sends(now):
            return False
        n, _ = self.mission_sample(now)
        if not self.mission_done and n <= self.mission_samples:
            self.recorded(now)
        if n >= self.mission_samples:
            self.mission_done = True
        return True


def fly(stalls: dict[int, float], stale: tuple[float, float] = (0.0, 0.0)) -> tuple[int, int, int, int]:
    """Service the sampler on a clock that jumps ``stalls[k]`` s late at service call k and whose
    telemetry is stale over ``stale`` (s); (samples, overruns, missed, ticks) at the end."""
    now = [0.0]
    sampler = ScriptedSampler(lambda: now[0], lambda t: not stale[0] <= t < stale[1])
    for k in range(400):
        now[0] += stalls.get(k, 0.0)
        wait = sampler.service(now[0])
        now[0] += max(wait, 0.0)
    loop = sampler.finish()
    return loop.samples, loop.overruns, loop.missed, sampler.tick


@pytest.mark.parametrize(
    "stalls, stale, mission_overruns",
    [
        ({}, (0.0, 0.0), 0),  # on time
        ({30: 0.17}, (0.0, 0.0), 3),  # late by three periods in the middle
        ({79: 0.26}, (0.0, 0.0), 2),  # late by five periods from tick 79: 79 and 80 are the mission's
        ({}, (1.0, 1.5), 0),  # half a second of stale telemetry
        ({78: 0.12}, (3.9, 4.2), 2),  # late by two periods, then stale past the end
    ],
)
def test_each_mission_tick_is_a_sample_an_overrun_or_a_miss(stalls, stale, mission_overruns):
    samples, overruns, missed, ticks = fly(stalls, stale)
    assert ticks > LAST + 1  # the loop ran on past the mission
    assert samples + overruns + missed == LAST + 1
    assert overruns == mission_overruns
    assert (missed > 0) == (stale != (0.0, 0.0))


def _attitude(t_ms: int):
    from pymavlink.dialects.v20 import common as mavlink

    return mavlink.MAVLink_attitude_message(t_ms, 0.01, -0.02, 0.3, 0.0, 0.0, 0.0)


def _position(t_ms: int):
    from pymavlink.dialects.v20 import common as mavlink

    return mavlink.MAVLink_local_position_ned_message(t_ms, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("make, kept", [(_attitude, "att"), (_position, "lpn")])
def test_telemetry_overtaken_on_the_way_is_not_kept(make, kept):
    """A link that reorders hands an older message after a newer one: the newer stays the freshest
    (and the older is counted); a stamp far earlier is a vehicle whose clock started again."""
    from offboard.flight.sampler import OVERTAKEN_MS

    sampler = ScriptedSampler(lambda: 0.0, lambda t: True)
    stamps = [100, 90, 110, 110, 105, 120, 120 - OVERTAKEN_MS]
    for t_ms in stamps:
        sampler.take(make(t_ms))
    assert getattr(sampler, kept).time_boot_ms == 120 and sampler.loop.overtaken == 3  # 90, 105, 120 - OVERTAKEN_MS
    sampler.take(make(20_000))
    sampler.take(make(3))  # 19 997 ms earlier: the vehicle rebooted
    assert getattr(sampler, kept).time_boot_ms == 3 and sampler.loop.overtaken == 3
    assert sampler.loop.to_dict(TO)["telemetry_overtaken"] == 3
