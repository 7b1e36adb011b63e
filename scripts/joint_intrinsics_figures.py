"""What the joint refinement of the cameras' intrinsics buys: the baseline of simulated
camera pairs calibrated three ways, the table of docs/vision.md ("Stereo calibration").

Per rig: random board poses seen by both cameras, the corners projected with the true
cameras and Gaussian noise added. Each camera is calibrated alone (``fit_camera`` with the
stated lens model), the poses refined with those intrinsics fixed (``refine_jointly``), then
everything together (``refine_intrinsics_jointly``); for comparison the poses are refined
with the true intrinsics fixed. The table gives, per rig kind, the RMS over 12 rigs of the
baseline's relative error.

Usage: python scripts/joint_intrinsics_figures.py   (prints a Markdown table)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from microcal.vision.joint_intrinsics import refine_intrinsics_jointly
from microcal.vision.joint_poses import Observation, Pose, initial_poses, refine_jointly
from microcal.vision.lens_models import fit_camera, lens_model

SIZE = (640, 480)
RIGS = 12


@dataclass(frozen=True)
class Rig:
    """A simulated pair: both cameras' intrinsics, the right camera's pose, the board."""

    label: str
    K: dict[str, np.ndarray]
    dist: dict[str, np.ndarray]
    right: Pose
    grid_um: np.ndarray
    distance_um: tuple[float, float]
    spread_um: float
    tilt_rad: float
    model: str
    noise_px: float
    views: int


def _grid(cols: int, rows: int, pitch_um: float) -> np.ndarray:
    return np.array([[x * pitch_um, y * pitch_um, 0.0] for y in range(rows) for x in range(cols)])


def _wide(model: str) -> Rig:
    K = {"left": np.array([[525.0, 0, 313.0], [0, 527.0, 247.0], [0, 0, 1]]),
         "right": np.array([[526.0, 0, 318.0], [0, 528.0, 246.0], [0, 0, 1]])}  # fmt: skip
    dist = {"left": np.array([-0.36, 0.17, 0, 0, 0.0]), "right": np.array([-0.35, 0.16, 0, 0, 0.0])}
    right = (cv2.Rodrigues(np.array([0.004, -0.006, -0.002]))[0], np.array([-120_000.0, -500, 0]))
    return Rig(f"wide-angle pair (Bumblebee2-like), {model}", K, dist, right,
               _grid(6, 4, 30_000.0), (550_000.0, 800_000.0), 100_000.0, 0.35, model, 0.08,
               11)  # fmt: skip


def _narrow(focal_px: float) -> Rig:
    K = np.array([[focal_px, 0, 330.0], [0, focal_px * 1.002, 236.0], [0, 0, 1]])
    angle = float(np.arctan2(350.0, 1000.0))
    R = cv2.Rodrigues(np.array([0.0, angle, 0.0]))[0]
    fov = 2.0 * np.degrees(np.arctan(np.hypot(*SIZE) / 2.0 / focal_px))
    label = f"narrow field ({fov:.0f} deg), converging by {np.degrees(angle):.0f} deg, radial1"
    return Rig(label, {"left": K, "right": K}, {c: np.array([-0.3, 0, 0, 0, 0.0])
               for c in ("left", "right")}, (R, -R @ np.array([350_000.0, 0, 0])),
               _grid(9, 7, 10_000.0), (980_000.0, 1_020_000.0), 5_000.0, 0.3, "radial1", 0.1,
               12)  # fmt: skip


def _observe(rig: Rig, rng: np.random.Generator) -> tuple[list[Observation], dict[int, Pose]]:
    cams = {"left": (np.eye(3), np.zeros(3)), "right": rig.right}
    views: dict[int, Pose] = {}
    obs = []
    for v in range(rig.views):
        R = cv2.Rodrigues(rng.normal(0, rig.tilt_rad, 3))[0]
        centre = np.array([rng.normal(0, rig.spread_um), rng.normal(0, rig.spread_um),
                           rng.uniform(*rig.distance_um)])  # fmt: skip
        views[v] = (R, centre - R @ rig.grid_um.mean(axis=0))
        for c, (Rc, tc) in cams.items():
            q, _ = cv2.projectPoints(rig.grid_um, cv2.Rodrigues(Rc @ R)[0],
                                     Rc @ views[v][1] + tc, rig.K[c], rig.dist[c])  # fmt: skip
            q = q.reshape(-1, 2)
            inside = np.all((q > 0) & (q < np.array(SIZE)), axis=1)
            if np.count_nonzero(inside) >= 12:
                noisy = q[inside] + rng.normal(0, rig.noise_px, (np.count_nonzero(inside), 2))
                obs.append(Observation(c, v, rig.grid_um[inside], noisy))
    return obs, views


def baseline_errors(rig: Rig, seed: int) -> dict[str, float]:
    """One rig's relative baseline error calibrated three ways."""
    rng = np.random.default_rng(seed)
    obs, views = _observe(rig, rng)
    model = lens_model(rig.model)
    intr, poses = {}, {}
    for c in ("left", "right"):
        mine = [o for o in obs if o.camera == c]
        fit = fit_camera([o.object_um for o in mine], [o.image_px for o in mine], SIZE, model)
        intr[c] = (fit.K, fit.dist)
        poses[c] = {o.view: (cv2.Rodrigues(r)[0], np.ravel(t))
                    for o, r, t in zip(mine, fit.rvecs, fit.tvecs, strict=True)}  # fmt: skip
    fixed = refine_jointly(obs, intr, *initial_poses(poses, "left"), "left")
    joint = refine_intrinsics_jointly(obs, intr, dict.fromkeys(intr, model), fixed.cameras,
                                      fixed.views, "left")  # fmt: skip
    cams = {"left": (np.eye(3), np.zeros(3)), "right": rig.right}
    truth = refine_jointly(obs, {c: (rig.K[c], rig.dist[c]) for c in cams}, cams, views, "left")
    length = float(np.linalg.norm(rig.right[1]))
    return {k: float(np.linalg.norm(f.cameras["right"][1])) / length - 1.0
            for k, f in (("fixed", fixed), ("joint", joint), ("true", truth))}  # fmt: skip


def main() -> None:
    print("| rig, lens model | intrinsics fixed from each camera alone | refined jointly "
          "| true intrinsics fixed |")  # fmt: skip
    print("| --- | --- | --- | --- |")
    for rig in (_wide("radial2"), _wide("radial3-tangential"), _narrow(5000.0), _narrow(2500.0)):
        errors = [baseline_errors(rig, seed) for seed in range(RIGS)]
        rms = {k: 100.0 * float(np.sqrt(np.mean([e[k] ** 2 for e in errors])))
               for k in ("fixed", "joint", "true")}  # fmt: skip
        print(f"| {rig.label}, {rig.noise_px:g} px | {rms['fixed']:.2f} % | {rms['joint']:.2f} % "
              f"| {rms['true']:.2f} % |")  # fmt: skip


if __name__ == "__main__":
    main()
