"""The one-camera ``patch`` rig opened from a rig file as a generic Rig."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.devices.microscope_drive import MicroscopeDrive
from microcal.errors import FormatError
from microcal.formats.rig_file import load_rig
from microcal.sim.patch import patch_rig
from microcal.vision.tip_target import TipTarget
from microcal.workflows.rigs import open_rig


def _rig_file(tmp_path, body: str = "[overrides]\nsize_px = [128, 128]\nsupersample = 1\n"):
    path = tmp_path / "patch.toml"
    path.write_text(f'driver = "sim"\npreset = "patch"\nseed = 3\n{body}')
    return str(path)


def test_a_patch_rig_file_opens_one_camera_a_microscope_and_the_pipette(tmp_path):
    with open_rig(load_rig(_rig_file(tmp_path))) as rig:
        assert list(rig.cameras) == ["scope"]
        assert rig.microscope is not None
        assert rig.microscope.axes == ("x", "y", "z")
        assert list(rig.manipulators) == ["m1"]
        assert rig.selected == "m1"
        assert isinstance(rig.board, TipTarget)
        assert rig.board.kind == "pipette"
        assert rig.truth is not None
        assert rig.truths["m1"] is rig.truth
        frame = rig.cameras["scope"].grab()
        assert frame.shape == (128, 128)
        assert frame.dtype == np.uint16
        assert "preset patch, seed 3" in rig.description["platform"]
    assert rig.closed
    assert rig.cameras["scope"].closed
    assert rig.microscope.closed


def test_the_drive_moves_stage_and_focus_and_reads_back_its_commands(tmp_path):
    with open_rig(load_rig(_rig_file(tmp_path))) as rig:
        assert rig.microscope is not None
        drive = MicroscopeDrive(rig.microscope, rig.cameras["scope"], rig.clock)
        t0 = rig.clock.now_s()
        drive.move_focus(-3.0)
        drive.move_stage([25.0, -10.0])
        np.testing.assert_array_equal(rig.microscope.position_um(), [25.0, -10.0, -3.0])
        assert rig.clock.now_s() > t0  # the moves took the rig's time
        frame = drive.grab_at_focus(1.5)
        assert frame.shape == (128, 128)
        assert drive.focus_um == 1.5


def test_the_rig_frames_are_the_patch_rigs_own(tmp_path):
    """The camera of the opened rig gives the frame the PatchRig of that seed gives."""
    with open_rig(load_rig(_rig_file(tmp_path))) as rig:
        got = rig.cameras["scope"].grab()
    want = patch_rig(3, size_px=(128, 128), supersample=1).grab().full()
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ("[overrides]\nsize_pix = [64, 64]\n", "override 'size_pix': preset 'patch' has no such"),
        ("[overrides]\napproach_deg = 120\n", "approach_deg"),
        ("[overrides.focus]\nscale = 0.1\n", "override 'focus.scale'"),
    ],
)
def test_bad_patch_overrides_are_refused_in_one_line(tmp_path, body, says):
    with pytest.raises(FormatError, match=says) as err:
        load_rig(_rig_file(tmp_path, body))
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_scope_calibrate_on_the_patch_rig_recovers_its_pixel_and_focus_tilt(tmp_path):
    from microcal.sim.patch import PatchConfig
    from microcal.sim.patch_scope import true_frame
    from microcal.workflows.scope import ScopeRequest, scope_calibrate

    got = scope_calibrate(ScopeRequest(_rig_file(tmp_path), "40x", tmp_path / "scope.json",
                                       image_px=384)).calibration  # fmt: skip
    cfg = PatchConfig()
    assert got.pixel_size_um == pytest.approx(cfg.um_per_px, rel=1e-3)  # 0.1 %
    truth = -np.linalg.inv(true_frame(cfg).px_per_um)  # the image's y against the stage's
    np.testing.assert_allclose(got.affine_um[:, :2], truth, atol=1e-3 * cfg.um_per_px)
    assert got.focus_angle_deg == pytest.approx(cfg.focus.tilt_deg, abs=0.02)
