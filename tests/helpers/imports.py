"""The import graph of the project's packages, read from the source (nothing is imported).

Every import statement counts, at module level or inside a function, except those under
``if TYPE_CHECKING:`` (never executed); so do the names a package loads lazily
(``_EXPORTS = {...}`` with :func:`mmwsim.lazy.lazy_exports`). ``from pkg import name`` points at
the submodule ``pkg.name`` when there is one, else at ``pkg``.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("mmwsim", "estimation", "planning", "scenes")


def modules(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    """Dotted name -> source file of every module of ``packages`` (a package is its ``__init__``)."""
    out = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _statements(tree: ast.AST):
    """Import statements and lazy-export tables, skipping ``if TYPE_CHECKING:`` blocks."""
    stack = [tree]
    while stack:
        node = stack.pop()
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                stack.extend(child.orelse)
                continue
            if isinstance(child, ast.Import | ast.ImportFrom):
                yield child
            elif isinstance(child, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "_EXPORTS" for t in child.targets
            ):
                yield child
            stack.append(child)


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The deepest known module that ``name`` (a dotted path) is, or is inside."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def imports_of(module: str, path: Path, known: dict[str, Path]) -> set[str]:
    """Modules of ``known`` that ``module`` imports (itself excluded)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out: set[str] = set()

    def relative(level: int, name: str | None) -> str:
        base = package.split(".")
        base = base[: len(base) - (level - 1)] if level > 1 else base
        return ".".join(base + ([name] if name else []))

    for node in _statements(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = relative(node.level, node.module) if node.level else node.module or ""
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:  # a lazy-export table: {".module": ("Name", ...)}
            keys = [k.value for k in node.value.keys if isinstance(k, ast.Constant)]
            targets = [relative(1, k.lstrip(".")) for k in keys]
        for t in targets:
            hit = _resolve(t, known)
            if hit is not None and hit != module:
                out.add(hit)
    return out


def import_graph(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, set[str]]:
    """Module -> the project modules it imports."""
    known = modules(root, packages)
    return {m: imports_of(m, p, known) for m, p in known.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def collapse(graph: dict[str, set[str]], unit) -> dict[str, set[str]]:
    """The graph between ``unit(module)`` groups (edges within a group dropped)."""
    out: dict[str, set[str]] = {}
    for m, targets in graph.items():
        u = unit(m)
        out.setdefault(u, set()).update(unit(t) for t in targets if unit(t) != u)
    return out
