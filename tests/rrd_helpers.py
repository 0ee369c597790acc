"""Reading recordings back in tests."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from rerun.chunk import RrdReader


def entity_rows(path: str | Path) -> Counter:
    """Rows logged per entity path of a recording (blueprint excluded)."""
    rows: Counter = Counter()
    for chunk in RrdReader(str(path)).stream().to_chunks():
        rows[chunk.entity_path] += chunk.num_rows
    return rows


def blueprint_count(path: str | Path) -> int:
    return len(RrdReader(str(path)).blueprints())
