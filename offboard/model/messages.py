"""The pymavlink message type, named once for the annotations of both processes.

pymavlink ships no type information, so to a type checker this is ``Any``: a message's fields
(``msg.time_boot_ms``) are read without a cast, and an annotation still says what a value is.
"""

from __future__ import annotations

from typing import TypeAlias

from pymavlink.dialects.v20 import common as mavlink

MAVLinkMessage: TypeAlias = mavlink.MAVLink_message

__all__ = ["MAVLinkMessage"]
