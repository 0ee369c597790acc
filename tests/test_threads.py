"""Parallel sections: ray queries and cell marking give the same answer on any number of threads."""

from __future__ import annotations

import os
import select
import signal
import sys
import threading

import numpy as np
import pytest

from mmwsim import _threads
from mmwsim.geometry import raycast
from mmwsim.geometry.raycast import RayCaster


@pytest.fixture
def restore_threads():
    yield
    _threads.set_threads(None)


def test_thread_map_keeps_order(restore_threads):
    _threads.set_threads(3)
    assert _threads.thread_map(lambda x: x * x, list(range(10))) == [x * x for x in range(10)]
    # within one of its threads a parallel section has one thread, and a nested map runs there
    inner = _threads.thread_map(
        lambda x: (
            _threads.threads(),
            _threads.thread_map(lambda y: threading.current_thread().name, [0, 1]),
        ),
        [0, 1, 2],
    )
    assert all(n == 1 and len(set(names)) == 1 and names[0].startswith("mmwsim-thread") for n, names in inner)
    assert _threads.threads() == 3
    _threads.set_threads(1)
    assert _threads.threads() == 1
    _threads.set_threads(None)
    assert _threads.threads() == _threads.cores() >= 1


def test_chunks_cover_every_ray_once(restore_threads, monkeypatch):
    monkeypatch.setattr(raycast, "_CHUNK", 1000)
    monkeypatch.setattr(raycast, "_MIN_SPLIT", 10)
    for threads in (1, 2, 5):
        _threads.set_threads(threads)
        for n in (1, 9, 10, 999, 1000, 1001, 4321):
            pieces = raycast._chunks(n)
            covered = np.concatenate([np.arange(n)[s] for s in pieces])
            assert np.array_equal(covered, np.arange(n))
            assert all(s.stop - s.start <= 1000 for s in pieces)
            assert len(pieces) >= min(threads, n // 10)


def test_ray_queries_same_on_any_number_of_threads(restore_threads, monkeypatch):
    # A unit box: rays from inside hit it exactly once, from outside some miss.
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    caster = RayCaster(box.vertices, box.faces)
    rng = np.random.default_rng(1)
    n = 5000
    o = rng.uniform(-2.0, 2.0, (n, 3))
    d = rng.normal(size=(n, 3))
    tmax = rng.uniform(0.1, 3.0, n)
    monkeypatch.setattr(raycast, "_CHUNK", 700)
    monkeypatch.setattr(raycast, "_MIN_SPLIT", 100)
    answers = []
    for threads in (1, 2, 4):
        _threads.set_threads(threads)
        t, face = caster.intersect(o, d)
        answers.append((t, face, caster.occluded(o, d, tmax), caster.intersect(o, d, tmax)[1]))
    for got in answers[1:]:
        for a, b in zip(answers[0], got, strict=True):
            assert np.array_equal(a, b)
    t, face, _, _ = answers[0]
    inside = np.all(np.abs(o) < 1.0, axis=1)
    assert np.all(face[inside] >= 0) and np.all(np.isfinite(t[inside]))
    assert np.any(face[~inside] < 0)


def test_fibonacci_pieces_equal_the_whole(restore_threads, monkeypatch):
    from mmwsim.tracer import shooting

    monkeypatch.setattr(shooting, "_MIN_SPLIT", 16)
    _threads.set_threads(1)
    whole = shooting._fib_slice(1000, 0, 1000)
    assert np.allclose(np.linalg.norm(whole, axis=1), 1.0)
    for threads in (2, 3):
        _threads.set_threads(threads)
        assert np.array_equal(shooting.fibonacci_directions(1000), whole)
        parts = [shooting._fib_slice(1000, s, 300) for s in range(0, 1000, 300)]
        assert np.array_equal(np.concatenate(parts), whole)


def test_shooting_same_legs_for_any_batch_and_threads(restore_threads, monkeypatch):
    # Batches and thread pieces change how sequences are numbered, never which rays go where.
    from mmwsim.scene import load_scene
    from mmwsim.tracer import shooting
    from mmwsim.tracer.tracer import Tracer

    scene = load_scene("manhattan:seed=2")
    tracer = Tracer(scene, scene.transmitter.array, 2, 2000, diffraction=False)
    monkeypatch.setattr(shooting, "_MIN_SPLIT", 64)
    runs = []
    for threads, batch in ((1, 1 << 22), (2, 700), (3, 333)):
        _threads.set_threads(threads)
        shot = shooting.shoot(tracer.caster, tracer.reflectors, scene.transmitter.array, 2, 2000, batch=batch)
        runs.append(shot)
    first = runs[0]
    for shot in runs[1:]:
        for a, b in zip(first.sample, shot.sample, strict=True):
            assert np.array_equal(a, b)
        for k in (1, 2):
            la, lb = first.legs[k], shot.legs[k]
            assert np.array_equal(la.start, lb.start) and np.array_equal(la.length, lb.length)
            assert np.array_equal(first.sequences[k][la.seq], shot.sequences[k][lb.seq])


def test_results_come_back_in_order_on_threads_kept_between_calls(restore_threads):
    _threads.set_threads(2)
    names = set()

    def square(x: int) -> int:
        names.add(threading.current_thread().name)
        return x * x

    for _ in range(3):
        assert _threads.thread_map(square, list(range(50))) == [x * x for x in range(50)]
    assert names and all(n.startswith(_threads._PREFIX) for n in names)
    assert len(names) <= 2


def test_a_nested_call_runs_in_its_thread_instead_of_waiting_on_the_pool(restore_threads):
    _threads.set_threads(2)

    def inner(x: int) -> list[int]:
        return _threads.thread_map(lambda y: x + y, [0, 1, 2])

    got = []
    # on a daemon thread: calls waiting on each other would never return
    outer = threading.Thread(
        target=lambda: got.append(_threads.thread_map(inner, [10, 20, 30, 40])), daemon=True
    )
    outer.start()
    outer.join(30.0)
    assert got == [[[x, x + 1, x + 2] for x in (10, 20, 30, 40)]], "nested thread_map calls deadlocked"


@pytest.mark.skipif(not hasattr(os, "fork") or sys.platform == "darwin", reason="fork")
def test_a_forked_child_starts_its_own_threads(restore_threads):
    _threads.set_threads(2)
    assert _threads.thread_map(abs, [-1, -2]) == [1, 2]  # the parent's pool exists
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: its parent's threads are gone, a new pool must serve it
        try:
            ok = _threads.thread_map(abs, [-3, -4, -5]) == [3, 4, 5]
            os.write(w, b"1" if ok else b"0")
        finally:
            os._exit(0)
    os.close(w)
    # a child waiting on threads it does not have would never answer
    ready, _, _ = select.select([r], [], [], 30.0)
    got = os.read(r, 1) if ready else b""
    if not ready:
        os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    assert got == b"1", "the forked child's thread_map hung"


def test_batch_map_joins_the_slices_of_any_number_of_threads(restore_threads):
    def kernel(a, b, scale):
        return a * scale, b.sum(1)

    a, b = np.arange(100.0), np.arange(300.0).reshape(100, 3)
    for threads in (1, 2, 3):
        _threads.set_threads(threads)
        got = _threads.batch_map(kernel, 2, a, b, 2.0)
        assert np.array_equal(got[0], 2.0 * a) and np.array_equal(got[1], b.sum(1))
        assert np.array_equal(_threads.batch_map(lambda a, s: a + s, 1, a, 1.0), a + 1.0)
