"""What the one-camera acquisition takes from the user's angles and the scope file: the same
axes, image direction and tip offset the simulator's ``patch`` rig is built with."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.procedures.one_camera_setup import nominal_axes_um, tool_finder
from microcal.sim.patch import PatchConfig
from microcal.sim.patch_scope import end_offset_px, image_axis, nominal_axes, true_frame
from microcal.vision.microscope_frame import MicroscopeFrame


@pytest.mark.parametrize(("approach", "azimuth"), [(30.0, 0.0), (25.0, 40.0), (35.0, -120.0)])
def test_the_angles_give_the_rigs_nominal_axes_image_direction_and_tip_offset(approach, azimuth):
    cfg = PatchConfig(approach_deg=approach, approach_azimuth_deg=azimuth)
    np.testing.assert_allclose(nominal_axes_um(approach, azimuth), nominal_axes(cfg), atol=1e-12)
    finder = tool_finder(true_frame(cfg), approach, azimuth, cfg.tool.tip_um / 2)
    np.testing.assert_allclose(finder.axis_px, image_axis(cfg), atol=1e-9)
    assert finder.end_offset_px == pytest.approx(end_offset_px(cfg), rel=1e-9)


def test_a_scope_files_set_gives_the_frame_of_its_calibration():
    truth = true_frame(PatchConfig())
    affine = np.column_stack([-np.linalg.inv(truth.px_per_um), [1.5, -2.0]])
    record = {"pixel_size_affine": affine.ravel().tolist(),
              "focus": {"drift_px_per_um": truth.drift_px_per_um.tolist()}}  # fmt: skip
    frame = MicroscopeFrame.from_record(record, (2048, 2048))
    np.testing.assert_allclose(frame.px_per_um, truth.px_per_um, rtol=1e-12)
    np.testing.assert_array_equal(frame.drift_px_per_um, truth.drift_px_per_um)
    np.testing.assert_array_equal(frame.centre_px, truth.centre_px)
    with pytest.raises(InputError, match="expected pixel_size_affine"):
        MicroscopeFrame.from_record({"pixel_size_affine": [1.0]}, (64, 64))


def test_angles_out_of_range_are_one_line():
    with pytest.raises(InputError, match="approach_deg"):
        nominal_axes_um(95.0)
