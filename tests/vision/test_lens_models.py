"""Lens models by name, and a fixed one used as asked."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.calibration_views import (
    render_calibration_views,
    wide_angle_camera,
)
from microcal.vision.lens_models import LENS_MODELS, choose_lens_model, fit_camera, lens_model
from microcal.vision.targets import parse_target

TARGET = "chessboard:7x4:25000"
NAMES = [m.name for m in LENS_MODELS]


@pytest.mark.parametrize("name", ["nope", "", "auto", "Radial1", "radial1 ", "radial4"])
def test_lens_model_unknown_name_raises_input_error(name):
    with pytest.raises(InputError) as info:
        lens_model(name)
    message = str(info.value)
    assert repr(name) in message
    for known in NAMES:
        assert known in message


def test_lens_model_finds_each_model_by_name():
    assert NAMES == ["radial1", "radial2", "radial2-tangential", "radial3-tangential",
                     "rational", "thin-prism", "tilted"]  # fmt: skip
    for model in LENS_MODELS:
        assert lens_model(model.name) is model


@pytest.fixture(scope="module")
def mono_views():
    views = render_calibration_views(wide_angle_camera(), parse_target(TARGET), 6, seed=1)
    obj = [views.target.points_um()] * views.n_views
    return obj, views.corners_px, views.camera.image_size_px


@pytest.mark.parametrize("name", ["radial2", "radial3-tangential", "rational"])
def test_choose_lens_model_with_one_model_uses_it_as_asked(mono_views, name):
    obj, img, size = mono_views
    model = lens_model(name)
    choice = choose_lens_model(obj, img, size, models=(model,))
    assert choice.fit.model is model
    assert choice.reason == f"lens model {name} as asked"
    assert choice.candidates == []
    assert choice.fit.dist.shape == (model.n_coefficients,)
    # The same fit as fitting that model directly (OpenCV's threads make the two calls differ
    # in the last digits): K within 1e-6 px, the distortion coefficients within 1e-5
    # (absolute), the RMS reprojection error within 1e-9 px.
    direct = fit_camera(obj, img, size, model)
    np.testing.assert_allclose(choice.fit.K, direct.K, rtol=0, atol=1e-6)
    np.testing.assert_allclose(choice.fit.dist, direct.dist, rtol=0, atol=1e-5)
    assert choice.fit.rms_px == pytest.approx(direct.rms_px, abs=1e-9)
    # Field of view of the fitted pinhole: within 1 deg of the true camera's (about 75 deg
    # diagonal for fx = 525 px on 640 x 480).
    true_fov = np.degrees(2 * np.arctan(np.hypot(320 / 525.0, 240 / 527.0)))
    assert choice.field_of_view_deg == pytest.approx(true_fov, abs=1.0)


def test_radial2_fixes_the_terms_it_leaves_out(mono_views):
    obj, img, size = mono_views
    choice = choose_lens_model(obj, img, size, models=(lens_model("radial2"),))
    k1, k2, p1, p2, k3 = choice.fit.dist
    assert (p1, p2, k3) == (0.0, 0.0, 0.0)  # fixed by the flags: exactly zero
    assert k1 != 0.0
    assert k2 != 0.0


def test_a_refused_guessed_start_is_fitted_from_opencvs_own(mono_views, monkeypatch):
    """Where OpenCV refuses a richer model's fit started from the simpler one's intrinsics
    (as on nearly frontal views: "principal point must be within the image"), the ladder
    fits that model from OpenCV's own start instead of stopping below it."""
    from microcal.errors import DegenerateDataError
    from microcal.vision import lens_models

    obj, img, size = mono_views
    models = tuple(lens_model(n) for n in ("radial1", "radial2", "radial2-tangential"))
    plain = lens_models.fit_camera

    def refusing(*args, guess=None, **kwargs):
        if guess is not None:
            raise DegenerateDataError("OpenCV refused the guessed start")
        return plain(*args, **kwargs)

    expected = choose_lens_model(obj, img, size, models=models)
    monkeypatch.setattr(lens_models, "fit_camera", refusing)
    choice = choose_lens_model(obj, img, size, models=models)
    # every model of the ladder was fitted and judged, as without the refusals
    assert [c["name"] for c in choice.candidates] == [m.name for m in models]
    assert all(c["held_out_rms_px"] is not None for c in choice.candidates)
    assert "ladder stopped" not in choice.reason
    assert choice.fit.model.name == expected.fit.model.name
