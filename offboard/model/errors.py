"""Errors a user can cause, shared by both programs (``offboard`` imports these).

Each subclasses a builtin, so callers catch them by kind; the command lines turn them into
one line naming what is wrong and where.
"""

from __future__ import annotations


class UserError(Exception):
    """Marker base: an error in what the user gave us (file, argument, packet), not a bug."""


class ParameterFileError(UserError, ValueError):
    """A parameter file (controller, vehicle, scenario) is missing a field or has a bad value.

    The message names the file and the field, e.g.
    ``paper.toml: gains.kx3: must lie in (0, 1), got 1.2``.
    """


class LinkError(UserError, OSError):
    """A socket cannot be opened (address in use, bad address) or a log cannot be written."""
