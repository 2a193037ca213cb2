"""The static checks, as part of the suite (issue 12): ruff's pyflakes rules over every Python
file of the project, and mypy over both packages, offboard and sitl_plant (pyproject.toml's
[tool.mypy])."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers import REPO


def test_ruff_finds_nothing():
    checked = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "offboard", "sitl_plant", "bench", "tests", "examples"],
                             cwd=REPO, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert checked.returncode == 0, checked.stdout + checked.stderr


@pytest.mark.slow  # 15-20 s of a cold mypy: in make test, not in make test-fast's minute
def test_mypy_finds_nothing_in_the_packages(tmp_path):
    checked = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "mypy")], cwd=REPO,
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "Success: no issues found" in checked.stdout
