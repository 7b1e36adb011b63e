"""The joint refinement of all cameras' and all views' poses (method (b) with N cameras)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.errors import DegenerateDataError
from microcal.vision.joint_poses import (
    Observation,
    initial_poses,
    refine_jointly,
    residuals_px,
)

K = np.array([[800.0, 0.0, 320.0], [0.0, 805.0, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.05, 1e-3, -5e-4, 0.0])
GRID = np.array([[x, y, 0.0] for x in range(0, 50_000, 10_000) for y in range(0, 40_000, 10_000)])


def _rot(rvec):
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return R


def _rig(rng, n_cameras=3, n_views=5):
    """True camera poses from the first camera's frame and the board's poses in it."""
    cams = {"c0": (np.eye(3), np.zeros(3))}
    for k in range(1, n_cameras):
        cams[f"c{k}"] = (_rot(rng.normal(0, 0.08, 3)), np.array([-80_000.0 * k, 2000.0, 500.0]))
    views = {
        v: (_rot(rng.normal(0, 0.4, 3)), np.array([-20_000.0, -15_000.0, 500_000.0])
            + rng.normal(0, 20_000, 3))
        for v in range(n_views)
    }  # fmt: skip
    return cams, views


def _observe(cams, views, seen, noise_px=0.0, rng=None):
    obs = []
    for c, (Rc, tc) in cams.items():
        for v, (Rv, tv) in views.items():
            if (c, v) not in seen:
                continue
            R, t = Rc @ Rv, Rc @ tv + tc
            q, _ = cv2.projectPoints(GRID, cv2.Rodrigues(R)[0], t, K, DIST)
            q = q.reshape(-1, 2)
            if noise_px:
                q = q + rng.normal(0, noise_px, q.shape)
            obs.append(Observation(c, v, GRID, q))
    return obs


def _vector(cams, views, obs):
    x = []
    for c in dict.fromkeys(o.camera for o in obs):
        if c != "c0":
            x += [cv2.Rodrigues(cams[c][0])[0].ravel(), cams[c][1]]
    for v in dict.fromkeys(o.view for o in obs):
        x += [cv2.Rodrigues(views[v][0])[0].ravel(), views[v][1]]
    return np.concatenate(x)


def test_jacobian_matches_central_differences():
    rng = np.random.default_rng(5)
    cams, views = _rig(rng)
    seen = {(c, v) for c in cams for v in views}
    obs = _observe(cams, views, seen, noise_px=0.3, rng=rng)
    intr = dict.fromkeys(cams, (K, DIST))
    x = _vector(cams, views, obs) + rng.normal(0, 1e-3, 6 * (2 + 5))
    _, jac = residuals_px(x, obs, intr, "c0")
    fd = np.zeros_like(jac)
    for j in range(len(x)):
        h = 1e-6 if j % 6 < 3 else 1e-2  # radians; µm
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        fd[:, j] = (residuals_px(xp, obs, intr, "c0")[0] - residuals_px(xm, obs, intr, "c0")[0]) / (
            2 * h
        )
    # Metric: largest difference relative to the column's largest entry.
    scale = np.abs(fd).max(axis=0)
    assert np.all(scale > 0)
    assert np.max(np.abs(jac - fd) / scale) < 1e-4


def test_initial_poses_join_a_camera_through_another():
    rng = np.random.default_rng(6)
    cams, views = _rig(rng, n_cameras=3, n_views=6)
    # c2 never sees a view with c0; c1 sees views with both.
    seen = {("c0", v) for v in (0, 1, 2)} | {("c1", v) for v in range(6)}
    seen |= {("c2", v) for v in (3, 4, 5)}
    poses = {
        c: {v: (cams[c][0] @ views[v][0], cams[c][0] @ views[v][1] + cams[c][1])
            for v in views if (c, v) in seen}
        for c in cams
    }  # fmt: skip
    start_c, start_v = initial_poses(poses, "c0")
    for c in cams:  # Metric: max abs difference, exact data.
        assert np.abs(start_c[c][0] - cams[c][0]).max() < 1e-9
        assert np.abs(start_c[c][1] - cams[c][1]).max() < 1e-6
    for v in views:
        assert np.abs(start_v[v][1] - views[v][1]).max() < 1e-6


def test_a_camera_sharing_no_view_is_refused_with_its_name():
    pose = (np.eye(3), np.zeros(3))
    poses = {"c0": {0: pose, 1: pose}, "c1": {0: pose, 1: pose}, "c2": {2: pose, 3: pose}}
    with pytest.raises(DegenerateDataError, match="c2 share no view"):
        initial_poses(poses, "c0")


@pytest.mark.parametrize("noise_px", [0.0, 0.05])
def test_refinement_recovers_the_poses_from_a_rough_start(noise_px):
    rng = np.random.default_rng(8)
    cams, views = _rig(rng, n_cameras=3, n_views=6)
    # Each view seen by a different subset of the cameras.
    seen = {("c0", 0), ("c1", 0), ("c0", 1), ("c2", 1), ("c1", 2), ("c2", 2), ("c0", 3)}
    seen |= {("c1", 3), ("c2", 3), ("c0", 4), ("c1", 4), ("c0", 5), ("c2", 5)}
    obs = _observe(cams, views, seen, noise_px=noise_px, rng=rng)
    start_c = {c: (R @ _rot(rng.normal(0, 0.01, 3)), t + rng.normal(0, 2000, 3))
               for c, (R, t) in cams.items()}  # fmt: skip
    start_c["c0"] = cams["c0"]
    start_v = {v: (R @ _rot(rng.normal(0, 0.01, 3)), t + rng.normal(0, 2000, 3))
               for v, (R, t) in views.items()}  # fmt: skip
    fit = refine_jointly(obs, dict.fromkeys(cams, (K, DIST)), start_c, start_v, "c0")
    assert set(fit.per_view_rms_px) == set(views)
    if noise_px:
        # Metric: residual RMS (2D length) against the noise's sqrt(2) x 0.05 px, less the
        # share the 6 x 8 pose parameters take up of the 2 x 20 x 13 residuals.
        dof = 1 - 48 / (2 * 20 * 13)
        assert fit.rms_px == pytest.approx(noise_px * np.sqrt(2 * dof), rel=0.1)
        return
    # Exact data: the truth, from 10 mrad and 2 mm off. Metric: rotation angle, deg; distance.
    assert fit.rms_px < 1e-6
    for c in cams:
        R, t = fit.cameras[c]
        angle = np.degrees(np.arccos(np.clip((np.trace(R @ cams[c][0].T) - 1) / 2, -1, 1)))
        assert angle < 1e-6
        assert np.linalg.norm(t - cams[c][1]) < 1e-3
