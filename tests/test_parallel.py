"""fork_map: results in order, progress from the workers, failures raised here at once."""

from __future__ import annotations

import os
import signal
import time
from multiprocessing import get_context

import pytest

from microcal._parallel import can_fork, fork_map
from microcal.errors import InputError

needs_fork = pytest.mark.skipif(not can_fork(), reason="this system does not fork safely")


def _square(x: int, tick) -> tuple[int, int]:
    for _ in range(x):
        tick()
    return x * x, os.getpid()


@needs_fork
def test_results_in_order_from_other_processes_with_every_tick():
    ticks = []
    got = fork_map(_square, [3, 1, 4, 2], 2, lambda: ticks.append(1))
    assert [v for v, _ in got] == [9, 1, 16, 4]
    assert {pid for _, pid in got}.isdisjoint({os.getpid()})
    assert len(ticks) == 10


def test_one_worker_runs_here_in_order():
    seen = []
    got = fork_map(lambda x, tick: seen.append(x) or x, [2, 1], 1)
    assert got == [2, 1]
    assert seen == [2, 1]  # the closure ran in this process


class _OddError(Exception):
    def __init__(self, *, why: str) -> None:  # cannot be rebuilt from its args
        super().__init__(why)


def _fails(x: int, tick):
    if x == 1:
        raise InputError("camera b: no image")
    if x == 2:
        raise _OddError(why="odd")
    time.sleep(30)  # the others are ended when one fails
    return x


@needs_fork
def test_a_worker_error_is_raised_here_and_ends_the_others():
    start = time.monotonic()
    with pytest.raises(InputError, match="camera b: no image"):
        fork_map(_fails, [0, 1], 2)
    with pytest.raises(RuntimeError, match="_OddError: odd"):
        fork_map(_fails, [2, 0], 2)
    assert time.monotonic() - start < 10


def _dies(x: int, tick):
    if x:
        os.kill(os.getpid(), signal.SIGKILL)
    return x


@needs_fork
def test_a_killed_worker_is_named_not_waited_for():
    with pytest.raises(RuntimeError, match="ended without a result"):
        fork_map(_dies, [0, 1], 2)


def _nested(n: int) -> list[int]:
    return fork_map(lambda x, tick: x + n, [1, 2], 2)


@needs_fork
def test_inside_a_daemonic_worker_it_runs_in_order():
    with get_context("fork").Pool(1) as pool:
        assert pool.map(_nested, [10]) == [[11, 12]]


def test_a_tick_passes_its_arguments():
    def work(item: int, tick) -> int:
        tick(f"item {item}", 1, 2)
        tick()
        return item

    got: list[tuple] = []
    assert fork_map(work, [1, 2], 2, lambda *args: got.append(args)) == [1, 2]
    assert sorted(got) == [(), (), ("item 1", 1, 2), ("item 2", 1, 2)]
