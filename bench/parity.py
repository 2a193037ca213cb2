"""PX4 v1.16 and sitl-plant as the tests measured them: the findings of the ``px4`` parity tests,
merged and rendered as docs/parity/measured.md (issue 13). ``make parity`` runs the tests with
findings on, then this module.

A finding is one compared behaviour: a stable key whose first dotted part is its area
(``AREAS``), a short text, what PX4 did and what the plant did (numbers or short texts, as the
test formatted them) and the test that compared them. A test records them through the
``parity_finding`` fixture (tests/conftest.py), a ``Recorder``: a list append, nothing more, so
recording changes no test. With ``PARITY_FINDINGS=DIR`` set, each test that recorded something
writes ``DIR/<its node id>.json`` as it ends (pytest-xdist workers never share a file: no locks);
``merge`` reads them all back, ``render`` writes the page with the merged JSON at its end, and
``page_data`` reads that JSON back, so the page can be rendered again from itself (the unit test
tests/unit/offboard/test_parity_measured.py does, and so nobody edits the page by hand).

A key recorded by two tests (one side each, say) is one row: each side is taken from the test that
recorded it; two different values for the same side of one key are an error (two behaviours
sharing a key).

    python -m bench.parity DIR --output docs/parity/measured.md
    python -m bench.parity docs/parity/measured.md   # the page again from its own JSON
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "parity" / "measured.md"
#: The environment variable that turns findings on: the folder the tests write them into.
ENV = "PARITY_FINDINGS"
#: The areas, in the page's order, each with its hand-written page (ranges over many runs, and what
#: the plant deliberately does not do) and what it covers.
AREAS = {
    "commander": "modes, acks, heartbeats, failsafes, takeoff and landing",
    "wire": "streams and rates, parameters, AUTOPILOT_VERSION, loss counting",
    "mission": "the mission protocol, Mission mode, Reposition, Return, Orbit",
    "services": "FTP, log download, the shell, calibration, STATUSTEXT in, body-frame velocity",
}
HEADER = "| behaviour | PX4 v1.16 (measured) | sitl-plant | checked by |"
JSON_BLOCK = re.compile(r"^```json\n(.*?)\n```\n?\Z", re.S | re.M)


class FindingsError(ValueError):
    """Findings that cannot be merged or rendered (an unknown area, one key with two values)."""


class _Absent:
    """A side the test did not record (another test records it under the same key)."""

    def __repr__(self) -> str:
        return "ABSENT"


ABSENT: Any = _Absent()


def area_of(key: str) -> str:
    """The area of ``key`` (its first dotted part); FindingsError when it is not one of ``AREAS``."""
    area = key.split(".", 1)[0]
    if area not in AREAS or "." not in key:
        raise FindingsError(f"finding key {key!r}: want '<area>.<name>' with an area of {sorted(AREAS)}")
    return area


def plain(value: Any) -> Any:
    """``value`` as strict JSON can hold it: tuples as lists, numpy scalars as Python numbers, floats
    to six significant digits, NaN and infinities as the strings ``"nan"``, ``"inf"``, ``"-inf"``,
    anything else as its text."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):  # six significant digits: a measurement, not float noise
        return float(f"{value:.6g}") if math.isfinite(value) else str(value)
    if hasattr(value, "item") and callable(value.item) and getattr(value, "shape", None) == ():
        return plain(value.item())  # a numpy scalar
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    return str(value)


@dataclass
class Recorder:
    """What one test compared, in the order it recorded it; called as ``parity_finding(key,
    behaviour, px4=..., plant=...)``. Checks the key's area at once, so a bad key fails where it is
    written, not at rendering."""

    test: str
    findings: list[dict] = field(default_factory=list)

    def __call__(self, key: str, behaviour: str, px4: Any = ABSENT, plant: Any = ABSENT) -> None:
        area_of(key)
        finding: dict = {"key": key, "behaviour": behaviour}
        if px4 is not ABSENT:
            finding["px4"] = plain(px4)
        if plant is not ABSENT:
            finding["plant"] = plain(plant)
        self.findings.append(finding)

    def write(self, folder: Path, nodeid: str, *, outcome: str, line: int = 0, px4_speed: float | None = None,
              now: dt.datetime | None = None) -> Path:  # fmt: skip
        """``folder/<nodeid>.json``: this test's findings with where they come from."""
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / (re.sub(r"[^\w.-]+", "_", nodeid).strip("_") + ".json")
        record = {
            "nodeid": nodeid, "test": self.test, "line": line, "outcome": outcome, "px4_speed": px4_speed,
            "utc": (now or dt.datetime.now(dt.timezone.utc)).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "load": round(os.getloadavg()[0], 2), "findings": self.findings,
        }  # fmt: skip
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(record, allow_nan=False, ensure_ascii=False, indent=1) + "\n", encoding="utf-8")
        tmp.replace(path)
        return path


def git_commit(root: Path = ROOT) -> tuple[str, bool]:
    """(HEAD's commit, whether the tree has uncommitted changes); ("unknown", False) outside git."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True,
                                text=True, check=True).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown", False
    return head, bool(status.strip())


def merge(records: list[dict], *, commit: str = "unknown", dirty: bool = False) -> dict:
    """The findings of many tests' records (``Recorder.write``'s files, read back) as one document:
    ``{"measured": {...}, "findings": [...]}``, findings one per key in the page's order (area, then
    test file, then the test's place in it, then the order recorded)."""
    rows: dict[str, dict] = {}
    order: dict[str, tuple] = {}
    for rec in records:
        file = rec["nodeid"].split("::", 1)[0]
        for seq, f in enumerate(rec["findings"]):
            key = f["key"]
            row = rows.setdefault(key, {"key": key, "behaviour": f["behaviour"], "tests": [], "failed": []})
            place = (list(AREAS).index(area_of(key)), file, rec["line"], rec["nodeid"], seq)
            order[key] = min(order.get(key, place), place)
            for side in ("px4", "plant"):
                if side in f:
                    value = plain(f[side])
                    if side in row and row[side] != value:
                        raise FindingsError(f"finding {key!r}: {side} is {row[side]!r} and {value!r} (two behaviours, one key?)")
                    row[side] = value
            if rec["test"] not in row["tests"]:
                row["tests"].append(rec["test"])
            if rec["outcome"] != "passed" and rec["test"] not in row["failed"]:
                row["failed"].append(rec["test"])
    findings = [rows[k] for k in sorted(rows, key=order.__getitem__)]
    for row in findings:
        row["tests"].sort()
        row["failed"].sort()
        if not row["failed"]:
            del row["failed"]
    speeds: dict[str, float] = {}
    for rec in records:
        if rec.get("px4_speed") is not None:
            speeds[Path(rec["nodeid"].split("::", 1)[0]).name] = rec["px4_speed"]
    times = sorted(rec["utc"] for rec in records)
    loads = [rec["load"] for rec in records if rec.get("load") is not None]
    measured = {
        "from": times[0] if times else None, "to": times[-1] if times else None, "commit": commit, "dirty": dirty,
        "px4_speed": dict(sorted(speeds.items())), "tests": len({rec["test"] for rec in records}),
        "failed": sorted({rec["test"] for rec in records if rec["outcome"] != "passed"}),
        "load": [min(loads), max(loads)] if loads else None, "cores": os.cpu_count(),
    }  # fmt: skip
    return {"measured": measured, "findings": findings}


def read_folder(folder: Path) -> list[dict]:
    """Every test's record in ``folder`` (the ``*.json`` files ``Recorder.write`` left)."""
    out = []
    for p in sorted(folder.glob("*.json")):
        try:
            out.append(json.loads(p.read_text(encoding="utf-8")))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise FindingsError(f"{p}: not a findings record ({e})") from None
    return out


# --- the page ----------------------------------------------------------------------------------------


def cell(value: Any, nested: bool = False) -> str:
    """One value as a table cell: floats to three significant digits, lists joined (a list in a
    list in parentheses), ``|`` escaped, a line break as ``↵``."""
    if value is None:
        text = "none"
    elif isinstance(value, bool):
        text = "yes" if value else "no"
    elif isinstance(value, float):
        text = f"{value:.0f}" if abs(value) >= 1000 else f"{value:.3g}"
    elif isinstance(value, list):
        text = ", ".join(cell(v, True) for v in value)
        text = f"({text})" if nested else text
    elif isinstance(value, dict):
        text = ", ".join(f"{k} {cell(v, True)}" for k, v in value.items())
    else:
        text = str(value)
    return text.replace("|", "\\|").replace("\n", " ↵ ").strip()


def _row(f: dict) -> str:
    px4 = cell(f["px4"]) if "px4" in f else "(not recorded)"
    plant = cell(f["plant"]) if "plant" in f else "(not recorded)"
    if "px4" in f and "plant" in f and f["px4"] == f["plant"]:
        plant = "the same"  # equal values: numbers that only round alike keep their figures
    failed = set(f.get("failed", ()))
    tests = ", ".join(f"`{t}`" + (" (failed)" if t in failed else "") for t in f["tests"])
    return f"| {cell(f['behaviour'])} | {px4} | {plant} | {tests} |"


def dump(data: dict) -> str:
    """``data`` as strict JSON (no NaN), a finding a line, so a new run's diff reads row by row."""
    lines = ["{", ' "measured": ' + json.dumps(data["measured"], allow_nan=False, ensure_ascii=False) + ",", ' "findings": [']
    lines.append(",\n".join("  " + json.dumps(f, allow_nan=False, ensure_ascii=False) for f in data["findings"]))
    lines += [" ]", "}"]
    return "\n".join(lines)


def _speeds(speeds: dict[str, float]) -> str:
    by_speed: dict[float, list[str]] = {}
    for name, speed in speeds.items():
        by_speed.setdefault(speed, []).append(f"`{name}`")
    return "; ".join(f"`--speed {s:g}` in " + ", ".join(names) for s, names in sorted(by_speed.items())) or "(not recorded)"


def render(data: dict) -> str:
    """The page docs/parity/measured.md for ``data`` (``merge``'s document)."""
    m = data["measured"]
    commit = m["commit"][:12] + (" with uncommitted changes" if m["dirty"] else "")
    load = "" if not m["load"] else f", the machine's 1-minute load average {m['load'][0]:g}-{m['load'][1]:g} on {m['cores']} cores"
    failed = ", ".join(f"`{t}`" for t in m["failed"])
    out = [
        "# PX4 v1.16 and sitl-plant, as measured",
        "",
        "<!-- Generated by `make parity` (bench/parity.py) from the findings of the px4 parity tests;",
        "     do not edit: tests/unit/offboard/test_parity_measured.py renders it again from the JSON at its end. -->",
        "",
        f"Generated by `make parity` from the findings of the `px4` parity tests (`tests/e2e/test_px4_parity_*.py`), "
        f"recorded {m['from']} to {m['to']} at commit {commit}: the real PX4 v1.16.0 SITL (its SIH quadrotor, "
        f"`../shared/px4-sitl`) and `sitl-plant` side by side, each row what one test compared, with what PX4 did "
        f"and what the plant did when it ran. PX4 ran at {_speeds(m['px4_speed'])}{load}: PX4's own times and rates "
        f"move with the machine's load, and the tests hold the plant within the tolerance each states. "
        f"{m['tests']} tests recorded {len(data['findings'])} findings"
        + (f"; failed: {failed}." if failed else ", all passed."),
        "",
        "Times are vehicle (simulation) time. The hand-written page of each area carries the ranges over "
        "many runs and what the plant deliberately does not do.",
    ]
    for area, covers in AREAS.items():
        rows = [f for f in data["findings"] if area_of(f["key"]) == area]
        out += ["", f"## {area}", "", f"{covers}; ranges over many runs and what the plant deliberately does not do: "
                f"[{area}.md]({area}.md).", ""]  # fmt: skip
        if rows:
            out += [HEADER, "|---|---|---|---|", *(_row(f) for f in rows)]
        else:
            out.append("(no findings recorded in this run)")
    out += ["", "## The findings (JSON)", "", "What the tests recorded, merged; the tables above are rendered from it.", "",
            "```json", dump(data), "```", ""]  # fmt: skip
    return "\n".join(out)


def page_data(text: str) -> dict:
    """The findings document embedded at the end of a page ``render`` wrote."""
    found = JSON_BLOCK.search(text)
    if found is None:
        raise FindingsError("no ```json block at the end of the page")
    try:
        return json.loads(found.group(1), parse_constant=_no_constant)
    except json.JSONDecodeError as e:
        raise FindingsError(f"the page's JSON block: {e}") from None


def _no_constant(name: str) -> None:
    raise FindingsError(f"{name} in the page's JSON (strict JSON has no NaN or Infinity)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.parity", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    parser.add_argument("findings", type=Path, help="the folder the tests wrote their findings into (PARITY_FINDINGS), "
                        "or a page written before: rendered again from its JSON (after a change of the renderer)")  # fmt: skip
    parser.add_argument("--output", type=Path, default=PAGE, help="the page to write")
    args = parser.parse_args(argv)
    try:
        if args.findings.is_file():
            data = page_data(args.findings.read_text(encoding="utf-8"))
        else:
            records = read_folder(args.findings) if args.findings.is_dir() else []
            if not records:
                print(f"parity: no findings in {args.findings}: did the px4 tests run (PX4_SITL, {ENV})?", file=sys.stderr)
                return 1
            data = merge(records, **dict(zip(("commit", "dirty"), git_commit())))
    except (FindingsError, json.JSONDecodeError) as e:
        print(f"parity: {e}", file=sys.stderr)
        return 1
    args.output.write_text(render(data), encoding="utf-8")
    print(f"parity: {len(data['findings'])} findings of {data['measured']['tests']} tests -> {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
