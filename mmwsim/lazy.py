"""Packages whose public names load on first use, so that importing one stays cheap.

``import mmwsim`` (and ``mmwsim --help``) must not pay for rerun, zarr, numba, scipy or trimesh,
and ``estimation``'s vocabularies must be readable without torch. A package lists its public names
and the submodule defining each; the first access imports that submodule.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, exports: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module ``__getattr__`` and ``__dir__`` of a package with lazily loaded public names.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : dict
        Public name -> the submodule that defines it, relative to the package (``".store"``), or
        ``".module:attribute"`` where the public name differs from the attribute.

    Returns
    -------
    __getattr__, __dir__
        To assign at the package's top level.
    """

    def __getattr__(name: str) -> Any:
        try:
            target = exports[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        module, _, attribute = target.partition(":")
        value = getattr(importlib.import_module(module, package), attribute or name)
        setattr(sys.modules[package], name, value)  # later look-ups skip __getattr__
        return value

    def __dir__() -> list[str]:
        return sorted(set(exports) | set(vars(sys.modules[package])))

    return __getattr__, __dir__
