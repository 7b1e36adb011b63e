"""The one-camera probe: the tip in {M} where the calibration says to look, NaN where it is
not found."""

from __future__ import annotations

import numpy as np

from microcal.procedures.one_camera_acquisition import TipFinder
from microcal.procedures.one_camera_probe import OneCameraTipProbe
from microcal.sim.patch import patch_rig
from microcal.sim.patch_scope import end_offset_px, image_axis, true_frame, truth_in_frame


def test_the_probe_measures_the_tip_and_gives_nan_where_there_is_none() -> None:
    rig = patch_rig(7, size_px=(512, 512), supersample=1)
    cfg = rig.config
    finder = TipFinder(true_frame(cfg), image_axis(cfg), end_offset_px(cfg), frames=11)
    truth = truth_in_frame(rig, finder.frame)
    here = truth()
    probe = OneCameraTipProbe(finder, rig.move_focus, rig.grab, rig.clock,
                              lambda d: here + d + (0.3, -0.2, 0.4))  # fmt: skip
    p, cov = probe.measure_with_covariance(np.zeros(3), 5)
    assert np.linalg.norm(p - here) < 0.4  # µm (the tip point's offset included)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert probe.frames_used >= 11
    # nothing where it looks (30 µm off the tip, beside the pipette): NaN, the run goes on
    assert np.all(np.isnan(probe.measure(np.array([0.0, 30.0, 0.0]))))
