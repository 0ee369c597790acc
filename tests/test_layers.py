"""The import contract: layers a reader can see, and no import circle anywhere.

Layers, lowest first: the ``mmwsim`` core (scene, geometry, materials, antennas, tracer,
fingerprints, dataset, trajectories, recording, ...); the scene catalogue ``scenes`` (reached by
the core only through the registry of ``mmwsim.scene.catalogue``); ``estimation`` and ``planning``,
independent of each other; the application (``mmwsim.cli``, ``mmwsim.demo``) on top. Imports
inside functions count; ``if TYPE_CHECKING:`` ones do not (they never run).
"""

from __future__ import annotations

import pytest

from tests.helpers.imports import ROOT as GRAPH_ROOT
from tests.helpers.imports import collapse, cycles, import_graph

GRAPH = import_graph()
APPLICATION = ("mmwsim.cli", "mmwsim.demo", "mmwsim.__main__")


def layer(module: str) -> str:
    if any(module == a or module.startswith(a + ".") for a in APPLICATION):
        return "application"
    return module.split(".")[0]  # mmwsim (the core), scenes, estimation, planning


# What each layer may import besides itself.
ALLOWED = {
    "mmwsim": set(),
    "scenes": {"mmwsim"},
    "estimation": {"mmwsim"},
    "planning": {"mmwsim"},
    "application": {"mmwsim", "scenes", "estimation", "planning"},
}


def unit(module: str) -> str:
    """A subpackage (or top-level module) of mmwsim; the other packages as a whole."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "mmwsim" else parts[0]


def test_the_graph_sees_the_packages():
    assert {"mmwsim.tracer.tracer", "estimation.training", "planning.planners", "scenes.manhattan"} <= set(
        GRAPH
    )
    # a function-local import and a lazy export both count
    assert "mmwsim.dataset.tiles" in GRAPH["mmwsim.dataset.store"]
    assert "mmwsim.dataset.store" in GRAPH["mmwsim"]


@pytest.mark.parametrize("name", sorted(ALLOWED))
def test_layers(name):
    offending = sorted(
        f"{m} -> {t}"
        for m, targets in GRAPH.items()
        if layer(m) == name
        for t in targets
        if layer(t) != name and layer(t) not in ALLOWED[name]
    )
    assert not offending, "imports across the layers:\n" + "\n".join(offending)


def test_no_import_circles_between_modules():
    assert not cycles(GRAPH)


def test_no_import_circles_between_subpackages():
    assert not cycles(collapse(GRAPH, unit))


def test_the_scene_model_never_names_the_catalogue():
    source = [p for p in (GRAPH_ROOT / "mmwsim").rglob("*.py") if 'import_module("scenes")' in p.read_text()]
    assert not source
