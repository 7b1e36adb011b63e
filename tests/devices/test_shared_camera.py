"""A camera shared by two threads: grabs take turns, the latest frame is kept with its age."""

from __future__ import annotations

import threading
import time

import numpy as np

from microcal import sim
from microcal.devices.shared_camera import SharedCamera


def test_grabs_from_two_threads_take_turns_and_the_latest_is_kept():
    plat = sim.platform("thesis", seed=0)
    inner = plat.cameras["top"]
    shared = SharedCamera(inner)
    assert (shared.name, shared.sensor_size_px, shared.bit_depth) == (
        inner.name, inner.sensor_size_px, inner.bit_depth)  # fmt: skip
    assert shared.latest(10.0) is None
    inside = []
    grab = inner._grab

    def counting_grab():
        inside.append(1)
        assert len(inside) == 1, "two grabs at once"
        try:
            time.sleep(0.002)
            return grab()
        finally:
            inside.pop()

    inner._grab = counting_grab  # type: ignore[method-assign]
    frames = []
    threads = [threading.Thread(target=lambda: frames.append(shared.grab())) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert len(frames) == 6
    assert not shared.busy()
    latest = shared.latest(10.0)
    assert latest is not None
    assert latest.shape == frames[0].shape
    assert any(np.array_equal(latest, f) for f in frames)
    time.sleep(0.02)
    assert shared.latest(0.01) is None  # too old
    shared.close()
    assert inner.closed
