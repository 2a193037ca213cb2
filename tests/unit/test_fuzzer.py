"""The fuzzer's valid frames (tests/helpers/fuzz.py) cover every common.xml message: each type can
be drawn with random field values, packs, and parses back through pymavlink's own parser to the
same values. (Its fields once paired declaration-order types with wire-order array lengths, so 45
types, SET_ATTITUDE_TARGET, PARAM_SET and SETUP_SIGNING among them, never packed and were
silently redrawn: the fuzz never sent them.)"""

from __future__ import annotations

import math
import random
from collections import Counter

import numpy as np
import pytest

from pymavlink.dialects.v20 import common as mavlink

from helpers.fuzz import _CLASSES, Fuzzer, random_message

DRAWS = 5  # per message type (each with other random values)


def _same(sent, parsed, ftype: str) -> bool:
    if ftype == "char":  # a string: what the wire carries, up to its first NUL
        raw = sent if isinstance(sent, bytes) else str(sent).encode()
        got = parsed if isinstance(parsed, bytes) else str(parsed).encode("utf-8", "surrogateescape")
        return raw.split(b"\0")[0].decode("utf-8", "replace").encode() == got.split(b"\0")[0].decode("utf-8", "replace").encode()
    if isinstance(sent, list):
        return len(sent) == len(parsed) and all(_same(a, b, ftype) for a, b in zip(sent, parsed))
    if ftype in ("float", "double"):
        if math.isnan(sent):
            return math.isnan(parsed)
        return sent == parsed if ftype == "double" else float(np.float32(sent)) == parsed
    return sent == parsed


@pytest.mark.parametrize("cls", _CLASSES, ids=lambda c: c.msgname)
def test_every_common_message_is_drawn_packed_and_parsed_back(cls):
    rng, nprng = random.Random(cls.id), np.random.default_rng(cls.id)
    for _ in range(DRAWS):
        msg = random_message(rng, nprng, cls)
        sender = mavlink.MAVLink(None, srcSystem=rng.randrange(1, 256), srcComponent=rng.randrange(256))
        frame = msg.pack(sender)  # raises if a field's value or shape is wrong: the bug this guards
        parsed = mavlink.MAVLink(None).parse_buffer(frame)
        assert parsed is not None and len(parsed) == 1, frame
        (back,) = parsed
        assert back.get_type() == cls.msgname and bytes(back.get_msgbuf()) == frame
        for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
            assert _same(getattr(msg, name), getattr(back, name), ftype), (cls.msgname, name, getattr(msg, name), getattr(back, name))


def test_the_fuzzers_valid_frames_hold_every_common_message():
    """The pool a fuzz test throws holds every type (3000 draws over ~210 types)."""
    fuzzer = Fuzzer(20)
    parser = mavlink.MAVLink(None)
    kinds = Counter(m.get_type() for frame in fuzzer.valid for m in parser.parse_buffer(frame) or [])
    assert sum(kinds.values()) == len(fuzzer.valid)
    missing = {cls.msgname for cls in _CLASSES} - set(kinds)
    assert not missing, sorted(missing)
