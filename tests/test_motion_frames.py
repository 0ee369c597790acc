"""Motion tables in the lattice frame: classes by speed and heading within the octant, read alike
by the tensor code and the compiled kernels, and sharper than the motion frame on a lattice."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation.smoothing.beam import _frame
from estimation.smoothing.motion import HEADINGS, MotionTable, heading_slopes, snap_to_lattice


def _steady_walkers(n, seed, length=8):
    """Users at a constant velocity (1.4 or 4 units per step, any heading) from anywhere,
    snapped to the 1/3 lattice: their accelerations are the lattice's quantisation alone."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0, 2 * np.pi, n)
    v = rng.choice([1.4, 4.0], n)[:, None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    start = rng.uniform(0, 50, (n, 2))
    return snap_to_lattice(start[:, None] + np.arange(length)[None, :, None] * v[:, None])


def _quarter_turns():
    """The rotations of the square lattice onto itself as 2 x 2 matrices."""
    return [
        torch.tensor([[c, -s], [s, c]], dtype=torch.float64) for c, s in ((1, 0), (0, 1), (-1, 0), (0, -1))
    ]


def test_a_lattice_frame_table_is_the_same_under_every_quarter_turn_and_keeps_left_from_right():
    table = MotionTable.lattice().fit(_steady_walkers(400, 0))
    assert int(table.headings) == HEADINGS and table.log_accel_table.shape[0] == 12 * HEADINGS
    rng = np.random.default_rng(1)
    v = torch.from_numpy(rng.integers(-15, 16, (500, 2)) / 3.0)
    a = torch.from_numpy(rng.integers(-3, 4, (500, 2)) / 3.0)
    base = table.log_accel(v, a)
    for m in _quarter_turns():
        assert torch.equal(table.log_accel(v @ m.T, a @ m.T), base)
    # it tells headings apart within the quadrant: 3, 40 and 80 degrees are other classes
    v = torch.tensor([[4.0, 0.2], [3.06, 2.57], [0.7, 3.94]], dtype=torch.float64)  # all at 4 per step
    _, _, cls = table._classify(v, torch.zeros(2))
    assert len(set(cls.tolist())) == 3 and len(set((cls // HEADINGS).tolist())) == 1
    # a turn to the left is not its mirror image: walkers that only ever turn left
    rng = np.random.default_rng(2)
    heading = rng.uniform(0, 2 * np.pi, 300)[:, None] + np.radians(20) * np.arange(8)
    left = snap_to_lattice(np.cumsum(4.0 * np.stack([np.cos(heading), np.sin(heading)], -1), 1))
    table = MotionTable.lattice().fit(left)
    v = torch.tensor([4.0, 0.0], dtype=torch.float64)
    turn = torch.tensor([4.0 * np.cos(np.radians(20)) - 4.0, 4.0 * np.sin(np.radians(20))])
    turn = torch.round(turn * 3) / 3
    mirror = turn * torch.tensor([1.0, -1.0])
    assert float(table.log_accel(v, turn) - table.log_accel(v, mirror)) > 3.0


def test_the_kernels_read_the_class_and_components_the_tensor_code_reads():
    rng = np.random.default_rng(2)
    # lattice values (on the axes, the diagonals and zero included) and continuous ones
    v = np.concatenate(
        [
            rng.integers(-12, 13, (400, 2)) / 3.0,
            rng.normal(0, 4, (400, 2)),
            [[0, 0], [2, 2], [-2, 2], [0, -3]],
        ]
    )
    a = rng.normal(0, 1, v.shape)
    for headings in (0, 1, HEADINGS):
        table = MotionTable(bin=1 / 3, reach=16 + 1 / 6, headings=headings)
        p, q, cls = (x.numpy() for x in table._classify(torch.from_numpy(v), torch.from_numpy(a)))
        edges, slopes = table.speed_edges.double().numpy(), heading_slopes(headings)
        for i in range(len(v)):
            f00, f01, f10, f11, c = _frame(v[i, 0], v[i, 1], edges, headings, slopes)
            assert c == cls[i]
            assert f00 * a[i, 0] + f01 * a[i, 1] == pytest.approx(p[i], abs=1e-12)
            assert f10 * a[i, 0] + f11 * a[i, 1] == pytest.approx(q[i], abs=1e-12)


def test_on_a_lattice_the_lattice_frame_predicts_steady_motion_better_than_the_motion_frame():
    train, test = _steady_walkers(3000, 3), _steady_walkers(500, 4)
    v = torch.from_numpy(np.diff(test, axis=1)[:, :-1].reshape(-1, 2))
    a = torch.from_numpy(np.diff(test, 2, axis=1).reshape(-1, 2))
    # both tables have the same bins (one per lattice step), so their densities compare; the
    # motion frame's unblurred, to compare the frames alone
    rotated = MotionTable(bin=1 / 3, reach=16 + 1 / 6).fit(train, smooth=0.0)
    lattice = MotionTable.lattice().fit(train)
    gain = float(lattice.log_accel(v, a).mean() - rotated.log_accel(v, a).mean())
    assert gain > 0.25  # 0.35 nats per step
    # and the fit does not blur the lattice's pattern by default (the motion frame's does)
    assert float(lattice.log_accel(v, a).mean()) > float(
        MotionTable.lattice().fit(train, smooth=0.6).log_accel(v, a).mean()
    )


def test_a_sparse_class_takes_its_speed_bands_histogram():
    walkers = _steady_walkers(40, 5)  # too few per heading bin for min_count=100
    table = MotionTable.lattice().fit(walkers, min_count=100)
    pooled = MotionTable(bin=1 / 3, reach=16 + 1 / 6, headings=1).fit(walkers, min_count=100)
    counts = table.band_count.numpy().reshape(-1, HEADINGS)
    band = int(np.argmax(counts.sum(1)))
    assert counts[band].sum() >= 100 and (counts[band] < 100).all()
    for k in range(HEADINGS):
        assert torch.equal(table.log_accel_table[band * HEADINGS + k], pooled.log_accel_table[band])


def test_a_model_saved_before_frames_loads_in_the_motion_frame():
    old = MotionTable().fit(_steady_walkers(200, 6) * 3)  # 12 classes, reach 16, no frame kept
    state = {k: v for k, v in old.state_dict().items() if k != "headings"}
    table = MotionTable(reach=16.25, headings=HEADINGS)
    table.load_state_dict(state)
    assert int(table.headings) == 0 and table.reach == 16.0
    v, a = torch.tensor([[4.0, 1.0], [-2.0, 6.0]]), torch.tensor([[0.5, -0.3], [1.0, 2.0]])
    assert torch.equal(table.log_accel(v, a), old.log_accel(v, a))
    # and one saved with its frame loads in it
    new = MotionTable(reach=16.25, headings=HEADINGS).fit(_steady_walkers(200, 6) * 3)
    again = MotionTable()
    again.load_state_dict(new.state_dict())
    assert int(again.headings) == HEADINGS and again.reach == 16.25
    assert torch.equal(again.log_accel(v, a), new.log_accel(v, a))


def test_the_alternatives_of_a_lattice_frame_table_keep_its_frame():
    rng = np.random.default_rng(7)
    speed = rng.choice([6.5, 8.0, 9.5], (600, 1, 1))
    heading = rng.uniform(0, 2 * np.pi, (600, 1))
    fast = snap_to_lattice(
        speed * np.arange(6)[None, :, None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    )
    table = MotionTable.lattice().fit(np.concatenate([fast, _steady_walkers(600, 8, length=6)]), min_count=20)
    # the broadened copy: a reversal at 8 per step is a plain turn now, at any heading
    wide = table.broadened()
    for deg in (0.0, 20.0, 33.0):
        u = torch.tensor([np.cos(np.radians(deg)), np.sin(np.radians(deg))])
        v = 8.0 * u
        assert float(wide.log_accel(v, -2 * v) - table.log_accel(v, -2 * v)) > 5.0
    # still densities where the turn ring fits inside the reach (mid speeds up to 6 per step)
    edges = table.speed_edges.tolist()
    mids = [(lo + hi) / 2 for lo, hi in zip([0.0] + edges, edges + [1.4 * edges[-1]], strict=True)]
    low = [b * HEADINGS + k for b, s in enumerate(mids) if s <= 6.0 for k in range(HEADINGS)]
    mass = wide.log_accel_table[low].double().exp().sum((1, 2)) * wide.bin**2
    assert torch.allclose(mass, torch.ones(len(low), dtype=torch.float64), atol=1e-3)
    # the speed-pooled copy mixes the fast bands heading bin by heading bin, by their samples
    pooled = table.speed_pooled(6.0)
    counts = table.band_count.double().numpy().reshape(-1, HEADINGS)
    lower = np.concatenate([[0.0], table.speed_edges.numpy()])
    fast_bands = np.flatnonzero(lower >= 6.0)
    for k in range(HEADINGS):
        w = counts[fast_bands, k]
        if w.sum() == 0:
            continue
        dens = table.log_accel_table[fast_bands * HEADINGS + k].double().exp()
        expected = (dens * torch.from_numpy(w / w.sum())[:, None, None]).sum(0)
        for b in fast_bands:
            assert torch.allclose(
                pooled.log_accel_table[b * HEADINGS + k].double().exp(), expected, rtol=1e-4, atol=1e-12
            )
    slow = [b * HEADINGS + k for b in np.flatnonzero(lower < 6.0) for k in range(HEADINGS)]
    assert torch.equal(pooled.log_accel_table[slow], table.log_accel_table[slow])
