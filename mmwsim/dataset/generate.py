"""Scene to data set: trace the receiver grid tile by tile and write the zarr store."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import closing
from pathlib import Path

from ..errors import MmwsimError
from ..files import RECORDING_SUFFIX, check_output_folder, check_suffix
from ..stages import STAGES
from .config import (
    DEFAULT_PATH_CHUNK,
    DEFAULT_TILE,
    CodebookConfig,
    GenerateConfig,
    check_tile_memory,
    resolve_config,
)
from .store import StoreWriter
from .tiles import TileResult, build_plan, compute_tile, install_plan

__all__ = ["generate", "run_tiles"]


def generate(
    scene: str,
    out: str | os.PathLike,
    spacing: float | None = None,
    max_reflections: int = 3,
    workers: int = 1,
    resume: bool = False,
    scheduler: str | None = None,
    rrd: str | os.PathLike | None = None,
    progress: bool = True,
    n_rays: int | None = None,
    codebook: CodebookConfig | None = None,
    band_limited: bool = False,
    tile_size: int = DEFAULT_TILE,
    path_chunk: int = DEFAULT_PATH_CHUNK,
    transmitter: tuple[float, float, float] | None = None,
    diffraction: bool = True,
    diffuse: float | None = None,
    min_path_gain_db: float | None = -180.0,
) -> Path:
    """Generate the data set of ``scene`` into the directory ``out``.

    Parameters
    ----------
    scene : str
        Catalogue name or scene file.
    out : path
        Store directory; written as ``<out>.partial`` and renamed when complete.
    spacing : float, optional
        Receiver spacing, metres (default: the scene's grid).
    max_reflections : int
        Interactions per path: reflections, the diffraction and diffuse scattering together.
    workers : int
        Local processes tracing tiles (1: this process).
    resume : bool
        Continue an unfinished run of the same configuration (or accept a complete one).
    scheduler : str, optional
        Address of a Dask scheduler that runs the tiles instead.
    rrd : path, optional
        Also write a Rerun recording of the result.
    progress : bool
        Show a tqdm progress bar.
    transmitter : (3,) float, optional
        Transmitter position, metres, instead of the scene's (needed for scenes without one).
    diffraction : bool
        Trace singly diffracted paths (with reflections before and after).
    diffuse : float, optional
        Scattering coefficient S set on every material for this run (0..1); None keeps the
        scene's own materials.
    min_path_gain_db : float or None
        Drop paths weaker than this for every pair of polarisations, dB.

    Returns
    -------
    Path of the store. Same configuration gives the same bytes, whatever the
    executor, the number of workers, or interruptions resumed.
    """
    from ..scene import load_scene

    if workers < 1:
        raise MmwsimError(f"--workers must be at least 1, got {workers}")
    out = Path(out)
    if rrd is not None:
        check_suffix(rrd, RECORDING_SUFFIX, "--rrd")
        check_output_folder(rrd, "--rrd")
    scene_obj = load_scene(scene, transmitter=transmitter)
    cfg = resolve_config(
        scene,
        scene_obj,
        spacing,
        max_reflections,
        n_rays,
        codebook,
        tile_size=tile_size,
        path_chunk=path_chunk,
        band_limited=band_limited,
        diffraction=diffraction,
        diffuse=diffuse,
        min_path_gain_db=min_path_gain_db,
    )
    check_tile_memory(cfg, workers if scheduler is None else 1)
    with StoreWriter(out, cfg, cfg.n_beams, resume) as writer:  # holds the data set's lock
        if writer.complete:
            if progress:
                print(f"{out} is already complete (content hash {cfg.hash()[:12]})")
        else:
            todo = range(writer.tiles_done, cfg.n_tiles)
            bar = _bar(cfg, writer.tiles_done, progress)
            # closing: a failed write stops the executor now (pending tiles cancelled)
            with closing(run_tiles(cfg, todo, workers, scheduler)) as results:
                try:
                    for result in results:
                        STAGES.add(result.stages)
                        with STAGES("store"):
                            writer.write(result)
                        bar.update(cfg.tile_range(result.tile)[1] - cfg.tile_range(result.tile)[0])
                finally:
                    bar.close()
            with STAGES("store"):
                writer.finish()
        if rrd is not None:
            from .record import record_dataset
            from .store import Dataset

            record_dataset(Dataset.open(out), rrd, scene=scene_obj)
    return out


def _bar(cfg: GenerateConfig, tiles_done: int, enabled: bool):
    from tqdm import tqdm

    done = min(tiles_done * cfg.tile_size, cfg.n_rx)
    return tqdm(
        total=cfg.n_rx,
        initial=done,
        unit="rx",
        unit_scale=True,
        desc="generate",
        disable=not enabled,
        leave=False,
    )


def run_tiles(
    cfg: GenerateConfig, tiles: Iterable[int], workers: int = 1, scheduler: str | None = None
) -> Iterator[TileResult]:
    """Compute ``tiles`` on the chosen executor and yield the results in tile order.

    With several workers, this process finds the tracer's candidates once and hands them
    to every worker. At most two tiles per worker are in flight, which bounds memory.
    """
    text = cfg.model_dump_json()
    tiles = list(tiles)
    if not tiles:
        return
    if scheduler is not None:
        yield from _dask(cfg, text, tiles, scheduler)
    elif workers == 1:
        for t in tiles:
            yield compute_tile(text, t)
    else:
        from ..workers import worker_pool

        plan = build_plan(cfg)
        # processes that die with this one (also under kill -9), each given the tracer's plan
        pool = worker_pool(workers, install_plan, (cfg.hash(), plan))
        try:
            yield from _windowed(lambda t: pool.submit(compute_tile, text, t), tiles, 2 * workers)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _windowed(submit, tiles: list[int], depth: int) -> Iterator[TileResult]:
    """Keep ``depth`` tiles submitted and yield their results in order; tiles still pending
    when the consumer stops (an error, a closed generator) are cancelled."""
    pending = []
    it = iter(tiles)
    try:
        for t in it:
            pending.append(submit(t))
            if len(pending) >= depth:
                break
        while pending:
            result = pending.pop(0).result()
            nxt = next(it, None)
            if nxt is not None:
                pending.append(submit(nxt))
            yield result
    finally:
        for f in pending:
            f.cancel()


def _dask(cfg: GenerateConfig, text: str, tiles: list[int], address: str) -> Iterator[TileResult]:
    try:
        from distributed import Client
    except ImportError:
        raise MmwsimError("--scheduler needs dask.distributed (pip install 'mmwsim[dask]')") from None
    try:
        client = Client(address, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        raise MmwsimError(f"cannot reach the Dask scheduler at {address!r}: {e}") from None
    try:
        n = max(1, sum(client.nthreads().values()))
        plan = client.scatter(build_plan(cfg), broadcast=True)
        yield from _windowed(lambda t: client.submit(compute_tile, text, t, plan, pure=False), tiles, 2 * n)
    finally:
        client.close()
