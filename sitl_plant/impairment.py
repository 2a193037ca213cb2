"""A bad link, built into the plant: seeded loss, delay and jitter, duplication, reordering and
corruption of UDP datagrams, per direction (``sitl-plant --link``, real time only).

It is the plant's counterpart of ArduPilot SITL's ``SIM_Sn_PKT_LOSS`` / ``SIM_Sn_DELAY`` and of
Linux ``netem``, for users who test their own controllers over a link that is not loopback.
Pure: :class:`Impairment` decides, from its own seeded generator, what becomes of each datagram
(when it is released, how many copies, which bit flipped); :class:`DelayLine` holds the
datagrams until their time. The link (``sitl_plant/link.py``) applies them to what it sends and
to what it receives.

The spec is ``loss=PCT,delay=MS,jitter=MS,duplicate=PCT,reorder=PCT,corrupt=PCT`` (any subset,
e.g. ``loss=20,delay=50,jitter=20``):

- ``loss``: each datagram is dropped with this probability;
- ``delay`` and ``jitter``: it is held ``delay + U(-jitter, +jitter)`` ms (never below 0), so
  datagrams may overtake each other when the jitter exceeds their spacing;
- ``reorder``: this share of datagrams skips the delay (netem's reordering), overtaking the
  ones held;
- ``duplicate``: it is sent twice (the copy with its own delay);
- ``corrupt``: one random bit of it is flipped.
"""

from __future__ import annotations

import heapq
import math
import random
from dataclasses import dataclass, field, fields

#: The spec's keys and what they mean (unit).
KEYS = {
    "loss": "percent of datagrams dropped",
    "delay": "ms each datagram is held",
    "jitter": "ms of uniform spread about the delay",
    "duplicate": "percent of datagrams sent twice",
    "reorder": "percent of datagrams that skip the delay",
    "corrupt": "percent of datagrams with one bit flipped",
}
_PERCENT = ("loss", "duplicate", "reorder", "corrupt")


class ImpairmentError(ValueError):
    """A spec that cannot be read (the message names the option and the field)."""


@dataclass(frozen=True)
class ImpairmentSpec:
    """What a direction of the link does to datagrams (percent and milliseconds)."""

    loss: float = 0.0
    delay: float = 0.0
    jitter: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0

    @property
    def active(self) -> bool:
        """Whether the spec impairs anything (some value above 0)."""
        return any(getattr(self, f.name) > 0 for f in fields(self))

    def as_option(self) -> str:
        """The spec as ``--link`` takes it (``delay=80,jitter=30,...``, the active keys only;
        ``parse_impairment`` reads it back to an equal spec)."""
        return ",".join(f"{f.name}={_number(getattr(self, f.name))}" for f in fields(self) if getattr(self, f.name)) or "loss=0"

    def describe(self) -> str:
        """In words: "loss 20 %, delay 50+-20 ms, ..." ("none")."""
        parts = [f"loss {self.loss:g} %"] if self.loss else []
        if self.delay or self.jitter:
            parts.append(f"delay {self.delay:g}+-{self.jitter:g} ms")
        parts += [f"{k} {getattr(self, k):g} %" for k in ("duplicate", "reorder", "corrupt") if getattr(self, k)]
        return ", ".join(parts) or "none"


def _number(value: float) -> str:
    """``80`` for 80.0, else the float's shortest exact form (``0.1``)."""
    return str(int(value)) if value == int(value) else repr(value)


def parse_impairment(text: str, option: str = "--link") -> ImpairmentSpec:
    """``loss=20,delay=50,jitter=20`` -> ImpairmentSpec; one-line errors naming the field."""
    values: dict[str, float] = {}
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        key, sep, value = part.partition("=")
        key = key.strip()
        if not sep or key not in KEYS:
            known = ", ".join(f"{k} ({v})" for k, v in KEYS.items())
            raise ImpairmentError(f"{option} {text!r}: {part!r} is not KEY=VALUE with a key of: {known}")
        try:
            number = float(value.strip().rstrip("%").removesuffix("ms"))
        except ValueError:
            raise ImpairmentError(f"{option} {text!r}: {key}={value!r} is not a number") from None
        if not math.isfinite(number) or number < 0 or (key in _PERCENT and number > 100):
            bound = "0..100 (percent)" if key in _PERCENT else ">= 0 (ms)"
            raise ImpairmentError(f"{option} {text!r}: {key} must be {bound}, got {value.strip()}")
        values[key] = number
    spec = ImpairmentSpec(**values)
    if spec.jitter > 0 and spec.jitter > spec.delay:
        raise ImpairmentError(f"{option} {text!r}: jitter {spec.jitter:g} ms exceeds the delay {spec.delay:g} ms")
    return spec


@dataclass
class ImpairmentCounts:
    datagrams: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    corrupted: int = 0

    def describe(self) -> str:
        """What was done to the datagrams so far, in one line."""
        return (f"{self.datagrams} datagrams: {self.dropped} dropped, {self.duplicated} duplicated, "
                f"{self.reordered} not delayed, {self.corrupted} corrupted")  # fmt: skip


@dataclass
class Impairment:
    """One direction's impairment, seeded: the same seed gives the same fate to the same stream."""

    spec: ImpairmentSpec
    seed: int | str = 0
    counts: ImpairmentCounts = field(default_factory=ImpairmentCounts)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    def schedule(self, datagram: bytes, now_s: float) -> list[tuple[float, bytes]]:
        """The copies of ``datagram`` that go on, each with the time it is released."""
        spec, rng, counts = self.spec, self._rng, self.counts
        counts.datagrams += 1
        if spec.loss and rng.random() * 100 < spec.loss:
            counts.dropped += 1
            return []
        copies = 1
        if spec.duplicate and rng.random() * 100 < spec.duplicate:
            counts.duplicated += 1
            copies = 2
        out = []
        for _ in range(copies):
            data = datagram
            if spec.corrupt and data and rng.random() * 100 < spec.corrupt:
                counts.corrupted += 1
                bit = rng.randrange(len(data) * 8)
                flipped = bytearray(data)
                flipped[bit // 8] ^= 1 << (bit % 8)
                data = bytes(flipped)
            delay_ms = spec.delay + (rng.uniform(-spec.jitter, spec.jitter) if spec.jitter else 0.0)
            if spec.reorder and rng.random() * 100 < spec.reorder:
                counts.reordered += 1
                delay_ms = 0.0
            out.append((now_s + max(delay_ms, 0.0) / 1000.0, data))
        return out


class DelayLine:
    """Datagrams held until their release time (first released first; equal times in order)."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, bytes, object]] = []
        self._n = 0

    def push(self, release_s: float, data: bytes, tag: object = None) -> None:
        """Hold ``data`` (with ``tag``, say its address) until ``release_s``; equal times keep their order."""
        heapq.heappush(self._heap, (release_s, self._n, data, tag))
        self._n += 1

    def due(self, now_s: float) -> list[tuple[bytes, object]]:
        """The (data, tag) pairs released by ``now_s``, in release order, taken out."""
        out = []
        while self._heap and self._heap[0][0] <= now_s:
            _, _, data, tag = heapq.heappop(self._heap)
            out.append((data, tag))
        return out

    def next_release_s(self) -> float | None:
        """When the next held datagram is due (None: none is held)."""
        return self._heap[0][0] if self._heap else None

    def __len__(self) -> int:
        return len(self._heap)
