"""Method (a)'s choice of camera model on rendered views of the telecentric and thesis presets.

The 10-seed figures come from ``scripts/camera_model_choice.py --seeds 10`` (docs/vision.md);
these tests run fewer seeds and frames so the suite stays short.
"""

from __future__ import annotations

import numpy as np
import pytest

from microcal import DegenerateDataError
from microcal.experiments.camera_model_trial import camera_model_trial
from microcal.experiments.demo import target_views
from microcal.procedures.rig_stereo import CALIBRATION_STEPS_UM
from microcal.sim import platform
from microcal.sim.platforms import CALIBRATION_TARGET
from microcal.vision.known_displacements import calibrate_known_displacements
from microcal.vision.targets import parse_target


@pytest.mark.slow
@pytest.mark.parametrize(
    ("preset", "kind", "seed"), [("telecentric", "affine", 101), ("thesis", "pinhole", 202)]
)
def test_auto_picks_the_model_of_the_lens(preset, kind, seed):
    trial = camera_model_trial(preset, seed, frames_per_view=3, poses=0)
    assert set(trial.chosen.values()) == {kind}
    cal = trial.calibration
    assert cal is not None
    for c in cal.cameras.values():
        names = [d["model"] for d in c.model_choice["candidates"]]
        assert names == ["pinhole", "affine"]
        assert c.model_choice["chosen"] == kind
    if preset == "telecentric":
        # The pinhole fit is reported as ill-conditioned, with its reason.
        assert all("ill-conditioned" in p for p in trial.pinhole_problem.values())
    else:
        assert not any(trial.pinhole_problem.values())


@pytest.mark.slow
def test_telecentric_affine_fit_reaches_the_noise_floor_and_the_true_cameras():
    trial = camera_model_trial("telecentric", 303, frames_per_view=4, poses=12, frames=3)
    # Metric: reprojection RMS over the RMS of the detected dots' error against their true
    # projections (the rendered noise floor), per camera: within 10 %.
    for ratio in trial.floor_ratio.values():
        assert abs(ratio - 1.0) <= 0.10
    # Metric: 3D RMS error of 12 measured poses against the truth; the affine cameras within
    # 1.2x the true cameras, the ill-conditioned pinhole fits worse.
    assert trial.rms_3d_um["chosen"] <= 1.2 * trial.rms_3d_um["true"]
    assert trial.rms_3d_um["pinhole"] > trial.rms_3d_um["chosen"]


@pytest.fixture(scope="module")
def telecentric_views():
    plat = platform("telecentric", seed=404)
    steps = np.array([[0.0, 0.0, z] for z in CALIBRATION_STEPS_UM])
    views = target_views(plat, parse_target(CALIBRATION_TARGET), steps, 2)
    dets, names = views.detections, views.names
    sizes = {n: c.model.image_size_px for n, c in plat.cameras.items()}
    return dets, names, sizes, steps


@pytest.mark.slow
def test_pinhole_asked_for_on_telecentric_views_is_refused(telecentric_views):
    dets, names, sizes, steps = telecentric_views
    grid = parse_target(CALIBRATION_TARGET)
    with pytest.raises(DegenerateDataError, match=r"camera top: the views do not fit one "
                       r"camera \(.*ill-conditioned.*--camera-model affine"):  # fmt: skip
        calibrate_known_displacements(dets, names, grid, steps, sizes, camera_model="pinhole")
    cal = calibrate_known_displacements(dets, names, grid, steps, sizes, camera_model="affine")
    assert [c.model.kind for c in cal.cameras.values()] == ["affine", "affine"]
    assert all(not c.model_choice for c in cal.cameras.values())  # no choice was made
    assert all(0 < c.model.projection_sigma_px < 0.05 for c in cal.cameras.values())
    assert np.isnan(cal.baseline_um)  # parallel projections have no centre
