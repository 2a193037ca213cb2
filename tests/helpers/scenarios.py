"""Scenario runs the tests share, each flown once per test session."""

from __future__ import annotations

import functools

from helpers import REPO
from offboard.inprocess import run_scenario
from offboard.metrics import summarize
from offboard.scenario import load_scenario


@functools.cache
def flown(name: str):
    """``missions/NAME`` flown in-process: (record, summary), cached."""
    record = run_scenario(load_scenario(REPO / "missions" / name))
    return record, summarize(record)
