"""QGC WPL 110: the plain-text waypoint file of QGroundControl, Mission Planner, MAVProxy, mavwp.

::

    QGC WPL 110
    <seq> <current> <frame> <command> <p1> <p2> <p3> <p4> <x/lat> <y/lon> <z/alt> <autocontinue>

one item a line, fields separated by tabs (any whitespace is read, as pymavlink's ``mavwp``
does), items numbered 0, 1, 2, ... in order. Item 0 is the home position (MAV_FRAME_GLOBAL,
AMSL altitude, as the ground stations write it); it is not flown. Lines starting with ``#``
are comments (``mavwp`` writes them). ``nan`` is a number (MAVLink uses NaN for "unchanged",
e.g. the yaw of a waypoint).
"""

from __future__ import annotations

import math
from pathlib import Path

from offboard.errors import MissionFormatError
from offboard.missions.fields import read_mission_text
from offboard.missions.items import GLOBAL_FRAMES, ItemMission, MissionItem

HEADER = "QGC WPL 110"
COLUMNS = ("seq", "current", "frame", "command", "param1", "param2", "param3", "param4", "x", "y", "z", "autocontinue")
_GLOBAL_NAMES = {"x": "x (latitude)", "y": "y (longitude)", "z": "z (altitude)"}


def looks_like_wpl(path: Path) -> bool:
    """Whether the file starts with a ``QGC WPL`` header (any version)."""
    try:
        with path.open("rb") as fh:
            return fh.read(7) == b"QGC WPL"
    except OSError:
        return False


def read_wpl(path: str | Path) -> ItemMission:
    """Read a QGC WPL 110 file.

    Raises
    ------
    MissionFormatError
        Missing file, wrong header, wrong number of fields, a field that is not a number
        (or not an integer where one is expected), items out of order, no item after home.
        Commands and frames are checked when the items are turned into a trajectory.
    """
    path = Path(path)
    source = path.name
    text = read_mission_text(path, f"a '{HEADER}' waypoint file")
    lines = text.splitlines()
    header = lines[0].strip() if lines else ""
    if header != HEADER:
        got = repr(header[:40]) if header else "an empty first line"
        raise MissionFormatError(f"{source}: line 1: header: expected '{HEADER}', got {got}")
    items: list[MissionItem] = []
    for lineno, line in enumerate(lines[1:], start=2):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        items.append(_parse_line(stripped, lineno, len(items), source))
    if len(items) < 2:
        raise MissionFormatError(f"{source}: no mission items after the home position (item 0); expected at least one more line")
    return ItemMission(items[0], tuple(items[1:]), source)


def _parse_line(line: str, lineno: int, expected_seq: int, source: str) -> MissionItem:
    fields = line.split()
    where = f"line {lineno}"
    if len(fields) != len(COLUMNS):
        raise MissionFormatError(
            f"{source}: {where}: expected {len(COLUMNS)} tab-separated fields "
            f"({' '.join(COLUMNS)}), got {len(fields)}"
        )
    values = dict(zip(COLUMNS, fields))

    def integer(name: str, allowed: tuple[int, ...] | None = None) -> int:
        try:
            value = int(values[name])
        except ValueError:
            raise MissionFormatError(f"{source}: {where}: {name}: expected an integer, got {values[name]!r}") from None
        if allowed is not None and value not in allowed:
            raise MissionFormatError(f"{source}: {where}: {name}: expected one of {', '.join(map(str, allowed))}, got {value}")
        return value

    seq = integer("seq")
    if seq != expected_seq:
        raise MissionFormatError(f"{source}: {where}: seq: expected {expected_seq} (items numbered 0, 1, 2, ... in order), got {seq}")
    where = f"line {lineno} (item {seq})"
    current = integer("current", (0, 1))
    frame = integer("frame")
    command = integer("command")
    autocontinue = integer("autocontinue", (0, 1))
    del current  # which item is current is the vehicle's business, not the path's

    def number(name: str) -> float:
        label = _GLOBAL_NAMES.get(name, name) if frame in GLOBAL_FRAMES else name
        try:
            value = float(values[name])
        except ValueError:
            raise MissionFormatError(f"{source}: {where}: {label}: expected a number, got {values[name]!r}") from None
        if math.isinf(value):
            raise MissionFormatError(f"{source}: {where}: {label}: expected a finite number, got {values[name]!r}")
        return value

    params = tuple(number(f"param{k}") for k in range(1, 5))
    return MissionItem(
        command, frame, params, number("x"), number("y"), number("z"), bool(autocontinue), seq=seq, where=where  # type: ignore[arg-type]
    )


def format_wpl(mission: ItemMission) -> str:
    """The text of a QGC WPL 110 file: home as item 0 (current = 1), then the items."""
    lines = [HEADER]
    for seq, item in enumerate((mission.home, *mission.items)):
        numbers = [*item.params, item.x, item.y, item.z]
        lines.append(
            "\t".join(
                [str(seq), "1" if seq == 0 else "0", str(item.frame), str(item.command)]
                + [repr(float(v)) for v in numbers]
                + ["1" if item.autocontinue else "0"]
            )
        )
    return "\n".join(lines) + "\n"


def write_wpl(mission: ItemMission, path: str | Path) -> None:
    """Write ``mission`` as a QGC WPL 110 file (floats to full precision, ``nan`` kept)."""
    Path(path).write_text(format_wpl(mission), encoding="utf-8")
