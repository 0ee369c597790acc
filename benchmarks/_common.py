"""Helpers shared by the benchmark scripts (run as ``python benchmarks/NAME.py``)."""

from __future__ import annotations

import time

import numpy as np


def raw_embree_rate(scene, n: int = 2_000_000) -> float:
    """Rays per second of one bare embreex intersect call from the transmitter of ``scene``.

    The float32 origin and direction arrays (``(n, 3)``) are prepared beforehand, so the
    figure is Embree's own throughput on one core: the ceiling any tracer stage can reach.
    """
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.tile(scene.transmitter.array.astype(np.float32), (n, 1))
    t = time.perf_counter()
    scene.ray_caster._scene.run(o, d, output=1)
    return n / (time.perf_counter() - t)


def run_dataset_parser(doc: str):
    """Arguments of the scripts that evaluate a training run: RUN DATASET [--max N] [--sigma DB]."""
    import argparse

    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("dataset")
    ap.add_argument("--max", type=int, default=1000, help="trajectories per split (seeded subset)")
    ap.add_argument("--sigma", type=float, default=6.0, help="fingerprint noise, dB (default 6)")
    return ap


def test_draws(data, n_max: int, sigma: float, length: int | None = None):
    """A seeded subset of at most ``n_max`` trajectories of ``data`` (a SequenceSet), cropped to
    ``length`` steps, and their fingerprints with fresh noise: ``(subset, bits)``, the same on
    every run."""
    import torch

    from estimation import noisy_bits

    if length is not None:
        data = data.crop(0, min(length, data.length))
    data = data.subset(np.sort(np.random.default_rng(0).permutation(data.n)[:n_max]))
    return data, noisy_bits(data, sigma, torch.Generator().manual_seed(1))


def stored_bits(ds, positions: np.ndarray, seed: int):
    """Fingerprints of trajectories ``positions (n, L, 2)`` metres drawn with fresh noise from a
    data set's stored PDPs at their nearest grid points (``Dataset.fingerprints``): a float
    tensor ``(n, L, M, N_s)`` and the grid points ``(n * L,)``."""
    import torch

    idx = ds.nearest(positions.reshape(-1, 2))
    bits = ds.fingerprints(idx, np.random.default_rng(seed))
    return torch.from_numpy(bits.reshape(*positions.shape[:2], *bits.shape[1:])).float(), idx


def predict_batched(est, bits, size: int = 500) -> np.ndarray:
    """``est.predict`` over ``bits`` in batches of ``size`` sequences, as one array."""
    return np.concatenate([est.predict(bits[i : i + size]).numpy() for i in range(0, len(bits), size)])


RECIPE_MINUTES = 30.0
"""The wall-clock budget a model's own epoch count (its cosine schedule's horizon) is sized for."""


def budget_settings(model: str, minutes: float, cap: int | None = None) -> dict:
    """TrainConfig settings that fit a model's own recipe into a budget of ``minutes``.

    A recipe with a cosine schedule decays to zero by its last epoch, so a shorter budget must
    shorten it: its ``epochs`` are scaled by ``minutes / 30`` (the recipe is sized for 30 minutes
    on 2 cores), and its warm-up keeps its share of them; ``cap`` bounds the epochs. Models on the
    plateau schedule get ``epochs = cap`` (the budget and early stopping end them).
    """
    from estimation.models import model_spec

    recipe = model_spec(model).recipe
    if recipe.get("schedule") != "cosine":
        return {} if cap is None else {"epochs": cap}
    epochs = max(2, round(recipe["epochs"] * minutes / RECIPE_MINUTES))
    return {"epochs": epochs if cap is None else min(epochs, cap)}
