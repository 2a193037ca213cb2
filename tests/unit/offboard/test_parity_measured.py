"""docs/parity/measured.md, the table "PX4 v1.16 and sitl-plant" generated from what the px4 parity
tests measured (``make parity``, bench/parity.py; issue 13). The page is exactly the rendering of
the findings JSON at its end (so nobody edits it by hand), and it holds every finding the tests
record (a new one needs a new ``make parity``). Also the recorder and the renderer themselves."""

from __future__ import annotations

import datetime as dt
import json
import math
import re

import pytest

from bench.parity import ABSENT, AREAS, PAGE, FindingsError, Recorder, cell, main, merge, page_data, read_folder, render
from helpers import REPO

PARITY_TESTS = sorted((REPO / "tests" / "e2e").glob("test_px4_parity_*.py"))
#: a recorder call's key: a string (or f-string) literal as its first argument
KEY = re.compile(r"parity_finding\(\s*(f?)(\"|')(.*?)\2", re.S)


def recorded_keys() -> dict[str, list[str]]:
    """Per parity test file, the keys its ``parity_finding(...)`` calls record (f-strings as written)."""
    out = {}
    for path in PARITY_TESTS:
        text = path.read_text()
        calls = text.count("parity_finding(")
        keys = [("f" if f else "") + key for f, _, key in KEY.findall(text)]
        assert len(keys) == calls, f"{path.name}: a parity_finding call without a literal key"
        out[path.name] = keys
    return out


def as_pattern(key: str) -> re.Pattern:
    """A key as written (an f-string's ``{...}`` fields standing for any text) as a regex."""
    if not key.startswith("f"):
        return re.compile(re.escape(key))
    parts = re.split(r"\{[^{}]*\}", key[1:])
    return re.compile(".+".join(re.escape(p) for p in parts))


# --- the committed page ------------------------------------------------------------------------------


def test_the_page_is_the_rendering_of_its_own_findings():
    text = PAGE.read_text(encoding="utf-8")
    data = page_data(text)
    assert text == render(data), (
        "docs/parity/measured.md is not what bench/parity.py renders from its JSON: run make parity (or, after a change "
        "of the renderer only, python -m bench.parity docs/parity/measured.md)")


def test_every_parity_test_records_findings_and_the_page_holds_them_all():
    data = page_data(PAGE.read_text(encoding="utf-8"))
    on_page = {f["key"] for f in data["findings"]}
    for name in ("commander", "wire", "mission", "services", "offboard_loss"):
        assert recorded_keys().get(f"test_px4_parity_{name}.py"), f"test_px4_parity_{name}.py records no findings"
    for file, keys in recorded_keys().items():
        for key in keys:
            literal = key.removeprefix("f")
            assert literal.split(".", 1)[0] in AREAS, f"{file}: key {key!r} names no area of {sorted(AREAS)}"
            pattern = as_pattern(key)
            assert any(pattern.fullmatch(k) for k in on_page), f"{file}: {key!r} is not on the page: run make parity"


def test_the_page_names_its_commit_and_px4_speeds():
    data = page_data(PAGE.read_text(encoding="utf-8"))
    m = data["measured"]
    assert re.fullmatch(r"[0-9a-f]{40}", m["commit"]) and m["px4_speed"] and m["from"] <= m["to"]
    for area in AREAS:
        assert any(f["key"].startswith(area + ".") for f in data["findings"]), f"no findings for {area}"


# --- the recorder and the renderer ----------------------------------------------------------------


NOW = dt.datetime(2025, 1, 2, 3, 4, 5, tzinfo=dt.timezone.utc)


def record(tmp_path, nodeid, line, calls, outcome="passed", speed=4.0):
    r = Recorder(nodeid.split("::")[-1])
    for args, kwargs in calls:
        r(*args, **kwargs)
    return r.write(tmp_path, nodeid, outcome=outcome, line=line, px4_speed=speed, now=NOW)


def test_the_recorder_keeps_values_as_strict_json(tmp_path):
    path = record(tmp_path, "tests/e2e/test_px4_parity_wire.py::test_x[api]", 10, [
        (("wire.a", "nan and tuples"), {"px4": math.nan, "plant": (1, (2, 3), float("inf"))}),
        (("wire.b", "one side"), {"plant": "x"}),
        (("wire.c", "float noise"), {"px4": 3.1679999999999993, "plant": 2}),
    ])  # fmt: skip
    text = path.read_text()
    json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in {text}"))
    rec = read_folder(tmp_path)[0]
    assert rec["findings"] == [{"key": "wire.a", "behaviour": "nan and tuples", "px4": "nan", "plant": [1, [2, 3], "inf"]},
                               {"key": "wire.b", "behaviour": "one side", "plant": "x"},
                               {"key": "wire.c", "behaviour": "float noise", "px4": 3.168, "plant": 2}]  # fmt: skip
    assert rec["test"] == "test_x[api]" and rec["outcome"] == "passed" and rec["utc"] == "2025-01-02T03:04:05Z"


def test_a_key_outside_the_areas_is_refused_where_it_is_recorded():
    with pytest.raises(FindingsError):
        Recorder("test_x")("flight.speed", "no such area", px4=1, plant=1)
    with pytest.raises(FindingsError):
        Recorder("test_x")("wire", "no name after the area", px4=1, plant=1)
    assert ABSENT is not None


def test_several_workers_files_merge_into_one_row_per_key_in_the_page_order(tmp_path):
    # two workers (two files each): sides of one key from two tests, areas and lines out of order
    record(tmp_path, "tests/e2e/test_px4_parity_wire.py::test_loss[plant]", 50, [(("wire.loss", "loss"), {"plant": "9 / 0"})], speed=2.0)
    record(tmp_path, "tests/e2e/test_px4_parity_wire.py::test_loss[px4]", 50, [(("wire.loss", "loss"), {"px4": "8 / 0"})], speed=2.0)
    record(tmp_path, "tests/e2e/test_px4_parity_commander.py::test_land", 90, [
        (("commander.land.b", "second"), {"px4": 2.0, "plant": 2.001}), (("commander.land.a", "first"), {"px4": 1.0, "plant": 1.0}),
    ], outcome="failed")  # fmt: skip
    record(tmp_path, "tests/e2e/test_px4_parity_commander.py::test_takeoff", 30, [(("commander.takeoff", "takeoff"), {"px4": 4.41, "plant": 3.9})])
    data = merge(read_folder(tmp_path), commit="a" * 40, dirty=False)
    keys = [f["key"] for f in data["findings"]]
    assert keys == ["commander.takeoff", "commander.land.b", "commander.land.a", "wire.loss"]
    loss = data["findings"][-1]
    assert (loss["px4"], loss["plant"], loss["tests"]) == ("8 / 0", "9 / 0", ["test_loss[plant]", "test_loss[px4]"])
    assert data["findings"][1]["failed"] == ["test_land"] and "failed" not in data["findings"][0]
    m = data["measured"]
    assert m["px4_speed"] == {"test_px4_parity_commander.py": 4.0, "test_px4_parity_wire.py": 2.0}
    assert m["failed"] == ["test_land"] and m["tests"] == 4

    page = render(data)
    assert page_data(page) == data and render(page_data(page)) == page
    assert "| takeoff | 4.41 | 3.9 | `test_takeoff` |" in page
    assert "| first | 1 | the same | `test_land` (failed) |" in page
    assert "| second | 2 | 2 | `test_land` (failed) |" in page  # alike once rounded, not the same
    assert "| loss | 8 / 0 | 9 / 0 | `test_loss[plant]`, `test_loss[px4]` |" in page
    assert page.index("## commander") < page.index("## wire") < page.index("## services")
    assert "(no findings recorded in this run)" in page.split("## mission")[1].split("##")[0]


def test_one_key_with_two_values_for_a_side_is_an_error(tmp_path):
    record(tmp_path, "tests/e2e/test_px4_parity_wire.py::test_a", 1, [(("wire.x", "x"), {"px4": 1})])
    record(tmp_path, "tests/e2e/test_px4_parity_wire.py::test_b", 2, [(("wire.x", "x"), {"px4": 2})])
    with pytest.raises(FindingsError, match="wire.x"):
        merge(read_folder(tmp_path))


def test_a_page_with_nan_in_its_json_is_refused():
    data = {"measured": {}, "findings": []}
    page = "x\n```json\n" + json.dumps(data).replace("[]", "[NaN]") + "\n```\n"
    with pytest.raises(FindingsError, match="NaN"):
        page_data(page)


@pytest.mark.parametrize("value, text", [
    (None, "none"), (True, "yes"), (3, "3"), (0.7234, "0.723"), (25.63, "25.6"), (2499.4, "2499"),
    ([1, 2, 3], "1, 2, 3"), ([[0, 0, 90], [0, 90, 90]], "(0, 0, 90), (0, 90, 90)"), ("a|b\nc", "a\\|b ↵ c"),
])  # fmt: skip
def test_cells(value, text):
    assert cell(value) == text


def test_the_cli_writes_the_page_and_says_when_there_is_nothing(tmp_path, capsys):
    assert main([str(tmp_path / "none"), "--output", str(tmp_path / "page.md")]) == 1
    assert "no findings" in capsys.readouterr().err
    record(tmp_path / "f", "tests/e2e/test_px4_parity_services.py::test_x", 1, [(("services.x", "x"), {"px4": 1, "plant": 1})])
    assert main([str(tmp_path / "f"), "--output", str(tmp_path / "page.md")]) == 0
    page = (tmp_path / "page.md").read_text(encoding="utf-8")
    assert render(page_data(page)) == page
    (tmp_path / "page.md").write_text(page.replace("| 1 | the same |", "| 2 | the same |"), encoding="utf-8")  # a hand edit
    assert main([str(tmp_path / "page.md"), "--output", str(tmp_path / "again.md")]) == 0  # rendered from its JSON
    assert (tmp_path / "again.md").read_text(encoding="utf-8") == page


def test_a_damaged_record_or_page_is_one_line_naming_it(tmp_path, capsys):
    folder = tmp_path / "f"
    folder.mkdir()
    (folder / "x.json").write_text("{bad", encoding="utf-8")
    assert main([str(folder), "--output", str(tmp_path / "page.md")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "x.json: not a findings record" in err
    page = tmp_path / "page.md"
    page.write_text("# a page\n\n```json\n{bad\n```\n", encoding="utf-8")
    assert main([str(page), "--output", str(tmp_path / "again.md")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the page's JSON block" in err
    assert not (tmp_path / "again.md").exists()
