"""The patch twin's sample switch: the calibration slide on its stage, seen by its camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.patch import patch_rig
from microcal.sim.patch_twin import PatchTwinCamera
from microcal.sim.twin import Twin


def _shift_px(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """How far the content of ``b`` lies from that of ``a``, (dx, dy) px."""
    (dx, dy), _ = cv2.phaseCorrelate(a.astype(np.float64), b.astype(np.float64))
    return np.array([dx, dy])


def test_the_slide_moves_with_the_stage_and_blurs_with_the_focus() -> None:
    rig = patch_rig(2, size_px=(384, 384))
    camera = PatchTwinCamera(rig, "slide")
    t0 = rig.clock.now_s()
    first = camera.grab()
    assert first.dtype == np.uint16
    assert rig.clock.now_s() - t0 == pytest.approx(0.03)  # the exposure and readout
    assert int(first.max()) - int(first.min()) > 2000  # dots on glass, in 12-bit counts
    rig.stage.move_to_um([8.0, 0.0, 0.0])
    rig.stage.wait_until_stopped(rig.clock)
    moved = camera.grab()
    # the stage's +x moves the slide to the image's -x (the camera's truth: x right, y down)
    shift = _shift_px(first, moved)
    assert abs(abs(shift[0]) - 8.0 / rig.config.um_per_px) < 0.5
    assert abs(shift[1]) < 0.5
    rig.move_focus(6.0)
    blurred = camera.grab()
    assert float(np.std(blurred)) < 0.8 * float(np.std(moved))


def test_the_tissue_is_there_by_default_and_the_sample_can_be_changed() -> None:
    rig = patch_rig(2, size_px=(256, 256))
    camera = PatchTwinCamera(rig)
    assert camera.sample == "tissue"
    tissue = camera.grab_lazy()
    assert tissue.region(0, 0, 4, 4).shape == (4, 4)
    camera.sample = "slide"
    assert camera.grab_lazy().shape == (256, 256)


def test_a_sample_that_is_not_there_is_refused_in_one_line() -> None:
    with pytest.raises(InputError, match="tissue or slide"):
        Twin(preset="patch", sample="glass", mcs2_port=0, frames_port=0)
    with pytest.raises(InputError, match="only the patch preset"):
        Twin(preset="thesis", sample="slide", mcs2_port=0, frames_port=0)
    twin = Twin(preset="patch", sample="slide", mcs2_port=0, frames_port=0, time_scale=1e4)
    assert twin.sample == "slide"
    assert "dotgrid:" in twin.describe()
    with pytest.raises(InputError, match="tissue or slide"):
        twin.sample = "agar"
    twin.sample = "tissue"
    assert twin.sample == "tissue"


@pytest.mark.slow
def test_scope_calibrate_through_the_twin_matches_the_in_process_slide(tmp_path) -> None:
    """``microcal scope-calibrate --rig patch-twin.toml`` on the twin's slide: the pixel size
    within 0.1 %, the rotation and the focus axis's angle within 0.05 degrees of the
    in-process calibration of the same seed (and of the truth)."""
    pytest.importorskip("pymmcore_plus")
    from microcal.sim.patch import PatchConfig
    from microcal.workflows.scope import ScopeRequest, scope_calibrate
    from support.twin_served import skip_without_namespace, twin_on_loopback

    skip_without_namespace()
    sim = tmp_path / "patch.toml"
    sim.write_text('driver = "sim"\npreset = "patch"\nseed = 0\n')
    here = scope_calibrate(ScopeRequest(rig=str(sim), objective="40x", out=tmp_path / "a.json"))
    rig = tmp_path / "patch-twin.toml"
    with twin_on_loopback(rig, preset="patch", seed=0, sample="slide", time_scale=50) as twin:
        spec = twin.frames.camera.slide.target.spec
        there = scope_calibrate(ScopeRequest(rig=str(rig), objective="40x",
                                             out=tmp_path / "b.json", target=spec,
                                             numerical_aperture=0.8))  # fmt: skip
    truth = PatchConfig()
    for got in (here.record, there.record):
        assert abs(float(got["pixel_size_um"]) / truth.um_per_px - 1) < 1e-3
        assert abs(abs(float(got["rotation_deg"])) - 180.0) < 0.05
        assert abs(float(got["focus"]["angle_deg"]) - truth.focus.tilt_deg) < 0.05  # type: ignore[index]
    a, b = here.record, there.record
    assert abs(float(a["pixel_size_um"]) / float(b["pixel_size_um"]) - 1) < 1e-3
    assert abs(abs(float(a["rotation_deg"])) - abs(float(b["rotation_deg"]))) < 0.05
    fa, fb = a["focus"]["angle_deg"], b["focus"]["angle_deg"]  # type: ignore[index]
    assert abs(float(fa) - float(fb)) < 0.05
