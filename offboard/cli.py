"""`offboard` command line: one sub-command per module, each registering itself.

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``func=<callable(args) -> int>``. Errors a user can cause (bad file, bad argument, refused
command, lost link) derive from the builtin exceptions and end as one line on stderr with a
non-zero exit code; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from offboard.errors import UserError
from offboard.model.clihelp import HelpFormatter, add_version

# Modules that register sub-commands, in the order --help lists them.
COMMAND_MODULES = (
    "offboard.commands.simulate",
    "offboard.commands.sweep",
    "offboard.commands.fly",
    "offboard.commands.tune",
    "offboard.commands.mission",
    "offboard.commands.replay",
)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every sub-command, or of ``only`` (``offboard.commands.<only>``): a command
    imports only its own module, so ``offboard fly`` loads nothing of the simulator that
    ``offboard simulate`` needs (tests/e2e/test_layering.py)."""
    parser = argparse.ArgumentParser(
        prog="offboard",
        description="Fly the Rosales et al. tracking controller: in-process, or over MAVLink.",
        formatter_class=HelpFormatter,
    )
    add_version(parser, "offboard")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    modules: tuple[str, ...] = COMMAND_MODULES
    if only is not None and f"offboard.commands.{only}" in COMMAND_MODULES:
        modules = (f"offboard.commands.{only}",)
    for name in modules:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that command is not built yet
                continue
            raise
        module.register(sub)
    _remember_parsers(parser)
    return parser


def _remember_parsers(parser: argparse.ArgumentParser) -> None:
    """Each sub-command's parser in its own namespace (the innermost wins), so an unknown option
    is reported with the usage of the command it was given to, not the top-level one."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for subparser in action.choices.values():
                subparser.set_defaults(_usage_parser=subparser)
                _remember_parsers(subparser)


def main(argv: Sequence[str] | None = None) -> int:
    """``offboard COMMAND ...``: the command's exit code; 2 with one line for a user's error, 130 when
    interrupted.
    """
    words = list(sys.argv[1:] if argv is None else argv)
    command = words[0] if words and not words[0].startswith("-") else None
    try:
        parser = build_parser(only=command)  # imports the command's modules: numpy and the rest, a second or so
    except KeyboardInterrupt:
        print(f"offboard{'' if command is None else ' ' + command}: interrupted while starting", file=sys.stderr)
        return 130
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        getattr(args, "_usage_parser", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return int(args.func(args))
    except UserError as exc:
        print(f"offboard {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"offboard {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `offboard ... | head`: the reader left; not an error of ours
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
