"""Strict JSON for every summary the commands write or print (docs/json.md).

Python's ``json`` writes NaN and infinities as the bare words ``NaN`` and ``Infinity``, which
JavaScript's ``JSON.parse``, ``jq`` and every strict parser reject. Here a number that is not
finite becomes ``null``: in a summary it means "no such figure" (a table cell without samples or
without references, a rate of a loop that never ran, a flight cut short before a phase).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np


def strict(value: object) -> object:
    """``value`` with every non-finite float (also inside dicts, lists, tuples, numpy arrays)
    replaced by None, numpy scalars and arrays turned into Python numbers and lists, paths into
    strings. Anything else JSON cannot hold is left for ``json.dumps`` to refuse."""
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return strict(value.item())
    if isinstance(value, np.ndarray):
        return strict(value.tolist())
    if isinstance(value, Mapping):
        return {str(k): strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def dumps(value: object, indent: int | None = None, *, default=None) -> str:
    """Strict JSON text of ``value`` (``strict`` first; ``allow_nan=False`` guards the rule)."""
    return json.dumps(strict(value), indent=indent, allow_nan=False, default=default)
