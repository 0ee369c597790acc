"""Stamps: the keys under which the estimator keeps what it made from its motion tables."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation._stamps import same_stamp, stamp
from estimation.smoothing.beam import motion_arrays
from estimation.smoothing.motion import MotionTable


def test_a_stamp_changes_when_a_tensor_changes_in_place_or_is_replaced():
    t, table = torch.zeros(3), MotionTable()
    lines = np.zeros((2, 2, 2))
    lines.flags.writeable = False
    key = stamp(t, table, lines, 1.5)
    assert same_stamp(key, stamp(t, table, lines, 1.5))
    t[0] += 1.0  # in place: the version counter moves
    assert not same_stamp(key, stamp(t, table, lines, 1.5))
    key = stamp(t, table, lines, 1.5)
    table.log_step_table[1] = 2.0  # a module's buffers are its key
    assert not same_stamp(key, stamp(t, table, lines, 1.5))
    key = stamp(t, table, lines, 1.5)
    table.log_step_table = table.log_step_table.clone()  # equal values, another tensor
    assert not same_stamp(key, stamp(t, table, lines, 1.5))
    key = stamp(t, table, lines, 1.5)
    other = lines.copy()
    other.flags.writeable = False
    assert not same_stamp(key, stamp(t, table, other, 1.5))  # arrays by identity
    assert not same_stamp(key, stamp(t, table, lines, 2.0))  # values by value
    assert not same_stamp(key, stamp(t, table, lines)) and not same_stamp(None, key)
    with pytest.raises(ValueError, match="read-only"):
        stamp(np.zeros(2))  # numpy keeps no version: a writable array could change unseen


def test_the_kernels_arrays_are_remade_when_their_table_changes():
    table = MotionTable()
    m = motion_arrays(table)
    assert motion_arrays(table) is m
    assert m.accel_max == m.accel_table.max() and m.accel_min == m.accel_table.min()
    table.log_accel_table[0, 0, 0] = 5.0
    again = motion_arrays(table)
    assert again is not m and again.accel_max == 5.0
