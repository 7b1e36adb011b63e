"""Calibration from known displacements (method (a)): steps that fit no camera are a clear
error, and the right steps calibrate."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.vision.targets import parse_target


@pytest.mark.slow
@pytest.mark.parametrize("mistake", ["steps in mm", "steps out of order"])
def test_known_displacements_that_fit_no_camera_are_a_clear_error(mistake):
    from microcal.errors import DegenerateDataError, InputError
    from microcal.thesis.cameras import thesis_cameras
    from microcal.vision.detect import Detection
    from microcal.vision.stereo_calibration import calibrate_known_displacements

    cams = dict(zip(("top", "side"), thesis_cameras(), strict=True))
    target = parse_target("dotgrid:20x15:250")
    steps = np.array([[0.0, 0.0, z] for z in (0.0, 1000.0, 2000.0, 3000.0, 4000.0)])
    rng = np.random.default_rng(5)
    dets = {
        n: [Detection(True, np.arange(300), c.project(target.points_um() + [2000, 2000, 0] + s)
                      + rng.normal(0, 0.05, (300, 2)), 0.05) for s in steps]
        for n, c in cams.items()
    }  # fmt: skip
    names = {n: [f"{n}{k}" for k in range(5)] for n in cams}
    sizes = {n: c.image_size_px for n, c in cams.items()}
    if mistake == "steps in mm":
        given, error = steps / 1000.0, (DegenerateDataError, r"do not fit one camera .*steps in µm")
    else:  # the views fit the steps in another order: named as such
        given, error = steps[[3, 0, 4, 1, 2]], (InputError, r"views out of order: top.*--known-d")
    with pytest.raises(error[0], match=error[1]):
        calibrate_known_displacements(dets, names, target, given, sizes)
    # The same detections with the right steps calibrate (metric: RMS reprojection, px).
    cal = calibrate_known_displacements(dets, names, target, steps, sizes)
    assert all(c.rms_px < 0.1 for c in cal.cameras.values())
