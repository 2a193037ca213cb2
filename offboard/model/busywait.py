"""Waiting for a lockstep peer: poll the sockets a little before sleeping in ``select`` (issue 16).

In lockstep the plant and the offboard take turns: each sends and then waits for the other's
answer, which comes a few hundred microseconds later (the other's physics or law). Sleeping in
``select`` for it costs the wake-up of an idle CPU: on a virtual machine the vCPU halts and is
woken by the host, tens of microseconds each way, twice a cycle. Polling first, for up to
``LOCKSTEP_SPIN_S``, catches the answer awake; past it the wait blocks as before (a peer that takes
longer is doing something else: starting, landing, a stall). The poll yields the CPU between
tries (``os.sched_yield``), so a process that has work on the same CPU is not held up by it.

``make bench`` (bench/RESULTS.md, "MAVLink lockstep loop") measures the loop this way and its
floors both ways, polling and sleeping at once; docs/benchmarks.md says what it gained.
"""

from __future__ import annotations

import os
import select
import time
from collections.abc import Sequence
from typing import Protocol, TypeVar


class _HasFileno(Protocol):
    def fileno(self) -> int: ...


_Fd = TypeVar("_Fd", bound=int | _HasFileno)

#: How long a lockstep wait polls before it sleeps, s: about twice the peer's usual turnaround
#: (the plant's 50 RK4 steps and autopilot, or the offboard's law and records: 100-250 us).
LOCKSTEP_SPIN_S = 0.0005


def poll_readable(fds: Sequence[_Fd], spin_s: float) -> list[_Fd]:
    """The readable ones of ``fds`` (sockets or file numbers) as soon as one is, polling for up to
    ``spin_s`` (yielding between polls); [] when none became readable in that time."""
    end = time.perf_counter() + spin_s
    while True:
        readable, _, _ = select.select(fds, [], [], 0.0)
        if readable or time.perf_counter() >= end:
            return readable
        os.sched_yield()
