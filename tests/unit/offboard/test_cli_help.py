"""The command lines' help, version and usage errors, as a newcomer meets them."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys

import pytest

from offboard.cli import build_parser as offboard_parser
from sitl_plant.cli import build_parser as plant_parser


def every_parser() -> list[tuple[str, argparse.ArgumentParser]]:
    found = [("sitl-plant", plant_parser())]
    todo = [("offboard", offboard_parser())]
    while todo:
        name, parser = todo.pop()
        found.append((name, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                todo.extend((f"{name} {sub}", p) for sub, p in action.choices.items())
    return found


@pytest.mark.parametrize("name, parser", every_parser(), ids=[n for n, _ in every_parser()])
def test_help_names_each_default_once(name, parser):
    text = " ".join(parser.format_help().split())  # argparse wraps lines: compare as one line
    assert "(default: None)" not in text and "(default: False)" not in text
    for help_text in re.findall(r"\(([^()]*default[^()]*)\)", text):
        assert help_text.count("default") == 1, help_text
    # no help text says "default" twice: once in its own words and once by the formatter
    for action in parser._actions:
        if action.help and "default" in action.help.lower():
            assert parser.formatter_class(parser.prog)._get_help_string(action) == action.help, action.dest


@pytest.mark.parametrize("program", [["-m", "offboard.cli"], ["-m", "sitl_plant.cli"]])
def test_version(program):
    proc = subprocess.run([sys.executable, *program, "--version"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0
    assert re.fullmatch(r"(offboard|sitl-plant) \d+\.\d+\.\d+\n", proc.stdout), proc.stdout


@pytest.mark.parametrize(
    "argv, usage",
    [
        (["fly", "m.toml", "--bogus"], "usage: offboard fly "),
        (["simulate", "s.toml", "--bogus"], "usage: offboard simulate "),
        (["mission", "show", "m.toml", "--bogus"], "usage: offboard mission show "),
        (["replay", "x.tlog", "--bogus"], "usage: offboard replay "),
    ],
)
def test_an_unknown_option_shows_the_usage_of_its_command(argv, usage, capsys):
    from offboard.cli import main

    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(usage) and err.rstrip().endswith("error: unrecognized arguments: --bogus"), err
