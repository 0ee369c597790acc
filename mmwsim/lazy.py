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
    package: str, exports: dict[str, tuple[str, ...]]
) -> tuple[list[str], Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__all__``, ``__getattr__`` and ``__dir__`` of a package with lazily loaded public names.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : dict
        Submodule, relative to the package (``".store"``) -> the public names it defines; a name
        ``"public=attribute"`` exports the submodule's ``attribute`` as ``public``.

    Returns
    -------
    __all__, __getattr__, __dir__
        To assign at the package's top level.
    """
    where: dict[str, tuple[str, str]] = {}
    for module, names in exports.items():
        for entry in names:
            public, _, attribute = entry.partition("=")
            where[public] = (module, attribute or public)

    def __getattr__(name: str) -> Any:
        try:
            module, attribute = where[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        value = getattr(importlib.import_module(module, package), attribute)
        setattr(sys.modules[package], name, value)  # later look-ups skip __getattr__
        return value

    def __dir__() -> list[str]:
        return sorted(set(where) | set(vars(sys.modules[package])))

    return sorted(where), __getattr__, __dir__
