"""Mission files: where the vehicle should go, read into a ``Trajectory`` (local NED).

Three kinds, one loader each (format reference for users: ``docs/missions.md``):

- parametric TOML (``.toml``): a ``[mission]`` table of segments (``parametric``);
- QGC WPL 110 text (``.waypoints``, ``.txt``, ``.mission``, any name with that header) (``wpl``);
- QGroundControl ``.plan`` JSON (``plan``).

``load_mission(path)`` picks the loader; ``mission_from_table`` reads a ``[mission]`` table
embedded in another TOML file (a scenario), and ``resolve_mission`` accepts either such a table
or the name of a mission file relative to the file that names it. Every error a file can
cause is a ``MissionFormatError`` whose one-line message names the file, the line, item or
segment, the field, and what was expected.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from offboard.errors import MissionFormatError
from offboard.missions.fields import read_mission_toml
from offboard.missions.items import ItemMission, trajectory_from_items
from offboard.missions.parametric import parse_mission_table, read_parametric
from offboard.missions.plan import read_plan
from offboard.missions.wpl import looks_like_wpl, read_wpl
from offboard.trajectory.base import Trajectory

__all__ = ["MISSIONS_DIR", "Mission", "MissionFormatError", "load_mission", "mission_from_table", "resolve_mission"]

#: The bundled mission files (``missions/`` at the top of the repository).
MISSIONS_DIR = Path(__file__).resolve().parents[2] / "missions"
WPL_SUFFIXES = (".waypoints", ".txt", ".mission", ".wpl")


@dataclass(frozen=True)
class Mission:
    """A mission, read and checked.

    Attributes
    ----------
    name : str
        From the file (``name`` key) or its stem.
    trajectory : Trajectory
        The reference to fly, local NED, from t = 0.
    home : (lat deg, lon deg, alt m AMSL) or None
        Geographic position of the local origin, if the file gives one.
    source : str
        Where it came from (file name, or ``scenario.toml: mission``).
    description : str
        Free text from the file.
    start_ned_m : tuple of 3 floats
        Where the vehicle is expected to start (NED, at rest); the reference may start elsewhere.
    start_yaw_rad : float
        Its heading there.
    items : ItemMission or None
        The MAVLink mission items, for waypoint files.
    """

    name: str
    trajectory: Trajectory
    home: tuple[float, float, float] | None
    source: str
    description: str = ""
    start_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_yaw_rad: float = 0.0
    items: ItemMission | None = None


def load_mission(path: str | Path) -> Mission:
    """Read any mission file: ``.toml`` parametric, ``.plan``, or QGC WPL 110 (by header).

    Raises
    ------
    MissionFormatError
        Missing or unreadable file, unknown kind, or anything malformed inside it.
    """
    path = Path(path)
    if not path.exists():
        raise MissionFormatError(f"{path}: no such file")
    if path.is_dir():
        raise MissionFormatError(f"{path}: is a directory, expected a mission file")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        parsed = read_parametric(path, read_mission_toml(path))
        return Mission(
            parsed.name, parsed.trajectory, parsed.home, path.name, parsed.description, parsed.start_ned_m, parsed.start_yaw_rad
        )
    if suffix == ".plan":
        return _from_items(read_plan(path), path)
    if suffix in WPL_SUFFIXES or looks_like_wpl(path):
        return _from_items(read_wpl(path), path)
    raise MissionFormatError(
        f"{path.name}: unknown mission file kind; expected .toml (parametric), .plan (QGroundControl) "
        f"or a 'QGC WPL 110' waypoint file ({', '.join(WPL_SUFFIXES)})"
    )


def _from_items(items: ItemMission, path: Path) -> Mission:
    trajectory = trajectory_from_items(items)
    start = trajectory.segments[0].reference(0.0).pos_ned_m
    return Mission(
        path.stem, trajectory, items.home_global, path.name, "", tuple(float(v) for v in start), 0.0, items  # type: ignore[arg-type]
    )


def mission_from_table(table: Mapping[str, Any], source: str, base_dir: Path) -> Mission:
    """A mission from a ``[mission]`` table embedded in another TOML file (a scenario).

    Parameters
    ----------
    table : mapping
        The parsed ``[mission]`` table (same keys as in a mission file).
    source : str
        The embedding file's name, for messages (``scenario.toml: mission.segment #2 ...``).
    base_dir : Path
        The embedding file's directory (kept for symmetry with ``resolve_mission``; a table
        names no other file).
    """
    parsed = parse_mission_table(table, source, "mission.", Path(source).stem)
    return Mission(
        parsed.name, parsed.trajectory, parsed.home, f"{source}: mission", parsed.description, parsed.start_ned_m, parsed.start_yaw_rad
    )


def resolve_mission(value: Any, source: str, base_dir: Path) -> Mission:
    """The ``mission`` entry of a scenario file: a file name or an embedded table.

    A string is a mission file path, relative to ``base_dir`` (the scenario's directory)
    unless absolute; if no such file exists there, a bare name is looked up among the bundled
    missions (``MISSIONS_DIR``). A table is read by ``mission_from_table``.

    Raises
    ------
    MissionFormatError
        Neither a string nor a table; no such file; anything wrong inside the mission.
    """
    if isinstance(value, Mapping):
        return mission_from_table(value, source, base_dir)
    if isinstance(value, str) and value.strip():
        path = Path(value)
        candidate = path if path.is_absolute() else Path(base_dir) / path
        if not candidate.exists() and not path.is_absolute() and len(path.parts) == 1 and (MISSIONS_DIR / path).exists():
            candidate = MISSIONS_DIR / path
        if not candidate.exists():
            raise MissionFormatError(f"{source}: mission: no mission file {value!r} (looked in {base_dir} and {MISSIONS_DIR})")
        return load_mission(candidate)
    raise MissionFormatError(
        f"{source}: mission: expected a mission file name (\"paper-helix.toml\") or a [mission] table, got {value!r}"
    )
