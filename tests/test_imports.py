"""Every module imports by its dotted path, and no public name shadows a subpackage."""

from __future__ import annotations

import importlib
import subprocess
import sys
import types

import pytest

from tests.helpers.imports import modules

MODULES = sorted(m for m in modules() if not m.endswith("__main__"))  # __main__ runs the CLI


@pytest.mark.parametrize("name", MODULES)
def test_module_imports_by_its_dotted_path(name):
    module = importlib.import_module(name)
    assert module.__name__ == name
    for public in getattr(module, "__all__", ()):
        assert hasattr(module, public), f"{name}.__all__ names {public!r}, which it does not define"


@pytest.mark.parametrize("name", sorted({m.rpartition(".")[0] for m in MODULES if "." in m}))
def test_subpackages_are_not_shadowed(name):
    """``pkg.sub`` is the module ``sub`` after ``import pkg`` too (no function of that name)."""
    package = importlib.import_module(name)
    for child in (m for m in MODULES if m.rpartition(".")[0] == name):
        importlib.import_module(child)
        attr = getattr(package, child.rpartition(".")[2])
        assert isinstance(attr, types.ModuleType), f"{child} is shadowed by {attr!r}"


def test_importing_mmwsim_and_its_cli_is_cheap():
    """``import mmwsim`` and building the CLI load none of the heavy libraries."""
    heavy = ["torch", "rerun", "zarr", "numba", "scipy", "trimesh", "ompl", "embreex", "matplotlib"]
    code = (
        "import sys, mmwsim, mmwsim.cli; mmwsim.cli.build_parser(); "
        f"print(','.join(m for m in {heavy!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == ""
