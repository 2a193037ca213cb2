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

# Modules that register sub-commands, in the order --help lists them.
COMMAND_MODULES = (
    "offboard.commands.simulate",
    "offboard.commands.fly",
    "offboard.commands.tune",
    "offboard.commands.mission",
    "offboard.commands.replay",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="offboard",
        description="Fly the Rosales et al. tracking controller: in-process, or over MAVLink.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that command is not built yet
                continue
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
