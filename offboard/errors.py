"""Errors a user can cause. Each subclasses a builtin so callers can catch it by kind.

The command line turns any of these into one line naming what is wrong and where.
"""

from __future__ import annotations


from offboard.model.errors import ParameterFileError, UserError

__all__ = [
    "ClockMismatch",
    "CommandRejected",
    "LinkTimeout",
    "LockstepMismatch",
    "LogFormatError",
    "MissionFormatError",
    "ParameterFileError",
    "UserError",
]


class MissionFormatError(UserError, ValueError):
    """A mission file is malformed; the message names the file, line or item, and field."""


class LinkTimeout(UserError, TimeoutError):
    """No MAVLink traffic from the vehicle within the allowed time."""


class CommandRejected(UserError, RuntimeError):
    """The vehicle refused a command; carries the MAV_RESULT value and name."""

    def __init__(self, command: str, result: int, result_name: str) -> None:
        super().__init__(f"{command} refused by the vehicle: {result_name} ({result})")
        self.command = command
        self.result = result
        self.result_name = result_name


class LogFormatError(UserError, ValueError):
    """A flight log cannot be read at all (not a tlog, empty)."""


class ClockMismatch(UserError, ValueError):
    """The vehicle's clock runs at another rate than ours while we sample on ours."""


class LockstepMismatch(UserError, ValueError):
    """The lockstep plant's period differs from the controller's sample time."""
