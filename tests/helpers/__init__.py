"""What the tests share (fixtures in ``tests/conftest.py``; flights of real processes in
``helpers.flights``): where things are, and a clock a test moves by hand."""

from __future__ import annotations

from pathlib import Path

#: The repository's root, and the folder beside it that CI provides (the paper, a real PX4 SITL).
REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"


class FakeClock:
    """A monotonic clock in seconds that only moves when a test sets ``now``."""

    def __init__(self, start_s: float = 100.0) -> None:
        self.now = start_s

    def __call__(self) -> float:
        return self.now
