"""Parts of a batch side by side (estimation._parts): in order, one torch thread each, nothing leaks."""

from __future__ import annotations

import threading

import pytest
import torch

from estimation._parts import map_parts
from mmwsim import _threads


@pytest.fixture
def two_threads():
    before = torch.get_num_threads()
    _threads.set_threads(2)
    torch.set_num_threads(2)
    yield
    _threads.set_threads(None)
    torch.set_num_threads(before)


def test_parts_come_back_in_order_each_on_one_torch_thread_with_the_callers_grad_mode(two_threads):
    seen = []

    def fn(x):
        inner = map_parts(lambda y: (y, threading.current_thread().name), [0, 1])  # runs in turn, here
        seen.append(
            (torch.get_num_threads(), torch.is_grad_enabled(), inner, threading.current_thread().name)
        )
        return x * x

    with torch.no_grad():
        assert map_parts(fn, list(range(6))) == [x * x for x in range(6)]
    assert torch.get_num_threads() == 2  # restored
    assert len(seen) == 6
    for count, grad, inner, name in seen:
        assert count == 1 and grad is False
        assert name.startswith("mmwsim-thread") and [n for _, n in inner] == [name, name]
    assert map_parts(lambda x: torch.is_grad_enabled(), [0, 1]) == [True, True]


def test_a_failing_part_raises_and_restores_the_torch_threads(two_threads):
    def fn(x):
        if x == 3:
            raise ValueError("part 3")
        return x

    with pytest.raises(ValueError, match="part 3"):
        map_parts(fn, list(range(5)))
    assert torch.get_num_threads() == 2


def test_one_thread_or_one_part_runs_in_the_callers_thread(two_threads):
    here = threading.current_thread().name
    assert map_parts(lambda x: threading.current_thread().name, [0]) == [here]
    _threads.set_threads(1)
    assert map_parts(lambda x: threading.current_thread().name, [0, 1]) == [here, here]
