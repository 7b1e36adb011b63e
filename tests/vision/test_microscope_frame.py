"""The microscope's frame {M}: image and focus to µm and back, from a scope calibration's
numbers, against the simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.sim.stage_slide import ScopeTruth
from microcal.vision.microscope_frame import MicroscopeFrame


def _frame(truth: ScopeTruth) -> MicroscopeFrame:
    return MicroscopeFrame(truth.pixels_per_stage(), truth.drift_px_per_um(),
                           np.array([1023.5, 1023.5]))  # fmt: skip


def test_a_point_goes_to_the_image_and_back() -> None:
    truth = ScopeTruth(um_per_px=0.1625, rotation_deg=2.0, stage_skew_deg=0.1,
                       focus_tilt_deg=0.5, focus_azimuth_deg=40.0)  # fmt: skip
    frame = _frame(truth)
    p = np.random.default_rng(1).uniform(-150, 150, (20, 3))
    q, f = frame.to_image(p)
    assert np.allclose(frame.to_um(q, f), p, atol=1e-9)
    assert np.allclose(f, p[:, 2])
    one_q, one_f = frame.to_image(p[0])
    assert np.allclose(frame.to_um(one_q, one_f[0]), p[0], atol=1e-9)
    assert frame.um_per_px == pytest.approx(0.1625 / np.sqrt(np.cos(np.radians(0.1))), rel=1e-9)


def test_the_field_centre_at_focus_zero_is_the_origin_and_the_focus_drift_is_taken_out() -> None:
    truth = ScopeTruth(um_per_px=0.1625, focus_tilt_deg=1.0, focus_azimuth_deg=0.0)
    frame = _frame(truth)
    assert np.allclose(frame.to_um(frame.centre_px, 0.0), 0.0)
    # a fixed point seen after 10 µm of focus: its image drifted by g * 10, {M} the same
    q0, _ = frame.to_image(np.array([5.0, -3.0, 0.0]))
    drifted = q0 + 10.0 * frame.drift_px_per_um
    assert np.allclose(frame.to_um(drifted, 10.0)[:2], [5.0, -3.0], atol=1e-9)


def test_the_covariance_follows_the_linear_map() -> None:
    frame = _frame(ScopeTruth(um_per_px=0.2, focus_tilt_deg=0.3))
    cov = np.diag([0.25, 0.25, 0.01])  # px², px², µm²
    out = frame.cov_to_um(cov)
    assert np.allclose(out, out.T)
    assert out[0, 0] == pytest.approx(0.25 * 0.04, rel=1e-3)
    assert out[2, 2] == pytest.approx(0.01)


def test_a_singular_map_is_refused_in_one_line() -> None:
    with pytest.raises(InputError, match="invertible") as info:
        MicroscopeFrame(np.zeros((2, 2)), np.zeros(2), np.zeros(2))
    assert "\n" not in str(info.value)
