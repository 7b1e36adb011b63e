"""Field curvature from a focus sweep: each region's sharpest focus, and the focal surface's
sag at the corner fitted to them."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.stage_slide import ScopeTruth, StageSlideScope
from microcal.vision.focal_surface import fit_field_curvature, region_sharpness


@pytest.mark.parametrize("sag_um", [0.8, -0.5])
def test_the_focal_surface_s_sag_is_recovered(sag_um):
    truth = ScopeTruth(um_per_px=0.1625, numerical_aperture=0.8, field_curvature_um=sag_um,
                       rotation_deg=1.0)  # fmt: skip
    scope = StageSlideScope(truth, image_size_px=(192, 192), seed=1)
    zs = np.linspace(-2.5, 2.5, 15)
    sharp = []
    for z in zs:
        scope.move_focus(z)
        sharp.append(region_sharpness(scope.grab()))
    curv = fit_field_curvature(zs, np.array(sharp))
    assert abs(curv.corner_um - sag_um) < 0.1
    assert abs(curv.corner_um - sag_um) < 4 * curv.corner_sd_um + 0.02
    assert abs(curv.centre_um) < 0.1  # the centre is in focus at 0
    assert np.all(np.abs(curv.tilt_um) < 0.1)  # the slide lies flat
    assert np.isfinite(curv.peaks_um).all()


def test_a_sweep_that_brackets_no_peak_is_one_line():
    zs = np.linspace(0.0, 1.0, 6)
    rising = np.broadcast_to(zs[:, None, None] + 1.0, (6, 5, 5))  # sharpest at the last step
    with pytest.raises(InputError, match=r"^field curvature: the sweep brackets the sharpest "
                                         r"focus of 0 of 25 regions; it needs 5"):  # fmt: skip
        fit_field_curvature(zs, rising)
