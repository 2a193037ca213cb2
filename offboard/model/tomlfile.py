"""Reading validated fields out of TOML parameter files, with one-line errors.

``Fields`` wraps one table of a parsed file and knows where it came from, so every error
names the file and the dotted field: ``vehicle.toml: inertia_kg_m2: expected 3 numbers, got 2``.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from offboard.model.errors import ParameterFileError


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file, turning I/O and syntax errors into ``ParameterFileError``."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ParameterFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ParameterFileError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterFileError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise ParameterFileError(f"{path}: not a text file") from None


class Fields:
    """Typed access to one TOML table; errors name ``source`` and the dotted key."""

    def __init__(self, table: Mapping[str, Any], source: str, prefix: str = "") -> None:
        if not isinstance(table, Mapping):
            raise ParameterFileError(f"{source}: {prefix.rstrip('.') or 'file'}: expected a table")
        self.table = table
        self.source = source
        self.prefix = prefix
        self._used: set[str] = set()

    def where(self, key: str) -> str:
        """``source: prefix.key``, how messages name a field."""
        return f"{self.source}: {self.prefix}{key}"

    def error(self, key: str, message: str) -> ParameterFileError:
        """The one-line error about ``key`` (to raise)."""
        return ParameterFileError(f"{self.where(key)}: {message}")

    def has(self, key: str) -> bool:
        """Whether the table has ``key`` (without marking it used)."""
        return key in self.table

    def raw(self, key: str, default: Any = ...) -> Any:
        """The value of ``key`` as TOML gave it, marked used; ``default`` when absent (none: an error that
        names the nearest unused key, a likely typo).
        """
        self._used.add(key)
        if key not in self.table:
            if default is ...:
                near = near_name(key, (k for k in self.table if k not in self._used))
                raise self.error(key, "missing" + (f" (is {near!r} meant to be {key}?)" if near else ""))
            return default
        return self.table[key]

    def sub(self, key: str, *, optional: bool = False) -> Fields:
        """The sub-table ``key`` as ``Fields`` (``optional``: an empty one when absent)."""
        value = self.raw(key, {} if optional else ...)
        if not isinstance(value, Mapping):
            raise self.error(key, f"expected a table, got {type(value).__name__}")
        return Fields(value, self.source, f"{self.prefix}{key}.")

    def number(
        self,
        key: str,
        default: Any = ...,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> float:
        """A finite number (an int is taken as a float; a boolean is not a number), within the bounds given."""
        value = self.raw(key, default)
        return self._check_number(key, value, gt=gt, ge=ge, lt=lt, le=le)

    def _check_number(self, key: str, value: Any, **bounds: float | None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value}")
        gt, ge, lt, le = bounds.get("gt"), bounds.get("ge"), bounds.get("lt"), bounds.get("le")
        if gt is not None and lt is not None and not (gt < value < lt):
            raise self.error(key, f"must lie in ({gt:g}, {lt:g}), got {value:g}")
        if gt is not None and not value > gt:
            raise self.error(key, f"must be > {gt:g}, got {value:g}")
        if ge is not None and not value >= ge:
            raise self.error(key, f"must be >= {ge:g}, got {value:g}")
        if lt is not None and not value < lt:
            raise self.error(key, f"must be < {lt:g}, got {value:g}")
        if le is not None and not value <= le:
            raise self.error(key, f"must be <= {le:g}, got {value:g}")
        return value

    def vector(self, key: str, length: int, default: Any = ..., **bounds: float | None) -> tuple[float, ...]:
        """``length`` finite numbers, each within the bounds (``number``'s)."""
        value = self.raw(key, default)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            got = f"{len(value)}" if isinstance(value, (list, tuple)) else repr(value)
            raise self.error(key, f"expected {length} numbers, got {got}")
        return tuple(self._check_number(f"{key}[{i}]", v, **bounds) for i, v in enumerate(value))

    def string(self, key: str, default: Any = ..., *, choices: tuple[str, ...] | None = None) -> str:
        """A string, one of ``choices`` when they are given."""
        value = self.raw(key, default)
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"expected one of {', '.join(choices)}, got {value!r}")
        return value

    def boolean(self, key: str, default: Any = ...) -> bool:
        """true or false (TOML's booleans only)."""
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {value!r}")
        return value

    def reject_unknown(self) -> None:
        """Raise on keys nobody asked for: a typo must not be silently ignored."""
        unknown = sorted(set(self.table) - self._used)
        if unknown:
            near = near_name(unknown[0], self._used)
            raise self.error(unknown[0], "unknown field" + (f"; did you mean {near}?" if near else ""))


def near_name(name: str, candidates: Any) -> str | None:
    """The candidate a typo of ``name`` most likely is (``radius`` for ``radius_m``), or None."""

    names = [str(c) for c in candidates]
    close = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
    if close:
        return close[0]
    prefixed = [c for c in names if c.startswith(name) or name.startswith(c)]  # radius / radius_m
    return prefixed[0] if len(prefixed) == 1 else None
