"""Print the figures the simulator and stepwise tests assert (for release notes).

Run from the repository root: .venv/bin/python scripts/print_sim_figures.py
It reuses the helpers of the test suite, so the figures are those the tests check.
"""

import sys
from pathlib import Path

import numpy as np

from microcal import sim, stepwise_fit
from microcal.metrics import decoupling_metrics, pose_accuracy

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(TESTS / "sim"), str(TESTS / "kinematics"), str(TESTS / "vision")]
import test_render as rendering_tests  # noqa: E402
import test_stepwise as stepwise_tests  # noqa: E402

# issue 3: noise-free detection over 50 poses
plat = sim.platform("thesis", seed=1)
rng = np.random.default_rng(5)
errs = []
for _ in range(50):
    plat.manipulator.move_to_um(rng.uniform([0, 0, 0], [8000, 8000, 4800]))
    plat.manipulator.wait_until_stopped(plat.clock)
    plat.clock.sleep(10)
    for cam in plat.cameras.values():
        img, tr = cam.render_reflectance(plat.clock.now_s(), np.zeros(2))
        c = rendering_tests.detect(img * 255.0, tr.features_px[0])
        errs.append(c - tr.features_px[0])
e = np.concatenate(errs)
print(
    "noise-free detection RMS px",
    np.sqrt(np.mean(np.sum(e**2, 1))).round(4),
    "max",
    np.linalg.norm(e, axis=1).max().round(4),
)
# AP and decoupling
plat = sim.platform("thesis", seed=3)
m = plat.manipulator


def settle(w=10):
    m.wait_until_stopped(plat.clock)
    plat.clock.sleep(w)


m.move_to_um([0, 0, 0])
settle()
base = plat.truth_position_um()
arr = {i: [] for i in range(8)}
P = np.array(
    [
        [2000, 0, 0],
        [8000, 0, 0],
        [0, 2000, 0],
        [0, 8000, 0],
        [0, 0, 1500],
        [0, 0, 3000],
        [1000, 1000, 600],
        [2000, 2000, 300],
    ],
    float,
)
for _cycle in range(3):
    for i, p in enumerate(P):
        m.move_to_um(p)
        settle()
        arr[i].append(plat.truth_position_um() - base)
ap = [pose_accuracy(P[i], arr[i])[1] for i in range(8)]
print("uncalibrated AP_p", np.round(ap, 2), "mean", round(np.mean(ap), 2), "max", round(max(ap), 2))
plat = sim.platform("thesis", seed=4)
m = plat.manipulator
m.move_to_um([0, 0, 0])
settle()
samples = []
seg = []
t = np.zeros(3)
for ax, L in ((0, 8000.0), (1, 8000.0), (2, 4800.0)):
    for k in range(17):
        t[ax] = L * k / 16
        m.move_to_um(t)
        settle(5)
        samples.append(plat.truth_position_um())
        seg.append(ax)
r = decoupling_metrics(np.array(samples), np.array(seg))
print(
    "decoupling ranges",
    {a: tuple(round(v, 2) for v in r.ranges_um[a]) for a in "xyz"},
    "omega",
    {a: round(v, 1) for a, v in r.omega.items()},
)
# stepwise trials
exact = 0
w3 = []
for seed in range(100):
    X, y = stepwise_tests._synthetic(np.random.default_rng(1000 + seed), 170, stepwise_tests.TRUTH)
    rr = stepwise_fit(X, y)
    exact += rr.in_model.tolist() == (stepwise_tests.TRUTH != 0).tolist()
    ins = rr.in_model & (stepwise_tests.TRUTH != 0)
    w3 += (np.abs(rr.coef[ins] - stepwise_tests.TRUTH[ins]) <= 3 * rr.se[ins]).tolist()
print("stepwise exact selections", exact, "/100; within 3 se", round(np.mean(w3) * 100, 1), "%")

# Issue 4: calibration (method a) then 100 poses x 5 frames measured, against ground truth.
import test_measurement as vision_tests  # noqa: E402

from microcal.vision.detect import detect  # noqa: E402
from microcal.vision.measurement import measure_poses  # noqa: E402
from microcal.vision.virtual_point import virtual_point  # noqa: E402

plat_cal, cal = vision_tests.known_calibration.__wrapped__()
pts = vision_tests.workspace_points()
for name, c in cal.cameras.items():
    err = vision_tests.truth_reprojection_px(c.model, plat_cal.cameras[name].model, pts, pts)
    print(f"method (a) {name}: RMS {c.rms_px:.4f} px, vs true camera {err:.4f} px")
plat = sim.platform("thesis", seed=23)
d = np.random.default_rng(4).uniform([0, 0, 0], [8000, 8000, 4800], (100, 3))
frames, truth = {}, []
for i, di in enumerate(d):
    plat.manipulator.move_to_um(di)
    plat.manipulator.wait_until_stopped(plat.clock)
    plat.clock.sleep(5.0)
    truth.append(plat.truth_position_um())
    for n, cam in plat.cameras.items():
        frames[(i, n)] = [cam.grab() for _ in range(5)]
res = measure_poses(
    list(range(100)), d, lambda i, n: frames[(i, n)], cal.models(), vision_tests.BOARD
)
e = np.array([r.p_um for r in res]) - np.array(truth)
cov = np.array([r.cov_um2 for r in res])
m2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e)
print(
    "3D RMS um",
    np.sqrt(np.mean(np.sum(e**2, 1))).round(3),
    "per axis",
    np.sqrt((e**2).mean(0)).round(3),
    "Mahalanobis mean square",
    m2.mean().round(3),
)
plat = sim.platform("thesis", seed=24)
plat.manipulator.move_to_um([4000, 4000, 2400])
plat.manipulator.wait_until_stopped(plat.clock)
plat.clock.sleep(10.0)
cam = plat.cameras["top"]
corners, vps = [], []
for _ in range(100):
    det = detect(cam.grab(), vision_tests.BOARD)
    corners.append(det.q_px)
    vps.append(virtual_point(det, vision_tests.BOARD).q_px)
print(
    "Table 4-1 one corner",
    np.array(corners)[:, 5].std(0, ddof=1).round(3),
    "virtual point",
    np.array(vps).std(0, ddof=1).round(3),
)
