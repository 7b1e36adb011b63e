"""The joint refinement of all cameras' intrinsics, lens terms and poses (method (b))."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.errors import DegenerateDataError
from microcal.vision.joint_intrinsics import refine_intrinsics_jointly, residuals_px
from microcal.vision.joint_poses import Observation, initial_poses, refine_jointly
from microcal.vision.lens_models import fit_camera, lens_model

#: A wide-angle camera like the Bumblebee2's (640 x 480), the truth of both cameras.
K_TRUE = {
    "left": np.array([[525.0, 0.0, 313.0], [0.0, 527.0, 247.0], [0.0, 0.0, 1.0]]),
    "right": np.array([[526.0, 0.0, 318.0], [0.0, 528.0, 246.0], [0.0, 0.0, 1.0]]),
}
DIST_TRUE = {
    "left": np.array([-0.36, 0.17, 0.0, 0.0, 0.0]),
    "right": np.array([-0.35, 0.16, 0.0, 0.0, 0.0]),
}
#: A 6 x 4 chessboard of 30 mm squares, µm.
GRID = np.array([[x, y, 0.0] for y in range(0, 120_000, 30_000) for x in range(0, 180_000, 30_000)],
                dtype=np.float64)  # fmt: skip
#: The right camera's frame from the left's: a 120 mm baseline.
RIGHT = (cv2.Rodrigues(np.array([0.004, -0.006, -0.002]))[0], np.array([-120_000.0, -500.0, 0.0]))
MODELS = {"left": lens_model("radial2"), "right": lens_model("radial2")}


def _views(rng, n):
    views = {}
    for v in range(n):
        R = cv2.Rodrigues(rng.normal(0, 0.35, 3))[0]
        centre = np.array([rng.uniform(-150_000, 100_000), rng.uniform(-90_000, 60_000),
                           rng.uniform(550_000, 800_000)])  # fmt: skip
        views[v] = (R, centre - R @ GRID.mean(axis=0))
    return views


def _observe(views, rng, noise_px, cameras=("left", "right")):
    cams = {"left": (np.eye(3), np.zeros(3)), "right": RIGHT}
    obs = []
    for v, (Rv, tv) in views.items():
        for c in cameras:
            Rc, tc = cams[c]
            q, _ = cv2.projectPoints(GRID, cv2.Rodrigues(Rc @ Rv)[0], Rc @ tv + tc, K_TRUE[c],
                                     DIST_TRUE[c])  # fmt: skip
            obs.append(Observation(c, v, GRID, q.reshape(-1, 2) + rng.normal(0, noise_px, (24, 2))))
    return cams, obs


def test_jacobian_matches_central_differences():
    rng = np.random.default_rng(3)
    views = _views(rng, 4)
    _, obs = _observe(views, rng, 0.1)
    intr = {c: (K_TRUE[c], DIST_TRUE[c]) for c in K_TRUE}
    models = {"left": lens_model("radial2"), "right": lens_model("radial3-tangential")}
    x = [np.array([525.0, 527.0, 313.0, 247.0, -0.36, 0.17]),
         np.array([526.0, 528.0, 318.0, 246.0, -0.35, 0.16, 0.0, 0.0, 0.0])]  # fmt: skip
    x += [cv2.Rodrigues(RIGHT[0])[0].ravel(), RIGHT[1]]
    for v in range(4):
        x += [cv2.Rodrigues(views[v][0])[0].ravel(), views[v][1]]
    x0 = np.concatenate(x) + rng.normal(0, 1e-4, sum(len(a) for a in x))
    _, jac = residuals_px(x0, obs, intr, models, "left")
    steps = np.where(np.abs(x0) > 1000.0, 1e-2, 1e-6)  # µm for translations, else relative
    fd = np.zeros_like(jac)
    for j in range(len(x0)):
        xp, xm = x0.copy(), x0.copy()
        xp[j] += steps[j]
        xm[j] -= steps[j]
        fd[:, j] = (residuals_px(xp, obs, intr, models, "left")[0]
                    - residuals_px(xm, obs, intr, models, "left")[0]) / (2 * steps[j])  # fmt: skip
    # Metric: largest difference of a derivative, relative to the column's largest.
    scale = np.maximum(np.max(np.abs(fd), axis=0), 1e-12)
    assert np.max(np.abs(jac - fd) / scale) < 1e-4


def _calibrate(obs, model):
    """As the procedure does: each camera alone, then the poses with those intrinsics fixed,
    then everything together."""
    intr, poses = {}, {}
    for c in ("left", "right"):
        mine = [o for o in obs if o.camera == c]
        fit = fit_camera([o.object_um for o in mine], [o.image_px for o in mine], (640, 480),
                         model)  # fmt: skip
        intr[c] = (fit.K, fit.dist)
        poses[c] = {o.view: (cv2.Rodrigues(r)[0], np.ravel(t))
                    for o, r, t in zip(mine, fit.rvecs, fit.tvecs, strict=True)}  # fmt: skip
    fixed = refine_jointly(obs, intr, *initial_poses(poses, "left"), "left")
    models = dict.fromkeys(intr, model)
    joint = refine_intrinsics_jointly(obs, intr, models, fixed.cameras, fixed.views, "left")
    return fixed, joint


@pytest.mark.slow
@pytest.mark.parametrize("model", ["radial2", "radial3-tangential"])
def test_the_shared_views_put_the_baseline_right(model):
    # 11 views of a 6 x 4 board by a wide-angle pair, corners with 0.08 px noise, 12 rigs:
    # with each camera's intrinsics fixed from its own calibration the baseline carries their
    # errors (0.5-0.6 % RMS); refined together it is nearly as right as with the true
    # intrinsics fixed (0.12 %).
    errors: dict[str, list[float]] = {"fixed": [], "joint": [], "true": []}
    true_length = float(np.linalg.norm(RIGHT[1]))
    for seed in range(12):
        rng = np.random.default_rng(seed)
        views = _views(rng, 11)
        cams, obs = _observe(views, rng, 0.08)
        fixed, joint = _calibrate(obs, lens_model(model))
        truth = refine_jointly(obs, {c: (K_TRUE[c], DIST_TRUE[c]) for c in K_TRUE}, cams, views,
                               "left")  # fmt: skip
        for key, fit in (("fixed", fixed), ("joint", joint), ("true", truth)):
            errors[key].append(float(np.linalg.norm(fit.cameras["right"][1])) / true_length - 1)
        assert joint.rms_px < fixed.rms_px
        for c in ("left", "right"):  # the model's fixed terms stay zero
            assert np.all(joint.intrinsics[c][1][len(lens_model(model).terms) :] == 0.0)
    # Metric: RMS over the rigs of the relative baseline error.
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in errors.items()}
    assert rms["joint"] < 0.4 * rms["fixed"]
    assert rms["joint"] < 1.5 * rms["true"]
    assert rms["joint"] < 0.002


def test_a_view_one_camera_alone_saw_keeps_its_own_board_pose():
    rng = np.random.default_rng(12)
    views = _views(rng, 7)
    cams, obs = _observe({v: p for v, p in views.items() if v < 6}, rng, 0.05)
    _, alone = _observe({6: views[6]}, rng, 0.05, cameras=("right",))
    start = {c: (K_TRUE[c], DIST_TRUE[c]) for c in K_TRUE}
    joint = refine_intrinsics_jointly(obs + alone, start, MODELS, cams, views, "left")
    assert set(joint.per_view_rms_px) == set(range(7))
    # Metric: the lone view's RMS, px, and its board pose against the truth, µm.
    assert joint.per_view_rms_px[6] < 0.15
    assert np.linalg.norm(joint.views[6][1] - views[6][1]) < 0.01 * np.linalg.norm(views[6][1])


def test_too_few_corners_are_refused():
    rng = np.random.default_rng(13)
    views = _views(rng, 1)
    cams, obs = _observe(views, rng, 0.05)
    few = [Observation(o.camera, o.view, o.object_um[:4], o.image_px[:4]) for o in obs]
    start = {c: (K_TRUE[c], DIST_TRUE[c]) for c in K_TRUE}
    with pytest.raises(DegenerateDataError, match="too few corners"):
        refine_intrinsics_jointly(few, start, MODELS, cams, views, "left")
