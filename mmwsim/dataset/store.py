"""The zarr v3 data set: layout, tile-by-tile writer with a commit marker, and the reader.

Layout (all arrays zstd-compressed)::

    /                      attrs["mmwsim"]: format, version, config, content_hash, summary
    grid/                  attrs: origin, spacing, shape, height (the ReceiverGrid)
    grid/positions         (n_rx, 3) float64, metres; index = ix + nx * iy
    grid/outdoors          (n_rx,) bool
    grid/valid             (n_rx,) bool: outdoors and some PDP entry in the bin window >= threshold
    grid/pdp               (n_rx, n_beams, n_bins) float16, dBm, -inf = no signal
    grid/paths/start       (n_rx,) int64: receiver i's paths are start[i] : start[i] + count[i]
    grid/paths/count       (n_rx,) int32
    grid/paths/delay       (n_slots,) float64 s (NaN in unused slots)
    grid/paths/jones       (n_slots, 2, 2) complex64 (Paths' convention, includes lambda / 4 pi L)
    grid/paths/aod, aoa    (n_slots, 2) float32 (zenith, azimuth), radians
    grid/paths/order       (n_slots,) int8 interactions (reflections, diffraction, diffuse)
    grid/paths/objects     (n_slots, K) int32 scene object per interaction, -1 pads
    grid/paths/faces       (n_slots, K) int32 triangle per interaction, -1 pads
    grid/paths/points      (n_slots, K, 3) float32 interaction points, metres
    grid/paths/types       (n_slots, K) int8 interaction kinds (mmwsim.tracer.Interaction), 0 pads
    trajectories/<split>   added later by ``mmwsim trajectories`` (mmwsim.trajectories.store), as one
                           atomic rename; not part of the content hash, which covers the generation

Each tile's paths start on a chunk boundary of the path arrays (the slots after
them up to the next boundary stay unused), so a tile's writes never touch another
tile's chunks: a killed run resumes by redoing the uncommitted tile and ends with
the same bytes. The run writes into ``<out>.partial`` and renames it when done, holding the
lock ``.<out>.lock`` (:mod:`mmwsim.locks`) from start to finish, so a second writer is refused.
A write that fails (disk full, read-only) keeps an unfinished run that has committed tiles
(resumable) and removes one that has not.
"""

from __future__ import annotations

import json
import os
from dataclasses import astuple
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import ZstdCodec

from ..errors import MmwsimError
from ..faults import fault
from ..files import reading, remove_tree, write_error, writing
from ..fingerprints import FingerprintSampler, GridField, NoiseModel, TracedField, receive_pattern
from ..fingerprints.field import Lookup
from ..locks import OutputLock
from ..scene import ReceiverGrid
from ..tracer.paths import Paths
from .config import GenerateConfig

__all__ = ["FORMAT", "Dataset", "StoreWriter", "partial_path"]

FORMAT = "mmwsim-dataset"
FORMAT_VERSION = 2
MARKER = ".mmwsim-progress.json"
_ZSTD = ZstdCodec(level=3, checksum=False)

PATH_FIELDS = ("delay", "jones", "aod", "aoa", "order", "objects", "faces", "points", "types")


def partial_path(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


def _path_specs(cfg: GenerateConfig) -> dict[str, tuple[tuple[int, ...], str, object]]:
    k = max(cfg.max_reflections, 1)
    return {
        "delay": ((), "float64", np.nan),
        "jones": ((2, 2), "complex64", 0),
        "aod": ((2,), "float32", np.nan),
        "aoa": ((2,), "float32", np.nan),
        "order": ((), "int8", -1),
        "objects": ((k,), "int32", -1),
        "faces": ((k,), "int32", -1),
        "points": ((k, 3), "float32", np.nan),
        "types": ((k,), "int8", 0),
    }


class StoreWriter:
    """Creates or reopens ``<out>.partial`` and appends tiles in order.

    Holds the data set's lock (:class:`mmwsim.locks.OutputLock`) from construction until
    :meth:`finish` or :meth:`close` (or the end of a ``with`` block).

    Parameters
    ----------
    out : path
        Final store directory.
    cfg : GenerateConfig
    n_beams : int
    resume : bool
        Continue a partial store of the same configuration; without it an existing
        store or partial store is an error.

    Raises
    ------
    MmwsimError
        If another process is writing the store (naming it), the output exists and is not a
        data set of this configuration, or the folder cannot be written.
    """

    def __init__(self, out: Path, cfg: GenerateConfig, n_beams: int, resume: bool):

        self.out, self.cfg, self.n_beams = Path(out), cfg, int(n_beams)
        self.tmp = partial_path(self.out)
        self.hash = cfg.hash()
        self.complete = False
        self.created = False
        parent = self.out.parent
        if not parent.is_dir():
            raise MmwsimError(f"{self.out}: folder {parent} does not exist or is not writable")
        self._lock: OutputLock | None = OutputLock(self.out, "data set").acquire()
        try:
            self._open(resume)
        except BaseException:
            self.close()
            raise

    def _open(self, resume: bool) -> None:
        from ..version import __version__

        if self.out.exists():
            other = _stored_hash(self.out)
            if other is None:
                raise MmwsimError(
                    f"{self.out}: exists and is not an mmwsim data set (remove it or choose another --out)"
                )
            if not resume:
                raise MmwsimError(f"{self.out} already exists (use --resume to check it, or remove it)")
            if other != self.hash:
                raise MmwsimError(
                    f"{self.out} holds a data set of another configuration "
                    f"(content hash {str(other)[:12]}, this run {self.hash[:12]})"
                )
            self.complete = True
            with writing(self.out):
                (self.out / MARKER).unlink(missing_ok=True)  # a run killed between rename and cleanup
            return
        if not os.access(self.out.parent, os.W_OK):
            raise MmwsimError(f"{self.out}: folder {self.out.parent} does not exist or is not writable")
        if self.tmp.exists():
            if not resume:
                raise MmwsimError(f"{self.tmp} holds an unfinished run (use --resume, or remove it)")
            other = _stored_hash(self.tmp)
            if other is None:
                raise MmwsimError(f"{self.tmp}: not an unfinished mmwsim data set (remove it)")
            if other != self.hash:
                raise MmwsimError(
                    f"{self.tmp} holds an unfinished run of another configuration "
                    f"(content hash {str(other)[:12]}, this run {self.hash[:12]})"
                )
            marker = self._read_marker()
            self.tiles_done, self.slots = marker["tiles_done"], marker["slots"]
            with reading(self.tmp, "unfinished data set"):
                self.root = zarr.open_group(str(self.tmp), mode="r+", zarr_format=3)
            return
        self.tiles_done, self.slots = 0, 0
        self.created = True
        try:
            fault("dataset.create", self.tmp)
            self._create(__version__)
        except OSError as e:
            self.discard()
            raise write_error(e, self.tmp, "nothing was kept") from None
        except BaseException:
            self.discard()
            raise

    def __enter__(self) -> StoreWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and self.created and self.tiles_done == 0 and not self.complete:
            self.discard()  # failed before its first tile (executor unreachable, ...): nothing to resume
        self.close()

    def close(self) -> None:
        """Release the data set's lock (the unfinished store, if any, stays resumable)."""
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def _failed(self, e: OSError) -> MmwsimError:
        """The one-line error of a failed write: keep a resumable run, drop one with nothing in it."""
        if self.tiles_done == 0 and self.created:
            self.discard()
            return write_error(e, self.tmp, "nothing was kept")
        return write_error(e, self.tmp, "the unfinished run is kept: run again with --resume")

    # ------------------------------------------------------------------ creation
    def _create(self, version: str) -> None:
        cfg = self.cfg
        root = zarr.open_group(str(self.tmp), mode="w", zarr_format=3)
        root.attrs["mmwsim"] = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "version": version,
            "content_hash": self.hash,
            "config": cfg.model_dump(mode="json"),
            "complete": False,
        }
        grid = ReceiverGrid(cfg.grid_origin, cfg.grid_spacing, cfg.grid_shape, cfg.grid_height)
        g = root.create_group("grid")
        g.attrs.update(
            {
                "origin": list(grid.origin),
                "spacing": grid.spacing,
                "shape": list(grid.shape),
                "height": grid.height,
            }
        )
        n, t = cfg.n_rx, cfg.tile_size

        def arr(group, name, shape, chunks, dtype, fill):
            return group.create_array(
                name, shape=shape, chunks=chunks, dtype=dtype, compressors=_ZSTD, fill_value=fill
            )

        pos = arr(g, "positions", (n, 3), (t, 3), "float64", 0.0)
        pos[:] = grid.positions()
        arr(g, "outdoors", (n,), (t,), "bool", False)
        arr(g, "valid", (n,), (t,), "bool", False)
        arr(
            g,
            "pdp",
            (n, self.n_beams, cfg.n_bins),
            (cfg.pdp_chunk, self.n_beams, cfg.n_bins),
            "float16",
            -np.inf,
        )
        p = g.create_group("paths")
        arr(p, "start", (n,), (t,), "int64", 0)
        arr(p, "count", (n,), (t,), "int32", 0)
        for name, (tail, dtype, fill) in _path_specs(cfg).items():
            arr(p, name, (0,) + tail, (cfg.path_chunk,) + tail, dtype, fill)
        self.root = root
        self._write_marker()

    # ------------------------------------------------------------------ marker
    def _marker_path(self) -> Path:
        return self.tmp / MARKER

    def _read_marker(self) -> dict:
        try:
            m = json.loads(self._marker_path().read_text())
            if not isinstance(m, dict) or m.get("content_hash") != self.hash:
                raise ValueError("not this run's marker")
            if not all(isinstance(m.get(k), int) and m[k] >= 0 for k in ("tiles_done", "slots")):
                raise ValueError("no tile count")
            return m
        except (OSError, ValueError) as e:
            raise MmwsimError(f"{self.tmp}: unreadable progress marker ({e}); remove the folder") from None

    def _write_marker(self) -> None:
        tmp = self.tmp / (MARKER + ".tmp")
        tmp.write_text(
            json.dumps({"content_hash": self.hash, "tiles_done": self.tiles_done, "slots": self.slots})
        )
        os.replace(tmp, self._marker_path())

    # ------------------------------------------------------------------ tiles
    def write(self, result) -> None:
        """Write tile ``result`` (a :class:`~mmwsim.dataset.tiles.TileResult`), the next one in order."""
        if result.tile != self.tiles_done:
            raise RuntimeError(f"tile {result.tile} written out of order (expected {self.tiles_done})")
        try:
            fault("dataset.tile", self.tmp)
            self._write(result)
        except OSError as e:
            raise self._failed(e) from None
        fault("dataset.committed", self.tmp)

    def _write(self, result) -> None:
        cfg = self.cfg
        start, stop = cfg.tile_range(result.tile)
        g = self.root["grid"]
        m = int(result.count.sum())
        c = cfg.path_chunk
        used = -(-m // c) * c
        p = g["paths"]
        if used:
            for name, (tail, dtype, fill) in _path_specs(cfg).items():
                a = p[name]
                a.resize((self.slots + used,) + tail)
                block = np.full((used,) + tail, fill, dtype=dtype)
                block[:m] = result.paths[name]
                a[self.slots : self.slots + used] = block
        first = self.slots + np.concatenate([[0], np.cumsum(result.count[:-1])]).astype(np.int64)
        p["start"][start:stop] = np.where(result.count > 0, first, 0)
        p["count"][start:stop] = result.count
        g["pdp"][start:stop] = result.pdp
        g["outdoors"][start:stop] = result.outdoors
        g["valid"][start:stop] = result.valid
        self.tiles_done += 1
        self.slots += used
        self._write_marker()

    def finish(self) -> None:
        """Record the summary, drop the marker and move the store into place."""
        if self.complete:
            self.close()
            return
        info = dict(self.root.attrs["mmwsim"])
        valid = np.asarray(self.root["grid/valid"][:])
        info.update(
            complete=True,
            n_valid=int(valid.sum()),
            n_paths=int(np.asarray(self.root["grid/paths/count"][:]).sum()),
        )
        try:
            self.root.attrs["mmwsim"] = info
            # Rename first, then drop the marker: a kill in between leaves a complete store
            # whose stray marker the next --resume removes.
            fault("dataset.rename", self.out)
            os.replace(self.tmp, self.out)
        except OSError as e:
            raise self._failed(e) from None
        fault("dataset.renamed", self.out)
        self.complete = True
        with writing(self.out, "the data set is complete"):
            (self.out / MARKER).unlink()
        self.close()

    def discard(self) -> None:
        """Remove the unfinished store."""
        remove_tree(self.tmp)


def _stored_hash(path: Path) -> str | None:
    try:
        meta = json.loads((Path(path) / "zarr.json").read_text())
        return meta["attributes"]["mmwsim"]["content_hash"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


class Dataset:
    """A generated data set, for library users.

    Open with :meth:`open`. Arrays are read lazily from the zarr store unless said.

    Attributes
    ----------
    root : zarr.Group
        The store's root group (``mode="r+"`` lets other stages add groups, e.g. trajectories).
    config : dict
        Resolved configuration the data set was generated with.
    content_hash : str
    version : str
        mmwsim version that wrote it.
    grid : ReceiverGrid
    """

    def __init__(self, root: zarr.Group, path: Path):
        info = root.attrs.get("mmwsim")
        if not isinstance(info, dict) or info.get("format") != FORMAT:
            raise MmwsimError(f"{path}: not an mmwsim data set")
        if not info.get("complete"):
            raise MmwsimError(f"{path}: the data set is incomplete (resume its generation)")
        self.root, self.path = root, Path(path)
        self.config: dict = info["config"]
        self.content_hash: str = info["content_hash"]
        self.version: str = info["version"]
        ga = root["grid"].attrs
        self.grid = ReceiverGrid(
            tuple(ga["origin"]), float(ga["spacing"]), tuple(ga["shape"]), float(ga["height"])
        )
        self._valid: np.ndarray | None = None
        self._positions: np.ndarray | None = None
        self._samplers: dict = {}

    @classmethod
    def open(cls, path: str | os.PathLike, mode: str = "r") -> Dataset:
        """Open the data set at ``path`` (``mode`` ``"r"`` or ``"r+"``)."""
        p = Path(path)
        if not (p / "zarr.json").is_file():
            hint = " (an unfinished run is next to it: resume it)" if partial_path(p).exists() else ""
            raise MmwsimError(f"{p}: no data set there{hint}")
        with reading(p, "mmwsim data set"):
            ds = cls(zarr.open_group(str(p), mode=mode, zarr_format=3), p)
            ds._check_arrays()
        return ds

    def _check_arrays(self) -> None:
        """Open every array of the layout (their metadata) and check it fits the grid, so that a
        damaged store fails here, in one line, rather than halfway through a computation."""
        n = self.grid.size
        names = [
            "grid/positions",
            "grid/outdoors",
            "grid/valid",
            "grid/pdp",
            "grid/paths/start",
            "grid/paths/count",
        ]
        for name in names + [f"grid/paths/{f}" for f in PATH_FIELDS]:
            a = self.root[name]
            if not isinstance(a, zarr.Array):
                raise ValueError(f"{name} is not an array")
            if name.count("/") == 1 or name.endswith(("start", "count")):
                if a.shape[0] != n:
                    raise ValueError(f"{name} has {a.shape[0]} rows for a grid of {n} receivers")
        if len(self.root["grid/pdp"].shape) != 3:
            raise ValueError("grid/pdp is not (receivers, beams, bins)")

    # ------------------------------------------------------------------ arrays
    @property
    def n_rx(self) -> int:
        return self.grid.size

    @property
    def positions(self) -> np.ndarray:
        """(n_rx, 3) float64 receiver positions, metres."""
        if self._positions is None:
            self._positions = self._read("grid/positions")
        return self._positions

    @property
    def valid(self) -> np.ndarray:
        """(n_rx,) bool: outdoors and detected (some noise-free PDP entry above the threshold)."""
        if self._valid is None:
            self._valid = self._read("grid/valid")
        return self._valid

    @property
    def outdoors(self) -> np.ndarray:
        """(n_rx,) bool."""
        return self._read("grid/outdoors")

    def _read(self, name: str) -> np.ndarray:
        with reading(self.path / name, "data set array"):
            return np.asarray(self.root[name][:])

    @property
    def pdp(self) -> zarr.Array:
        """(n_rx, n_beams, n_bins) float16 dBm (a lazy zarr array; ``[...]`` reads numpy)."""
        return self.root["grid/pdp"]

    @property
    def n_beams(self) -> int:
        return int(self.pdp.shape[1])

    # ------------------------------------------------------------------ lookups
    def nearest(self, xy: np.ndarray) -> np.ndarray:
        """(...) int64 index of the grid point nearest to each (..., 2) or (..., 3) position, metres
        (:meth:`ReceiverGrid.nearest_index <mmwsim.scene.ReceiverGrid.nearest_index>`)."""
        return self.grid.nearest_index(xy)

    def paths(self, index: np.ndarray | int) -> Paths:
        """The stored paths of receivers ``index`` (re-traced nothing), as :class:`Paths`.

        ``rx_index`` of the result counts the given receivers 0..len(index)-1.
        """
        idx = np.atleast_1d(np.asarray(index, dtype=np.int64))
        p = self.root["grid/paths"]
        start = np.asarray(p["start"].get_coordinate_selection(idx))
        count = np.asarray(p["count"].get_coordinate_selection(idx)).astype(np.int64)
        sel = np.concatenate(
            [np.arange(s, s + c) for s, c in zip(start, count, strict=True)] + [np.zeros(0, int)]
        )
        # Stores of format 1 (before diffraction) hold no interaction kinds: all are reflections.
        names = [n for n in PATH_FIELDS if n in p]
        cols = {name: np.asarray(p[name].get_orthogonal_selection((sel,))) for name in names}
        from ..constants import SPEED_OF_LIGHT

        return Paths(
            tx=np.asarray(self.config["transmitter"], dtype=np.float64),
            rx=self.positions[idx],
            frequency=float(self.config["frequency"]),
            rx_index=np.repeat(np.arange(len(idx)), count),
            length=cols["delay"] * SPEED_OF_LIGHT,
            jones=cols["jones"].astype(np.complex128),
            aod=cols["aod"].astype(np.float64),
            aoa=cols["aoa"].astype(np.float64),
            order=cols["order"],
            faces=cols["faces"].astype(np.int64),
            objects=cols["objects"],
            points=cols["points"].astype(np.float64),
            types=cols.get("types"),
        )

    # ------------------------------------------------------------------ scene
    def scene(self, spec: str | None = None):
        """The scene the data set was generated from, with its transmitter (see
        :meth:`GenerateConfig.load_scene`; ``spec`` loads it from elsewhere, checked to be the same)."""
        return GenerateConfig.model_validate(self.config).load_scene(spec)

    # ------------------------------------------------------------------ fingerprints
    def noise(
        self, sigma_db: float | None = None, threshold_dbm: float | None = None, bins=None
    ) -> NoiseModel:
        """The fingerprint noise model of the data set's config, with any of its values replaced."""
        return NoiseModel(
            self.config["sigma_db"] if sigma_db is None else float(sigma_db),
            self.config["threshold_dbm"] if threshold_dbm is None else float(threshold_dbm),
            tuple(self.config["bins"] if bins is None else bins),
        )

    def sampler(self, sigma_db: float | None = None, threshold_dbm: float | None = None, bins=None):
        """A :class:`~mmwsim.fingerprints.FingerprintSampler` over all receivers (built once per
        :meth:`noise` model, cached)."""
        noise = self.noise(sigma_db, threshold_dbm, bins)
        if noise not in self._samplers:
            self._samplers[noise] = FingerprintSampler(self.pdp, noise)
        return self._samplers[noise]

    def field(self, method: Lookup = "nearest", bins: slice | None = None) -> GridField:
        """The data set's PDPs as a fingerprint field over its grid (read lazily from the store).

        Parameters
        ----------
        method : {"nearest", "linear"}
        bins : slice, optional
            Default: the fingerprint window (``config["bins"]``, bins 1..81).
        """
        bins = slice(*self.config["bins"]) if bins is None else bins
        return GridField(
            self.grid, self.pdp, self.valid, method, bins, sampler=lambda n: self.sampler(*astuple(n))
        )

    def traced_field(self, bins: slice | None = None, scene=None) -> TracedField:
        """A fingerprint field traced exactly with the data set's own configuration.

        Scene and transmitter, reflections, candidate rays, codebook, receive gain, transmit
        power, sampling and receiver height are the ones the data set was generated with, so at
        grid points it gives the stored PDPs (before their float16 rounding).

        Parameters
        ----------
        bins : slice, optional
            Default: the fingerprint window.
        scene : Scene, optional
            The data set's scene if already loaded.
        """
        from .tiles import make_codebook_from

        cfg = GenerateConfig.model_validate(self.config)
        return TracedField.from_scene(
            self.scene() if scene is None else scene,
            make_codebook_from(cfg),
            cfg.max_reflections,
            cfg.n_rays,
            slice(*cfg.bins) if bins is None else bins,
            height=cfg.grid_height,
            rx_pattern=receive_pattern(cfg.rx_gain_dbi),
            tx_power_dbm=cfg.tx_power_dbm,
            sample_rate=cfg.sample_rate,
            n_bins=cfg.n_bins,
            band_limited=cfg.band_limited,
        )

    def fingerprints(
        self,
        index: np.ndarray,
        rng: np.random.Generator,
        sigma_db: float | None = None,
        threshold_dbm: float | None = None,
        bins=None,
        threads: int = 1,
    ) -> np.ndarray:
        """Fingerprints of receivers ``index`` (n,) with fresh noise: (n, n_beams, n_window) uint8.

        Defaults (sigma, threshold, bin window) come from the data set's config.
        """
        return self.sampler(sigma_db, threshold_dbm, bins).sample(index, rng, threads=threads)

    def __repr__(self) -> str:
        nv = int(self.valid.sum())
        return (
            f"Dataset({str(self.path)!r}, {self.grid.shape[0]} x {self.grid.shape[1]} receivers at "
            f"{self.grid.spacing:g} m, {nv} valid, {self.n_beams} beams)"
        )
