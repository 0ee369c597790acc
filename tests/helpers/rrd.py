"""Reading recordings back in tests: data rows per entity, and the default blueprint stored with them.

An ``.rrd`` written with a default blueprint holds two stores: the recording, and a blueprint store
(kind ``blueprint``, same application id) whose entities describe the layout: ``/viewport`` names
the root container, ``/container/<uuid>`` and ``/view/<uuid>`` the containers and views,
``/view/<uuid>/ViewContents`` a view's entity query, ``/time_panel`` the time panel.
"""

from __future__ import annotations

import uuid
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from rerun.chunk import RrdReader

_KINDS = {1: "Tabs", 2: "Horizontal", 3: "Vertical", 4: "Grid"}


def entity_rows(path: str | Path) -> Counter:
    """Rows logged per entity path of a recording (blueprint excluded)."""
    rows: Counter = Counter()
    for chunk in RrdReader(str(path)).stream().to_chunks():
        rows[chunk.entity_path] += chunk.num_rows
    return rows


def blueprint_count(path: str | Path) -> int:
    return len(RrdReader(str(path)).blueprints())


def entity_components(path: str | Path) -> tuple[dict[str, set[str]], set[str]]:
    """Component columns logged per entity, and the entities that have static rows."""
    comps: dict[str, set[str]] = {}
    static: set[str] = set()
    for chunk in RrdReader(str(path)).stream().to_chunks():
        names = {n for n in chunk.to_record_batch().schema.names if ":" in n}
        comps.setdefault(chunk.entity_path, set()).update(names)
        if not chunk.timeline_names and names:
            static.add(chunk.entity_path)
    return comps, static


@dataclass
class View:
    kind: str
    name: str | None
    origin: str
    query: list[str]


@dataclass
class Container:
    kind: str
    name: str | None
    contents: list[str]


@dataclass
class StoredBlueprint:
    application_id: str
    root: str
    containers: dict[str, Container] = field(default_factory=dict)
    views: dict[str, View] = field(default_factory=dict)
    timeline: str | None = None

    def tabs(self) -> list[str]:
        """Names of the root's children, in order."""
        root = self.containers[self.root]
        return [(self.containers.get(c) or self.views[c]).name for c in root.contents]

    def walk(self, item: str | None = None):
        """Every container and view id under ``item`` (the root by default), depth first."""
        item = self.root if item is None else item
        yield item
        if item in self.containers:
            for child in self.containers[item].contents:
                yield from self.walk(child)


def read_blueprint(path: str | Path) -> StoredBlueprint:
    """The one blueprint store of a recording, as containers and views."""
    reader = RrdReader(str(path))
    (store,) = reader.blueprints()
    comps: dict[str, dict] = {}
    for chunk in reader.stream(store=store).to_chunks():
        batch = chunk.to_record_batch()
        values = comps.setdefault(chunk.entity_path.lstrip("/"), {})
        for i, name in enumerate(batch.schema.names):
            if ":" in name and not name.startswith("rerun."):
                column = batch.column(i).to_pylist()
                if column and column[-1] is not None:
                    values[name.split(":", 1)[1]] = column[-1]

    def one(v):
        return v[0] if isinstance(v, list) and len(v) == 1 else v

    root = "container/" + str(uuid.UUID(bytes=bytes(one(comps["viewport"]["root_container"]))))
    bp = StoredBlueprint(store.application_id, root)
    for ent, c in comps.items():
        if ent.startswith("container/"):
            bp.containers[ent] = Container(
                _KINDS[int(one(c["container_kind"]))],
                one(c.get("display_name")),
                list(c.get("contents") or []),
            )
        elif ent.startswith("view/") and "class_identifier" in c:
            query = comps.get(f"{ent}/ViewContents", {}).get("query", [])
            bp.views[ent] = View(
                one(c["class_identifier"]), one(c.get("display_name")), one(c["space_origin"]), list(query)
            )
    bp.timeline = one(comps.get("time_panel", {}).get("timeline"))
    return bp


def query_matches(view: View, entities) -> set[str]:
    """Entities (``/a/b`` paths) a view's query selects: ``path`` or ``path/**``, ``- ...`` excludes."""
    origin = "/" + view.origin.strip("/")

    def expand(expr: str) -> tuple[str, bool]:
        expr = expr.replace("$origin", origin.rstrip("/") or "/").strip()
        sub = expr.endswith("/**")
        path = "/" + expr[: -3 if sub else None].strip("/")
        return path, sub

    def hit(ent: str, path: str, sub: bool) -> bool:
        return ent == path or (sub and (path == "/" or ent.startswith(path + "/")))

    rules = [(e.startswith("- "), *expand(e[2:] if e[:2] in ("- ", "+ ") else e)) for e in view.query]
    rules.sort(key=lambda r: (len(r[1]), not r[2], r[0]))  # the most specific matching rule wins
    out = set()
    for ent in entities:
        keep = False
        for exclude, path, sub in rules:
            if hit(ent, path, sub):
                keep = not exclude
        if keep:
            out.add(ent)
    return out


# What each view class draws: a view whose query selects none of these shows nothing.
_DRAWN = {
    "3D": ("Mesh3D:", "Points3D:", "LineStrips3D:", "Image:", "Pinhole:"),
    "2D": ("Image:", "Points2D:", "LineStrips2D:"),
    "BarChart": ("BarChart:values",),
    "TextDocument": ("TextDocument:text",),
    "Tensor": ("Tensor:data",),
    "TimeSeries": ("Scalars:scalars",),
}


def check_blueprint(path: str | Path, tabs: list[str], timeline: str | None = None) -> StoredBlueprint:
    """Assert that a recording's stored blueprint reads well, and return it.

    - one blueprint store of the project's application, its root a tab container with ``tabs``;
    - every container and view named;
    - every view selects at least one entity it can draw, and at least one of those is static, so
      it shows something whatever timeline is active;
    - a tensor view selects exactly one tensor (the viewer refuses more);
    - the time panel opens on ``timeline``.
    """
    bp = read_blueprint(path)
    comps, static = entity_components(path)
    assert bp.application_id == "mmwsim"
    assert bp.containers[bp.root].kind == "Tabs"
    assert bp.tabs() == tabs, bp.tabs()
    for item in bp.walk():
        thing = bp.containers.get(item) or bp.views[item]
        assert thing.name, f"unnamed {item}"
    for item in bp.walk():
        if item not in bp.views:
            continue
        view = bp.views[item]
        drawn = {
            e for e in query_matches(view, comps) if any(c.startswith(_DRAWN[view.kind]) for c in comps[e])
        }
        assert drawn, f"view {view.name!r} ({view.origin}, {view.query}) selects nothing it can draw"
        assert drawn & static, f"view {view.name!r} draws nothing static: empty on other timelines"
        if view.kind == "Tensor":
            assert len(drawn) == 1, f"tensor view {view.name!r} selects {len(drawn)} tensors"
    assert bp.timeline == timeline, bp.timeline
    return bp
