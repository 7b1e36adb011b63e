"""The settle loop's searches in a forked process: the corners of searching each frame here."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from microcal import sim
from microcal._parallel import can_fork
from microcal.procedures.acquisition import _FrameSearch
from microcal.procedures.settle_search import ForkedSearcher

pytestmark = pytest.mark.skipif(not can_fork(), reason="this system does not fork safely")


def _frames(n: int) -> tuple[sim.SimPlatform, list]:
    plat = sim.platform("thesis", seed=7)
    m = plat.manipulator
    m.move_to_um(np.array([3000.0, 2000.0, 1000.0]))
    m.wait_until_stopped(plat.clock)
    return plat, [plat.cameras["top"].grab_lazy() for _ in range(n)]


def _in_turn(target, roi, frames) -> list:
    search = _FrameSearch(target, (roi, None))
    return [search.corners(f) for f in frames]


@pytest.mark.parametrize("grow_px", [0, -60])  # the predicted region right, or far too small
def test_forked_searches_find_the_corners_found_here(grow_px):
    plat, frames = _frames(4)
    target = plat.scene.board
    first = _FrameSearch(target).corners(frames[0])  # where the board is
    assert first is not None
    lo, hi = first.min(axis=0), first.max(axis=0)
    roi = (int(lo[0]) - 40 - grow_px, int(lo[1]) - 40 - grow_px,
           int(hi[0]) + 40 + grow_px, int(hi[1]) + 40 + grow_px)  # fmt: skip
    searcher = ForkedSearcher(functools.partial(_FrameSearch, target))
    try:
        pose = searcher.pose(roi, frames[0].shape)
        numbers = [pose.submit(f) for f in frames]
        got = [pose.corners(k) for k in numbers]
        # a region far too small: the search reads the whole frame, here, from the first frame
        assert searcher.searched_here == (4 if grow_px < 0 else 0)
    finally:
        searcher.close()
    want = _in_turn(target, roi, frames)
    for a, b in zip(got, want, strict=True):
        if b is None:
            assert a is None
        else:
            np.testing.assert_array_equal(a, b)
