"""A minimal shell over SERIAL_CONTROL (device SERIAL_CONTROL_DEV_SHELL), shaped as PX4 SITL's
``pxh`` answers through ``src/modules/mavlink/mavlink_shell.cpp`` (measured on PX4 v1.16 SITL:
docs/parity/services.md).

Pure: ``Shell.feed(bytes) -> bytes`` of output, and ``replies(bytes)`` cuts output into
SERIAL_CONTROL replies (flags SERIAL_CONTROL_FLAG_REPLY, up to 70 bytes each). A line is echoed,
answered, then the prompt ``pxh> `` follows, as PX4's. Commands: ``ver`` (``all``, ``hw``,
``git``, ``uri``, ...), ``param show [NAME | PREFIX*]``, ``help``; anything else answers as pxh
does for a command it lacks ("Invalid command: ..."). The values are the plant's own.
"""

from __future__ import annotations

import fnmatch
import platform
import re
from collections.abc import Callable, Iterator

from pymavlink.dialects.v20 import common as mavlink

from sitl_plant.params import ParamTable

PROMPT = "pxh> "
DATA_LEN = 70  # SERIAL_CONTROL.data
MAX_LINE = 512


def version_lines(flight_sw_version: int, os_release: str | None = None) -> dict[str, str]:
    """``ver``'s lines, by subcommand, for a MAVLink ``flight_sw_version`` (major << 24 | minor
    << 16 | patch << 8 | type; PX4 prints ``Release 1.16.0 (17826047)`` for 0x011000FF) and the
    host's ``os_release`` (``platform.release()`` by default; PX4 SITL prints the kernel's)."""
    major, minor, patch = flight_sw_version >> 24 & 0xFF, flight_sw_version >> 16 & 0xFF, flight_sw_version >> 8 & 0xFF
    release = platform.release() if os_release is None else os_release
    numbers = [int(n) for n in re.findall(r"\d+", release)[:3]] + [0, 0, 0]
    os_number = (numbers[0] & 0xFF) << 24 | (numbers[1] & 0xFF) << 16 | (numbers[2] & 0xFF) << 8 | 0xFF
    return {
        "hw": "HW arch: SITL_PLANT",
        "git": "PX4 git-hash: 0000000000000000000000000000000000000000",
        "fw": f"PX4 version: Release {major}.{minor}.{patch} ({flight_sw_version})",
        "os": f"OS: {platform.system() or 'Linux'}",
        "osver": f"OS version: Release {numbers[0]}.{numbers[1]}.{numbers[2]} ({os_number})",
        "bdate": "Build datetime: sitl-plant (Python)",
        "uri": "Build uri: localhost",
        "variant": "Build variant: sitl-plant",
        "gcc": "Toolchain: Python",
        "px4guid": "PX4GUID: 0000000000000000000000000000000000",
        "mcu": "UNKNOWN MCU",
    }


_VER_ALL = ("hw", "git", "fw", "os", "osver", "bdate", "uri", "variant", "gcc", "px4guid", "mcu")
_VER_USAGE = (
    "Tool to print various version information\n\nUsage: ver <command> [arguments...]\n Commands:\n\n"
    "   hw            Hardware architecture\n\n   mcu           MCU info\n\n   git           git version information\n\n"
    "   bdate         Build date and time\n\n   gcc           Compiler info\n\n   px4guid       PX4 GUID\n\n"
    "   uri           Build URI\n\n   all           Print all versions\n"
)


class Shell:
    """The shell of one link.

    Parameters
    ----------
    params : ParamTable
        The plant's parameters (read at each command).
    flight_sw_version : callable returning int
        The version AUTOPILOT_VERSION reports (read at each ``ver``).
    """

    def __init__(self, params: ParamTable, flight_sw_version: Callable[[], int]) -> None:
        self.params = params
        self.flight_sw_version = flight_sw_version
        self._pending = b""

    def feed(self, data: bytes) -> bytes:
        """Input bytes; the output they cause (each complete line: echo, answer, prompt)."""
        self._pending += data
        out = []
        while True:
            cut = min((i for i in (self._pending.find(b"\n"), self._pending.find(b"\r")) if i >= 0), default=-1)
            if cut < 0:
                if len(self._pending) > MAX_LINE:
                    self._pending = b""
                    out.append("\nline too long\n" + PROMPT)
                break
            line, self._pending = self._pending[:cut], self._pending[cut + 1 :]
            if self._pending.startswith(b"\n") and cut >= 0:
                self._pending = self._pending[1:]  # "\r\n" is one end of line
            text = line.decode("utf-8", "replace").strip()
            out.append(text + "\n" + self.run(text) + PROMPT)
        return "".join(out).encode()

    def run(self, line: str) -> str:
        """One command line's output (without the prompt)."""
        words = line.split()
        if not words:
            return ""
        cmd, args = words[0], words[1:]
        if cmd == "ver":
            return self._ver(args)
        if cmd == "param":
            return self._param(args)
        if cmd == "help":
            return "Builtin Commands:\n  help\n  param\n  ver\n"
        return f"Invalid command: {cmd}\ntype 'help' for a list of commands\n"

    def _ver(self, args: list[str]) -> str:
        lines = version_lines(self.flight_sw_version())
        if not args:
            return "Error, not enough parameters.\n" + _VER_USAGE + "Command 'ver' failed, returned 1.\n"
        sub = args[0]
        if sub == "all":
            return "".join(lines[k] + "\n" for k in _VER_ALL)
        if sub in lines:
            return lines[sub] + "\n"
        return _VER_USAGE + "Command 'ver' failed, returned 1.\n"

    def _param(self, args: list[str]) -> str:
        t = self.params
        if not args or args[0] != "show":
            return "Usage: param show [NAME | PREFIX*]\nCommand 'param' failed, returned 1.\n"
        pattern = args[1] if len(args) > 1 else "*"
        names = [n for n in t if fnmatch.fnmatchcase(n, pattern)]
        body = "".join(_param_line(t, n) for n in names)
        n = len(t)
        return f"Symbols: x = used, + = saved, * = unsaved\n{body}\n {n}/{n} parameters used.\n"


def _param_line(t: ParamTable, name: str) -> str:
    """PX4's ``param show`` line: used mark, name, [used index, index], value (4 decimals for
    floats, an integer as such)."""
    value = t[name]
    i = t.index(name)
    shown = str(int(value)) if t.spec(name).kind == "int" else f"{value:.4f}"
    return f"x   {name} [{i},{i}] : {shown}\n"


def replies(output: bytes) -> Iterator[mavlink.MAVLink_message]:
    """SERIAL_CONTROL replies carrying ``output`` (PX4: device SHELL, flags REPLY, 70 bytes each)."""
    for start in range(0, len(output), DATA_LEN):
        chunk = output[start : start + DATA_LEN]
        yield mavlink.MAVLink_serial_control_message(
            mavlink.SERIAL_CONTROL_DEV_SHELL, mavlink.SERIAL_CONTROL_FLAG_REPLY, 0, 0, len(chunk), list(chunk.ljust(DATA_LEN, b"\0"))
        )
