"""Frames painted in another process (sim.paint_process): the same pixels and draws as at
the grab, read in any order and from any thread, and a process that ends with its user."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from microcal import sim
from microcal._parallel import can_fork
from microcal.sim.camera import paint_here
from microcal.sim.paint_process import MAX_AHEAD, PaintProcess, painting_elsewhere

pytestmark = pytest.mark.skipif(not can_fork(), reason="painting elsewhere needs fork (Linux)")


def _moved(preset: str, seed: int) -> sim.SimPlatform:
    plat = sim.platform(preset, seed=seed)
    plat.manipulator.move_to_um([4000, 4000, 2400])
    plat.manipulator.wait_until_stopped(plat.clock)
    return plat


@pytest.mark.parametrize("preset", ["thesis", "thesis-tip"])  # a board; a tool's tip
def test_frames_painted_elsewhere_are_the_frames_painted_at_the_grab(preset):
    here, there = _moved(preset, 4), _moved(preset, 4)
    n = 3 * MAX_AHEAD  # more frames in flight than the process takes ahead
    expected = [cam.grab_lazy().full() for _ in range(n) for cam in here.cameras.values()]
    with painting_elsewhere(there.cameras.values()) as process:
        assert process.forked
        frames = [cam.grab_lazy() for _ in range(n) for cam in there.cameras.values()]
        # read out of order, some of them from another thread
        with ThreadPoolExecutor(max_workers=1) as pool:
            late = pool.submit(lambda: [f.full() for f in frames[::2]]).result()
        early = [f.full() for f in frames[1::2]]
    got = [None] * len(frames)
    got[::2], got[1::2] = late, early
    for want, have in zip(expected, got, strict=True):
        np.testing.assert_array_equal(have, want)
    # and the cameras paint at the grab again, their random streams where the other's are
    assert all(cam.painter is paint_here for cam in there.cameras.values())
    for a, b in zip(here.cameras.values(), there.cameras.values(), strict=True):
        np.testing.assert_array_equal(a.grab(), b.grab())


def test_frames_grabbed_inside_stay_readable_after_the_process_ends():
    plat = _moved("thesis", 1)
    cam = plat.cameras["top"]
    with painting_elsewhere([cam]):
        frames = [cam.grab_lazy() for _ in range(3)]
    assert all(f.full().max() > 0 for f in frames)


def test_closing_ends_the_process_and_later_jobs_are_painted_here():
    process = PaintProcess()
    proc = process._proc
    process.close()
    assert not proc.is_alive()
    plat = _moved("thesis", 2)
    cam = plat.cameras["side"]
    cam.painter = process  # closed: paints at once, here
    assert cam.grab_lazy().full().max() > 0
