"""Every public module, class, function, method and property of the math layer has a docstring
(STYLE.md: "Docstrings enforced", after python-control's ``control/tests/docstrings_test.py``).

The math layer is what ARCHITECTURE.md keeps pure: the controller and its design, the
trajectories, the shared models, the baselines and the simulator's dynamics. A method documented
where it is declared (a base class's, a Protocol's it subclasses) counts, as ``inspect.getdoc``
finds it. The I/O layers (links, commands, the plant's server and autopilot, replay, sweeps) are
not held to it yet.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

PACKAGES = ("offboard.controller", "offboard.trajectory", "offboard.model", "offboard.baselines", "sitl_plant.dynamics")


def _modules() -> list[str]:
    names = []
    for package in PACKAGES:
        names.append(package)
        path = importlib.import_module(package).__path__
        names += [info.name for info in pkgutil.walk_packages(path, package + ".")]
    return names


def _undocumented(module_name: str) -> list[str]:
    module = importlib.import_module(module_name)
    missing = [] if inspect.getdoc(module) else ["(the module)"]
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module_name:
            continue  # private, or imported from elsewhere (checked there)
        if not (inspect.isclass(obj) or inspect.isfunction(obj)):
            continue
        if not inspect.getdoc(obj):
            missing.append(name)
        if inspect.isclass(obj):
            for member, value in vars(obj).items():
                if member.startswith("_"):
                    continue
                if isinstance(value, property):
                    documented = bool(value.__doc__)
                elif inspect.isfunction(value) or isinstance(value, (staticmethod, classmethod)):
                    documented = bool(inspect.getdoc(getattr(obj, member)))
                else:
                    continue  # a field, a constant
                if not documented:
                    missing.append(f"{name}.{member}")
    return missing


@pytest.mark.parametrize("module_name", _modules())
def test_every_public_name_has_a_docstring(module_name):
    assert _undocumented(module_name) == []


def test_the_check_finds_a_missing_docstring(tmp_path, monkeypatch):
    (tmp_path / "undocumented_probe.py").write_text('"""A module."""\n\n\ndef documented():\n    """Yes."""\n\n\n'
                                                     "def bare():\n    return 1\n\n\nclass Thing:\n    \"\"\"A thing.\"\"\"\n\n"
                                                     "    @property\n    def size(self):\n        return 1\n")  # fmt: skip
    monkeypatch.syspath_prepend(str(tmp_path))
    assert _undocumented("undocumented_probe") == ["bare", "Thing.size"]
