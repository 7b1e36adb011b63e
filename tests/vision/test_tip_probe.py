"""The vision probe (evaluate, check, goto, the closed loop) with a tool's tip as the target."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.sim import platform
from microcal.vision.probe import VisionProbe


@pytest.mark.slow
def test_the_probe_measures_a_needles_tip_on_the_thesis_cameras() -> None:
    plat = platform("thesis-tip", seed=3, overrides={"board": "tip:needle:20:5"})
    m = plat.manipulator
    probe = VisionProbe(plat.cameras, plat.camera_models, plat.scene.board, frames=2)
    for d in ([2500.0, 3000.0, 1500.0], [6000.0, 5500.0, 3500.0]):
        m.move_to_um(np.array(d))
        m.wait_until_stopped(plat.clock, timeout_s=60)
        plat.clock.sleep(5.0)
        p, cov = probe.measure_with_covariance(np.array(d), 2)
        error = p - m.true_position_um()
        # 22 µm pixels: a few µm, nearly all along the tool's axis (docs/vision.md)
        assert float(np.linalg.norm(error)) < 15.0, error
        across = error - (error @ plat.scene.tool.axis) * plat.scene.tool.axis  # type: ignore[union-attr]
        assert float(np.linalg.norm(across)) < 5.0, across
        assert np.all(np.isfinite(cov))
