"""What both command lines share: the help formatter and ``--version``."""

from __future__ import annotations

import argparse


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default once: not for flags, unset options (``None``, ``""``), or help
    that already names its default (``"(default: runs/<mission>-<time>)"``)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (action.default in (None, "", False) or action.default is argparse.SUPPRESS or "default" in text.lower()
                or isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))):  # fmt: skip
            return action.help
        return super()._get_help_string(action)


def program_version(prog: str) -> str:
    """``PROG VERSION`` of the installed project (``--version``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"{prog} {version('rosales-offboard')}"
    except PackageNotFoundError:  # run from a source tree that was never installed
        return f"{prog} (not installed)"


def add_version(parser: argparse.ArgumentParser, prog: str) -> None:
    """Give ``parser`` a ``--version`` option printing ``program_version(prog)``."""
    parser.add_argument("--version", action="version", version=program_version(prog))
