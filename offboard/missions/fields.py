"""Reading mission files: TOML fields raising ``MissionFormatError``, and the text of the others.

``MissionFields`` is ``offboard.model.tomlfile.Fields`` with the same one-line messages
(``file: mission.segment #2 (hold-12m): radius_m: must be > 0, got -2``) but of the mission kind,
so callers can tell a bad mission from a bad parameter file. ``read_mission_text`` is how the
waypoint (QGC WPL) and ``.plan`` readers open their files: every I/O error is one line.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from offboard.errors import MissionFormatError, ParameterFileError
from offboard.model.tomlfile import Fields, read_toml


class MissionFields(Fields):
    """``Fields`` whose errors are ``MissionFormatError``."""

    def __init__(self, table: Mapping[str, Any], source: str, prefix: str = "") -> None:
        if not isinstance(table, Mapping):
            where = prefix.rstrip(". ") or "file"
            raise MissionFormatError(f"{source}: {where}: expected a table, got {type(table).__name__}")
        super().__init__(table, source, prefix)

    def error(self, key: str, message: str) -> MissionFormatError:  # type: ignore[override]
        return MissionFormatError(f"{self.where(key)}: {message}")

    def sub(self, key: str, *, optional: bool = False) -> MissionFields:
        value = self.raw(key, {} if optional else ...)
        if not isinstance(value, Mapping):
            raise self.error(key, f"expected a table, got {type(value).__name__}")
        return MissionFields(value, self.source, f"{self.prefix}{key}.")

    def table_list(self, key: str) -> list[Any]:
        """An array of tables (``[[mission.segment]]``), at least one."""
        value = self.raw(key)
        if not isinstance(value, list) or not value:
            raise self.error(key, "expected one or more tables ([[...]] entries)")
        return value


def read_mission_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML mission file; I/O and syntax errors become ``MissionFormatError``."""
    try:
        return read_toml(path)
    except ParameterFileError as exc:
        raise MissionFormatError(str(exc)) from None


def read_mission_text(path: Path, expected: str) -> str:
    """The text of a mission file (UTF-8); every way it cannot be read is one line.

    Parameters
    ----------
    path : Path
    expected : str
        What the file should be, for the messages (``"a 'QGC WPL 110' waypoint file"``).

    Raises
    ------
    MissionFormatError
        No such file, a directory, not text, or unreadable (permissions, I/O).
    """
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MissionFormatError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise MissionFormatError(f"{path}: is a directory, expected {expected}") from None
    except UnicodeDecodeError:
        raise MissionFormatError(f"{path.name}: not a text file; expected {expected}") from None
    except OSError as exc:
        raise MissionFormatError(f"{path}: cannot read it: {exc.strerror or exc}") from None
