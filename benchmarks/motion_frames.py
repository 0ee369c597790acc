"""How well tn-match's sub-cell motion tables predict the test trajectories, frame by frame.

Usage: python benchmarks/motion_frames.py DATASET [--headings 12,24,36] [--blend 0.2]

Fits the sub-cell (lattice) acceleration table on the training split's trajectories snapped to the
lattice, as ``tn-match``'s training does, once in the frame of the motion (the tables of models
trained before the lattice frame: accelerations along and across the motion, blurred by 0.6 bins)
and once in the lattice's own frame per number of heading bins, and prints per kind the mean log
density (nats per step, per square grid unit) of the seen-area test trajectories' lattice
accelerations. Both frames share the bins (one per lattice step), so the figures compare: a
higher one is a sharper prior that still holds on trajectories it was not fitted on.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def _snapped(positions: np.ndarray, grid_xy: np.ndarray) -> np.ndarray:
    """Positions ``(n, L, 2)`` metres in grid units from the first grid point, on the lattice."""
    from estimation.models.candidate_transformer import _place_frames
    from estimation.smoothing.motion import snap_to_lattice

    lo, spacing, _, _ = _place_frames(grid_xy)  # the frame CandidateTransformer.fit_motion snaps in
    return snap_to_lattice((positions - lo) / spacing)


def _lattice_steps(positions: np.ndarray, grid_xy: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Displacements and accelerations ``(m, 2)`` of the trajectories on the lattice."""
    d = np.diff(_snapped(positions, grid_xy), axis=1)
    return torch.from_numpy(d[:, :-1].reshape(-1, 2)), torch.from_numpy(np.diff(d, axis=1).reshape(-1, 2))


def main() -> None:
    from estimation.adapter import load_splits
    from estimation.smoothing.motion import BLEND, SUBCELLS, MotionTable
    from mmwsim.trajectories import KINDS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--headings", default="12,24,36", help="heading bins per quadrant to compare")
    ap.add_argument("--blend", type=float, default=BLEND, help=f"lattice frame's blend (default {BLEND})")
    args = ap.parse_args()
    sets, _ = load_splits(args.dataset, ("train", "test/seen"))
    train, test = sets["train"], sets["test/seen"]
    reach = 16.0 + 0.5 / SUBCELLS
    tables = {"motion frame": MotionTable(bin=1.0 / SUBCELLS, reach=reach)}
    for h in (int(v) for v in args.headings.split(",")):
        tables[f"lattice, {h} headings"] = MotionTable(bin=1.0 / SUBCELLS, reach=reach, headings=h)
    snapped = _snapped(train.positions.astype(np.float64), train.grid_xy)
    for name, table in tables.items():
        table.fit(snapped, blend=None if name == "motion frame" else args.blend)
    kinds = [k for k in ("pedestrian", "hybrid", "vehicle") if (test.kind == KINDS.index(k)).any()]
    print(f"{args.dataset}: mean log density of the test/seen lattice accelerations, nats per step")
    print("| table | " + " | ".join(kinds) + " |")
    print("|---|" + "---:|" * len(kinds))
    for name, table in tables.items():
        cells = []
        for k in kinds:
            v, a = _lattice_steps(
                test.positions[test.kind == KINDS.index(k)].astype(np.float64), test.grid_xy
            )
            cells.append(f"{float(table.log_accel(v, a).mean()):.3f}")
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
