"""The grammar of the command-line model specs (``--wind``, ``--sensors``): ``kind[:arguments]``,
the arguments a comma-separated list of numbers or ``key=value`` options. One reader for both, so
they split, check and word their errors alike; each spec module keeps only its kinds.

Every function takes ``fail``, which makes the spec's own exception (``WindSpecError``,
``SensorSpecError``) from a message, so an error names the spec and the part in one line.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

Fail = Callable[[str], Exception]


def kind_and_args(text: str) -> tuple[str, str]:
    """(kind in lower case, arguments) of ``kind[:arguments]``, both stripped."""
    kind, _, args = text.partition(":")
    return kind.strip().lower(), args.strip()


def number(name: str, text: str, fail: Fail, *, nonnegative: bool = False) -> float:
    """``text`` as a finite number (and >= 0 with ``nonnegative``)."""
    try:
        value = float(text)
    except ValueError:
        raise fail(f"{name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise fail(f"{name} must be finite, got {text!r}")
    if nonnegative and value < 0:
        raise fail(f"{name} must be >= 0, got {text!r}")
    return value


def options(text: str, allowed: Sequence[str], fail: Fail) -> dict[str, str]:
    """``key=value,key=value`` as a dict (values unparsed); each key one of ``allowed``, once."""
    found: dict[str, str] = {}
    for item in text.split(","):
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or not key:
            raise fail(f"expected key=value with key one of {', '.join(allowed)}, got {item.strip()!r}")
        if key not in allowed:
            raise fail(f"unknown option {key!r} in {item.strip()!r} (expected {', '.join(allowed)})")
        if key in found:
            raise fail(f"option {key!r} given twice")
        found[key] = value
    return found
