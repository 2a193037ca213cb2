"""Every public module, class, function, method and property of both packages has a docstring
(STYLE.md: "Docstrings enforced", after python-control's ``control/tests/docstrings_test.py``).

A method documented where it is declared (a base class's, a Protocol's it subclasses) counts, as
``inspect.getdoc`` finds it. Private names (a leading underscore) and ``__main__`` modules are not
held to it.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

PACKAGES = ("offboard", "sitl_plant")


def _modules() -> list[str]:
    names = []
    for package in PACKAGES:
        names.append(package)
        path = importlib.import_module(package).__path__
        names += [info.name for info in pkgutil.walk_packages(path, package + ".") if not info.name.endswith(".__main__")]
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
