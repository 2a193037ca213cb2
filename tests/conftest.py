"""Shared fixtures, and the test tiers.

Layout: ``tests/unit/offboard``, ``tests/unit/sitl_plant`` (pure, in one process: the fast tier,
``make test-fast``), ``tests/e2e`` (real processes talking over loopback UDP, real PX4 where the
test is about PX4: marked ``e2e`` here, whatever the file says). Helpers are ``tests/helpers``
(on the path through ``pythonpath`` in pyproject.toml), never a test module.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from helpers import FakeClock

E2E_DIR = Path(__file__).resolve().parent / "e2e"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if E2E_DIR in Path(str(item.fspath)).resolve().parents:
            item.add_marker(pytest.mark.e2e)


@pytest.fixture
def fake_clock() -> FakeClock:
    """A clock the test advances by setting ``fake_clock.now``."""
    return FakeClock()


@pytest.fixture
def free_ports() -> Callable[[int], list[int]]:
    """``free_ports(n)``: n distinct UDP ports on 127.0.0.1 the OS just handed out (never PX4's)."""
    from offboard.demo import free_udp_ports

    return free_udp_ports
