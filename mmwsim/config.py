"""Validated configuration: strict models, TOML reading, one-line errors, content hashes."""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import BaseModel, ConfigDict, Strict, StrictFloat, StrictInt, ValidationError

from .errors import MmwsimError

__all__ = ["Vec2", "Vec3", "Int2", "StrictModel", "read_toml", "validate", "content_hash", "canonical_json"]

M = TypeVar("M", bound=BaseModel)

# TOML arrays arrive as lists: accept them as tuples, but keep the items strict.
Vec2 = Annotated[tuple[StrictFloat, StrictFloat], Strict(False)]
Vec3 = Annotated[tuple[StrictFloat, StrictFloat, StrictFloat], Strict(False)]
Int2 = Annotated[tuple[StrictInt, StrictInt], Strict(False)]


class StrictModel(BaseModel):
    """Base of every config model: unknown keys, mistyped values, NaN and infinities are errors."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file, turning every failure into one-line :class:`MmwsimError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise MmwsimError(f"{p}: file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise MmwsimError(f"{p}: malformed TOML: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise MmwsimError(f"{p}: cannot read: {e}") from None


def validate(model: type[M], data: Any, where: str) -> M:
    """Validate ``data`` against ``model``; the first problem becomes a one-line error naming the key."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        err = e.errors()[0]
        loc = err["loc"]
        if loc and isinstance(loc[-1], int) and err["type"] in ("missing", "too_long"):
            loc, err = loc[:-1], {**err, "type": "length", "msg": "wrong number of values"}
        key = ".".join(str(p) for p in loc) or "(top level)"
        if err["type"] == "extra_forbidden":
            msg = f"unknown key {key!r}"
        elif err["type"] == "missing":
            msg = f"missing key {key!r}"
        else:
            msg = f"key {key!r}: {err['msg']} (got {err.get('input')!r})"
        raise MmwsimError(f"{where}: {msg}") from None


def canonical_json(obj: Any) -> str:
    """Sorted, compact JSON of a config (models are dumped first)."""
    if isinstance(obj, BaseModel):
        obj = obj.model_dump(mode="json")
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def content_hash(obj: Any) -> str:
    """SHA-256 hex digest of :func:`canonical_json`."""
    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()
