"""Chessboards that overfill the field: numbered from three marker circles (OpenCV's
sector-based finder), corners refined as any chessboard's, rendered by the simulator."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import sim
from microcal.errors import InputError
from microcal.sim.render import Placement, Reflectance
from microcal.sim.slide_render import render_slide
from microcal.vision.board_symmetry import ambiguous_turns
from microcal.vision.detect import detect
from microcal.vision.targets import parse_target

#: 41 x 31 squares of 250 µm; the circles in squares (20, 15), (20, 16) and (21, 16): the
#: corner square (20, 16) is dark (a light circle), the two others light (dark circles).
BOARD_SPEC = "chessboard:40x30:250:markers=20,15/20,16/21,16"
BOARD = parse_target(BOARD_SPEC)
#: The same board with squares a telecentric lens shows about as large (600 µm).
BOARDS = {"thesis": BOARD, "telecentric": parse_target(BOARD_SPEC.replace(":250:", ":600:"))}
#: The part of the image rendered and searched (x0, y0, x1, y1).
BOX = (300, 250, 800, 650)


def _rot(rvec):
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]


def _marker_um(target):
    c, r = target.markers[1]  # the corner square's centre
    return np.array([(c - 0.5) * target.pitch_um, (r - 0.5) * target.pitch_um, 0.0])


def _placement(cam, rvec, at_px, target=BOARD, square_px=24.0):
    """The board turned by ``rvec`` (in the camera's frame) with its corner marker's square
    at ``at_px``, a square about ``square_px`` across."""
    R = cam.R.T @ _rot(rvec)
    centre = _marker_um(target)
    step = target.pitch_um / square_px
    depth_um = cam.K[0, 0] * step if cam.kind == "pinhole" else 0.0
    t = cam.R.T @ (np.array([0.0, 0.0, depth_um]) - cam.t_um)
    for _ in range(20):
        q = cam.project((R @ centre + t)[None])[0]
        J = np.column_stack([(cam.project((R @ centre + t + d)[None])[0] - q) for d in
                             (cam.R.T[:, 0] * step, cam.R.T[:, 1] * step)])  # fmt: skip
        move = np.linalg.solve(J, np.asarray(at_px, float) - q)
        t = t + (cam.R.T[:, 0] * move[0] + cam.R.T[:, 1] * move[1]) * step
    return Placement(target, R, t)


def _image(cam, placement, rng, box=BOX, blur=0.7, noise=1.0, frames=1):
    """8-bit render of the board over ``box`` (blurred, noisy; ``frames`` averaged)."""
    w, h = cam.image_size_px
    refl = Reflectance()
    value, alpha = render_slide(cam, placement, box, reflectance=refl)
    patch = np.where(alpha > 0, value, refl.background) * 230.0
    clean = np.full((h, w), refl.background * 230.0, dtype=np.float32)
    clean[box[1] : box[3], box[0] : box[2]] = patch
    clean = cv2.GaussianBlur(clean, (0, 0), blur)
    total = np.zeros((h, w), dtype=np.float32)
    for _ in range(frames):
        noisy = clean + np.float32(noise) * rng.standard_normal(clean.shape, dtype=np.float32)
        total += np.clip(np.rint(noisy), 0, 255)
    return (total / frames).astype(np.float32)


# Poses: (rotation vector in the camera frame, where the corner marker lands, px): turned in
# plane (a quarter and a half turn), tilted by up to 25 degrees.
POSES = [
    ((0.0, 0.0, 0.1), (550, 450)),
    ((0.3, -0.2, 0.5), (480, 420)),
    ((-0.25, 0.2, 1.9), (600, 380)),
    ((0.2, 0.3, -2.6), (480, 480)),
    ((0.1, -0.1, 1.6), (520, 470)),
]


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["thesis", "telecentric"])
def test_rendered_boards_are_numbered_right_and_corners_within_a_fiftieth_pixel(preset):
    rng = np.random.default_rng(3)
    cam = sim.platform(preset, seed=0).camera_models["side"]
    board = BOARDS[preset]
    errors = []
    for rvec, at in POSES:
        placement = _placement(cam, rvec, at, board)
        det = detect(_image(cam, placement, rng, frames=8), board, roi=BOX)
        assert det.found, det.reason
        truth = cam.project(placement.points_world_um())
        # the numbering: every corner's id is the corner nearest to where it was found (100 %)
        nearest = np.argmin(np.linalg.norm(truth[None, :, :] - det.q_px[:, None, :], axis=2),
                            axis=1)  # fmt: skip
        assert np.array_equal(nearest, det.ids)
        assert len(det.ids) > 100
        errors.append(np.linalg.norm(det.q_px - truth[det.ids], axis=1))
    err = np.concatenate(errors)
    # Metric: distance of the corners found from their true projections, px (0.7 px blur,
    # noise 1 DN of 230 over 8 averaged frames, squares about 24 px across): RMS about
    # 0.007, every corner within 0.02 (the worst 0.015-0.018 over these poses, noise seeds 3
    # and 11; 0.025 with the symmetry fit alone)
    assert np.sqrt(np.mean(err**2)) < 0.01
    assert err.max() < 0.02


def test_views_without_the_circles_say_why():
    rng = np.random.default_rng(4)
    cam = sim.platform("thesis", seed=0).camera_models["side"]
    far = _placement(cam, (0.0, 0.0, 0.1), (1100, 900))  # circles outside the box
    det = detect(_image(cam, far, rng), BOARD, roi=BOX)
    assert not det.found
    assert "not its 3 marker circles" in det.reason
    # a circle on the wrong colour: the spec's corner square one off (light, not dark)
    wrong = parse_target("chessboard:40x30:250:markers=21,15/21,16/22,16")
    det = detect(_image(cam, _placement(cam, (0.0, 0.0, 0.1), (550, 450)), rng), wrong, roi=BOX)
    assert not det.found
    assert "do not match the spec's markers" in det.reason


def test_board_spec_round_trips_and_is_checked():
    assert BOARD.markers == ((20, 15), (20, 16), (21, 16))
    assert parse_target(BOARD.spec) == BOARD
    assert BOARD.partial
    assert ambiguous_turns(BOARD) == [0]
    for spec, words in [
        ("chessboard:9x6:400:markers=4,3/4,4", "exactly 3 marker circles"),
        ("chessboard:9x6:400:markers=4,3/4,4/5,4/5,3", "exactly 3 marker circles"),
        ("chessboard:9x6:400:markers=4,2/4,4/6,4", "an L of neighbouring squares"),
        ("chessboard:9x6:400:markers=3,3/4,4/5,5", "an L of neighbouring squares"),
        ("chessboard:9x6:400:markers=9,3/9,4/8,4", "outside the board's inner squares"),
        ("chessboard:9x6:400:markers=0,3/0,4/1,4", "outside the board's inner squares"),
        ("chessboard:9x6:400:markers=4,3/4,3/5,3", "given twice"),
        ("chessboard:9x6:400:markers=4;3", "expected markers=C,R/C,R/C,R"),
        ("charuco:5x4:400:markers=2,2/2,3/3,3", "numbered by its own codes"),
    ]:
        with pytest.raises(InputError, match=words):
            parse_target(spec)


#: A board larger than both thesis cameras' crops (500 µm squares, about 22 px), its circles
#: near its middle.
PAIR_BOARD = "chessboard:60x50:500:markers=30,25/30,26/31,26"
#: Each camera's crop (x0, y0, x1, y1) about where both optical axes pass nearest.
PAIR_BOXES = {"side": (364, 336, 864, 736), "top": (575, 430, 1075, 830)}
#: Views: (tilt about the board's x and y axes and in-plane turn, rad; shift in the board's
#: plane, µm).
PAIR_VIEWS = [
    ((0.0, 0.0, 0.05), (0.0, 0.0)),
    ((0.12, 0.0, 0.3), (300.0, -200.0)),
    ((-0.12, 0.05, -0.2), (-300.0, 200.0)),
    ((0.05, 0.12, 0.1), (200.0, 300.0)),
    ((-0.08, -0.08, -0.15), (-200.0, -300.0)),
    ((0.1, -0.1, 0.2), (0.0, 400.0)),
]


def _pair_placements(cams, target):
    """Placements seen by both thesis cameras: the board faces the two, its corner marker's
    square near the point where their optical axes pass nearest."""
    rays = []
    for cam in cams.values():
        rays.append((-cam.R.T @ cam.t_um, cam.R.T @ np.array([0.0, 0.0, 1.0])))
    (o1, d1), (o2, d2) = rays
    s = np.linalg.lstsq(np.column_stack([d1, -d2]), o2 - o1, rcond=None)[0]
    meet = 0.5 * (o1 + s[0] * d1 + o2 + s[1] * d2)
    z = (d1 + d2) / np.linalg.norm(d1 + d2)  # the board's +z points away from the cameras
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    base = np.column_stack([x, np.cross(z, x), z])
    out = []
    for (ax, ay, az), shift in PAIR_VIEWS:
        R = base @ _rot((ax, ay, 0.0)) @ _rot((0.0, 0.0, az))
        centre = _marker_um(target) + np.array([*shift, 0.0])
        out.append(Placement(target, R, meet - R @ centre))
    return out


def _write_pair(tmp_path, target, rng):
    cams = sim.platform("thesis", seed=0).camera_models
    for i, placement in enumerate(_pair_placements(cams, target)):
        for name, cam in cams.items():
            image = _image(cam, placement, rng, box=PAIR_BOXES[name], frames=4)
            x0, y0, x1, y1 = PAIR_BOXES[name]
            crop = np.clip(np.rint(image[y0:y1, x0:x1]), 0, 255).astype(np.uint8)
            cv2.imwrite(str(tmp_path / f"{name}_{i}.png"), crop)
    return cams


@pytest.mark.slow
def test_partial_board_views_calibrate_the_thesis_cameras_and_a_wrong_spec_is_refused(tmp_path):
    from microcal.workflows.stereo import stereo_calibrate_images

    rng = np.random.default_rng(7)
    target = parse_target(PAIR_BOARD)
    cams = _write_pair(tmp_path, target, rng)
    images = [f"{name}={tmp_path}/{name}_*.png" for name in cams]
    # a spec whose circles sit one square off: the marker squares' colours contradict it
    wrong = "chessboard:60x50:500:markers=31,25/31,26/32,26"
    refused = tmp_path / "refused.json"
    with pytest.raises(InputError) as err:
        stereo_calibrate_images(wrong, images, refused)
    assert "\n" not in str(err.value)
    assert "do not match the spec's markers" in str(err.value)
    assert not refused.exists()

    out = tmp_path / "cameras.json"
    cal = stereo_calibrate_images(PAIR_BOARD, images, out, lens_model="radial1")
    assert out.exists()
    for name, cam in cams.items():
        assert cal.cameras[name].views_used == len(PAIR_VIEWS)
        K = cal.cameras[name].model.K
        # Metric: the focal length (px) against the true camera's, relative (the principal
        # point is left alone: 500 x 400 px of a lens of 12800-14900 px fix it loosely)
        assert abs(K[0, 0] / cam.K[0, 0] - 1.0) < 0.02, name
    # Metric: the stereo RMS reprojection error, px
    assert cal.rms_px < 0.1


@pytest.mark.slow
def test_a_board_moved_by_known_steps_across_its_plane_calibrates_from_different_parts(tmp_path):
    """Method (a) end to end (``calibrate-cameras --known-displacements``) with a marked
    chessboard of which each view sees a different part (the rendered box as the image)."""
    from microcal.workflows.stereo import stereo_calibrate_images

    cam = sim.platform("thesis", seed=0).camera_models["side"]
    base = _placement(cam, (0.15, -0.1, 0.2), (560, 460))
    steps = np.array([[0.0, 0.0, 0.0], [-1500.0, 0.0, 1000.0], [750.0, 750.0, 2000.0],
                      [-750.0, -750.0, 3000.0], [-1500.0, 500.0, 1500.0]])  # fmt: skip
    seen = []
    for name, seed in (("a", 7), ("b", 8)):
        rng = np.random.default_rng(seed)
        for i, d in enumerate(steps):
            moved = Placement(BOARD, base.R, base.t_um + base.R @ d)
            image = _image(cam, moved, rng, frames=8)[BOX[1] : BOX[3], BOX[0] : BOX[2]]
            cv2.imwrite(str(tmp_path / f"{name}_{i}.png"), np.rint(image).astype(np.uint8))
            if name == "a":
                seen.append(set(detect(image, BOARD).ids.tolist()))
    for i, ids in enumerate(seen):  # each view sees corners no other view sees
        assert ids - set().union(*(s for k, s in enumerate(seen) if k != i)), i
    csv = tmp_path / "steps.csv"
    csv.write_text("dx_um,dy_um,dz_um\n" + "".join(f"{x},{y},{z}\n" for x, y, z in steps))
    out = tmp_path / "cameras.json"
    cal = stereo_calibrate_images(BOARD_SPEC, [f"a={tmp_path}/a_*.png", f"b={tmp_path}/b_*.png"],
                                  out, known_displacements=csv, camera_model="pinhole")  # fmt: skip
    assert out.exists()
    every = np.array(sorted(set().union(*seen)))
    truth = cam.project(base.points_world_um()[every]) - BOX[:2]  # the box's pixels
    for name in ("a", "b"):
        c = cal.cameras[name]
        assert c.views_used == len(steps)
        # Metric: RMS reprojection error of the corners found, px
        assert c.rms_px < 0.05
        err = np.linalg.norm(c.model.project(BOARD.points_um()[every]) - truth, axis=1)
        # Metric: the calibrated camera against the true one over every corner seen, px RMS
        assert np.sqrt(np.mean(err**2)) < 0.05
