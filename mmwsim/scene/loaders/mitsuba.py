"""Mitsuba XML scenes as exported for Sionna RT.

Reads ``<bsdf type="itu-radio-material">`` (with ``type`` and ``thickness``),
``<bsdf type="radio-material">`` (permittivity and conductivity), on both the optional
diffuse-scattering properties ``scattering_coefficient`` and ``xpd_coefficient`` (floats, as
Sionna RT writes them), ``scattering_pattern`` (string) and ``alpha_r`` (integer), the older
``mat-itu_<name>`` ids, and ``ply`` / ``obj`` shapes with optional ``to_world``
transforms. Coordinates are kept as given. Parsed with defusedxml.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import trimesh
from defusedxml import ElementTree
from defusedxml.common import DefusedXmlException

from ...errors import MmwsimError
from ...materials import Material, get_material
from ..objects import SceneObject, Transmitter
from ..scene import Scene
from .meshes import read_mesh, resolve_inside

__all__ = ["load_mitsuba", "guess_kind"]

_GROUND_NAME = re.compile(r"ground|terrain|floor|plane|road|street|pavement", re.IGNORECASE)


def _props(elem) -> dict[str, str]:
    return {
        c.get("name"): c.get("value")
        for c in elem
        if c.get("name") is not None and c.get("value") is not None
    }


def _float(props: dict[str, str], keys: tuple[str, ...], where: str) -> float | None:
    for k in keys:
        if k in props:
            try:
                value = float(props[k])
            except ValueError:
                raise MmwsimError(f"{where}: {k}={props[k]!r} is not a number") from None
            if not np.isfinite(value):
                raise MmwsimError(f"{where}: {k}={props[k]!r} is not a finite number")
            return value
    return None


def _scattering(props: dict[str, str], where: str) -> dict:
    """Sionna RT's diffuse-scattering properties of a radio-material bsdf, where present."""
    alpha_r = None
    if "alpha_r" in props:
        try:
            alpha_r = int(props["alpha_r"])
        except ValueError:
            raise MmwsimError(f"{where}: alpha_r={props['alpha_r']!r} is not an integer") from None
    return {
        "S": _float(props, ("scattering_coefficient",), where),
        "xpd": _float(props, ("xpd_coefficient",), where),
        "pattern": props.get("scattering_pattern"),
        "alpha_r": alpha_r,
    }


def _material(elem, where: str) -> Material:
    try:
        return _radio_material(elem, where)
    except MmwsimError as e:  # range errors of Material name the material, not the file
        raise MmwsimError(str(e) if str(e).startswith(where) else f"{where}: {e}") from None


def _radio_material(elem, where: str) -> Material:
    kind = elem.get("type", "")
    ident = elem.get("id", "") or ""
    props = _props(elem)
    thickness = _float(props, ("thickness",), where)
    if kind == "itu-radio-material":
        if "type" not in props:
            raise MmwsimError(f"{where}: itu-radio-material {ident!r} has no 'type'")
        return get_material(props["type"], thickness).with_scattering(**_scattering(props, where))
    if kind == "radio-material":
        eps = _float(props, ("relative_permittivity", "eta_r"), where)
        sigma = _float(props, ("conductivity", "sigma"), where)
        if eps is None or sigma is None:
            raise MmwsimError(
                f"{where}: radio-material {ident!r} needs relative_permittivity and conductivity"
            )
        mat = Material.custom(ident or "custom", eps, sigma, thickness)
        return mat.with_scattering(**_scattering(props, where))
    nested = elem.find("bsdf")
    if kind == "twosided" and nested is not None and nested.get("type", "").endswith("radio-material"):
        return _radio_material(nested, where)
    if re.match(r"^(mat-)?itu_", ident):
        return get_material(ident, thickness)
    raise MmwsimError(f"{where}: unknown material {ident or kind!r} (bsdf type {kind!r})")


def _number(text) -> float:
    """A finite float from an attribute (ValueError otherwise, reported as a malformed transform)."""
    value = float(text)
    if not np.isfinite(value):
        raise ValueError(f"{text!r} is not finite")
    return value


def _transform(elem, where: str) -> np.ndarray:
    t = elem.find("transform")
    m = np.eye(4)
    if t is None:
        return m
    for op in t:
        try:
            if op.tag == "matrix":
                vals = [_number(v) for v in op.get("value", "").replace(",", " ").split()]
                step = np.array(vals).reshape(4, 4)
            elif op.tag == "translate":
                step = trimesh.transformations.translation_matrix([_number(op.get(a, 0)) for a in "xyz"])
            elif op.tag == "scale":
                if op.get("value") is not None:
                    s = [_number(op.get("value"))] * 3
                else:
                    s = [_number(op.get(a, 1)) for a in "xyz"]
                step = np.diag(s + [1.0])
            elif op.tag == "rotate":
                axis = [_number(op.get(a, 0)) for a in "xyz"]
                if not any(axis):
                    raise ValueError("zero rotation axis")
                step = trimesh.transformations.rotation_matrix(np.radians(_number(op.get("angle", 0))), axis)
            else:
                raise MmwsimError(f"{where}: unsupported transform {op.tag!r}")
        except ValueError as e:
            raise MmwsimError(f"{where}: malformed {op.tag} transform ({e})") from None
        m = step @ m
    return m


def guess_kind(name: str, mesh: trimesh.Trimesh) -> str:
    """``ground`` for flat horizontal meshes or ground-like names, else ``building``."""
    if _GROUND_NAME.search(name):
        return "ground"
    lo, hi = mesh.bounds
    flat = (hi[2] - lo[2]) < 1e-3 * max(1.0, float(np.linalg.norm(hi[:2] - lo[:2])))
    return "ground" if flat else "building"


def load_mitsuba(path: str | Path, transmitter: tuple[float, float, float] | None = None) -> Scene:
    """Load a Mitsuba XML scene (as exported for Sionna RT).

    Parameters
    ----------
    path : path-like
        The ``.xml`` file; shape file names are relative to its folder and may not leave it.
    transmitter : (3,) float, optional
        Transmitter position, metres (XML scenes carry none).
    """
    path = Path(path)
    try:
        root = ElementTree.parse(str(path)).getroot()
    except FileNotFoundError:
        raise MmwsimError(f"{path}: file not found") from None
    except (ElementTree.ParseError, DefusedXmlException) as e:
        raise MmwsimError(f"{path}: malformed or unsafe XML: {e}") from None
    if root.tag != "scene":
        raise MmwsimError(f"{path}: not a Mitsuba scene (root element <{root.tag}>)")
    materials: dict[str, Material] = {}
    for b in root.findall("bsdf"):
        if b.get("id"):
            materials[b.get("id")] = _material(b, f"{path}: bsdf {b.get('id')!r}")
    objects: list[SceneObject] = []
    for i, s in enumerate(root.findall("shape")):
        name = s.get("id") or f"shape_{i}"
        where = f"{path}: shape {name!r}"
        stype = s.get("type")
        if stype not in ("ply", "obj"):
            raise MmwsimError(f"{where}: unsupported shape type {stype!r} (ply and obj are read)")
        filename = _props(s).get("filename")
        if not filename:
            raise MmwsimError(f"{where}: no filename")
        ref = s.find("ref")
        inline = s.find("bsdf")
        if ref is not None:
            mid = ref.get("id")
            if mid not in materials:
                raise MmwsimError(f"{where}: unknown material {mid!r}")
            material = materials[mid]
        elif inline is not None:
            material = _material(inline, where)
        else:
            raise MmwsimError(f"{where}: no material")
        mesh = read_mesh(resolve_inside(filename, path.parent, where))
        mesh.apply_transform(_transform(s, where))
        name = re.sub(r"^mesh-", "", name)
        objects.append(SceneObject(name, mesh, material, guess_kind(name, mesh)))
    tx = Transmitter(tuple(float(v) for v in transmitter)) if transmitter is not None else None
    try:
        return Scene(objects, transmitter=tx, name=path.stem, source=str(path))
    except MmwsimError as e:
        raise MmwsimError(f"{path}: {e}") from None
