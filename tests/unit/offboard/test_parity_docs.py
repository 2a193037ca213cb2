"""docs/parity/*.md, the table "PX4 v1.16 and sitl-plant": every row names the tests that
checked it against PX4 (or the plant), and those tests exist, so a row cannot outlive its test."""

from __future__ import annotations

import re

from helpers import REPO

PARITY = REPO / "docs" / "parity"


def test_functions() -> set[str]:
    names = set()
    for path in (REPO / "tests").rglob("test_*.py"):
        names.update(re.findall(r"^(?:async )?def (test_\w+)", path.read_text(), re.M))
    return names


test_functions.__test__ = False  # a helper, not a test


def tables(path) -> list[tuple[list[str], list[list[str]]]]:
    """Each table of a page: (its header, its rows), cells split at unescaped ``|``."""
    out: list[tuple[list[str], list[list[str]]]] = []
    lines = path.read_text().splitlines()
    for i, line in enumerate(lines):
        if not line.startswith("|") or set(line) <= set("|-: "):
            continue
        cells = [cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip()[1:-1])]
        if i + 1 < len(lines) and lines[i + 1].startswith("|") and set(lines[i + 1]) <= set("|-: "):
            out.append((cells, []))  # a header: the separator line follows
        else:
            assert out, f"{path.name}: a row before any table header: {line[:60]}"
            out[-1][1].append(cells)
    return out


def test_every_parity_row_names_tests_that_exist():
    files = sorted(PARITY.glob("*.md"))
    assert len(files) >= 2
    known = test_functions()
    for path in files:
        found = tables(path)
        assert found, f"{path.name}: no table"
        body = []
        for header, rows in found:
            assert header[-1] == "checked by" and "PX4" in header[1], f"{path.name}: header {header}"
            assert all(len(row) == len(header) for row in rows), f"{path.name}: a row's cells do not match its header"
            body += rows
        assert body, f"{path.name}: no rows"
        for row in body:
            named = re.findall(r"`(test_\w+)(?:\[[^\]`]*\])?`", row[-1])  # a parametrised one: test_name[id]
            if row[-1].startswith("not checked"):
                continue  # said so, in so many words
            assert named, f"{path.name}: row {row[0]!r} names no test (or says 'not checked')"
            missing = [n for n in named if n not in known]
            assert not missing, f"{path.name}: row {row[0]!r} names tests that do not exist: {missing}"


def test_the_plant_page_links_every_parity_file():
    text = (REPO / "docs" / "plant.md").read_text()
    for path in PARITY.glob("*.md"):
        assert f"parity/{path.name}" in text, f"docs/plant.md does not link docs/parity/{path.name}"
