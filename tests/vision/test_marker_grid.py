"""Calibration slides that overfill the field: numbered from hollow marker dots, centres
corrected for perspective, rendered by the simulator on the thesis and telecentric presets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import sim
from microcal.errors import InputError
from microcal.sim.platforms import OVERFILLING_SLIDE
from microcal.sim.render import Placement, Reflectance
from microcal.sim.slide_render import render_slide
from microcal.vision.board_symmetry import ambiguous_turns
from microcal.vision.detect import detect
from microcal.vision.dot_centres import disc_image_bias_px
from microcal.vision.targets import parse_target

SLIDE = parse_target(OVERFILLING_SLIDE)
#: The part of the image rendered and searched (x0, y0, x1, y1): rendering and locating
#: thousands of dots over the whole image takes tens of seconds.
BOX = (300, 250, 800, 650)


def _rot(rvec):
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]


def _placement(cam, rvec, at_px, pitch_px=22.0, depth_um=None):
    """The slide turned by ``rvec`` (in the camera's frame) with its first marker at ``at_px``
    (at ``depth_um`` from the camera; pinhole: by default where a pitch is ``pitch_px``)."""
    R = cam.R.T @ _rot(rvec)
    centre = np.array([*SLIDE.markers[0], 0.0]) * SLIDE.pitch_um
    step = SLIDE.pitch_um / pitch_px  # µm per px, roughly: Newton steps across the view
    if depth_um is None:
        depth_um = cam.K[0, 0] * step if cam.kind == "pinhole" else 0.0
    t = cam.R.T @ (np.array([0.0, 0.0, depth_um]) - cam.t_um)
    for _ in range(20):  # put the marker where it is wanted, whatever the projection
        q = cam.project((R @ centre + t)[None])[0]
        J = np.column_stack([(cam.project((R @ centre + t + d)[None])[0] - q) for d in
                             (cam.R.T[:, 0] * step, cam.R.T[:, 1] * step)])  # fmt: skip
        move = np.linalg.solve(J, np.asarray(at_px, float) - q)
        t = t + (cam.R.T[:, 0] * move[0] + cam.R.T[:, 1] * move[1]) * step
    return Placement(SLIDE, R, t)


def _image(cam, placement, rng, box=BOX, blur=0.7, noise=1.0):
    """8-bit render of the slide over ``box`` (blurred, noisy), whole-image coordinates."""
    w, h = cam.image_size_px
    refl = Reflectance()
    value, alpha = render_slide(cam, placement, box, reflectance=refl)
    patch = np.where(alpha > 0, value, refl.glass) * 230.0
    image = np.full((h, w), refl.glass * 230.0, dtype=np.float32)
    image[box[1] : box[3], box[0] : box[2]] = patch
    image = cv2.GaussianBlur(image, (0, 0), blur)
    image += np.float32(noise) * rng.standard_normal(image.shape, dtype=np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _truth(cam, placement):
    return cam.project(placement.points_world_um())


# Poses: (rotation vector in the camera frame, where the first marker lands, px): turned
# in-plane, tilted by up to 25 degrees, markers near the box's edges.
POSES = [
    ((0.0, 0.0, 0.1), (550, 450)),
    ((0.3, -0.2, 0.5), (480, 420)),
    ((-0.35, 0.25, 2.0), (600, 380)),
    ((0.2, 0.3, -2.6), (420, 520)),
]


@pytest.mark.parametrize("preset", ["thesis", "telecentric"])
def test_rendered_slides_are_numbered_right_and_centred_within_a_fiftieth_pixel(preset):
    rng = np.random.default_rng(3)
    cam = sim.platform(preset, seed=0).camera_models["side"]
    errors = []
    for rvec, at in POSES:
        placement = _placement(cam, rvec, at)
        det = detect(_image(cam, placement, rng), SLIDE, roi=BOX)
        assert det.found, det.reason
        truth = _truth(cam, placement)
        # the numbering: every dot's id is the dot nearest to where it was found (100 %)
        nearest = np.argmin(np.linalg.norm(truth[None, :, :] - det.q_px[:, None, :], axis=2),
                            axis=1)  # fmt: skip
        assert np.array_equal(nearest, det.ids)
        assert len(det.ids) > 300
        errors.append(np.linalg.norm(det.q_px - truth[det.ids], axis=1))
    err = np.concatenate(errors)
    # Metric: distance of the dot centres found from their true projections, px (0.7 px
    # blur, noise 1 DN of 230, dots about 11 px across): RMS about 0.005, every dot within
    # 0.02 (the worst 0.013-0.015 over these poses and noise seeds 3, 11, 12)
    assert np.sqrt(np.mean(err**2)) < 0.01
    assert err.max() < 0.02


def test_views_without_markers_or_with_too_few_say_why():
    rng = np.random.default_rng(4)
    cam = sim.platform("thesis", seed=0).camera_models["side"]
    far = _placement(cam, (0.0, 0.0, 0.1), (1100, 900))  # markers outside the box
    det = detect(_image(cam, far, rng), SLIDE, roi=BOX)
    assert not det.found
    assert "none of the slide's 3 hollow marker dots is in view" in det.reason
    # only the first marker in the box, the two others outside: three ways fit
    edge = _placement(cam, (0.0, 0.0, 0.0), (770, 275))
    det = detect(_image(cam, edge, rng), SLIDE, roi=BOX)
    assert not det.found
    assert "hollow marker dots in view fit the spec's markers in" in det.reason


def test_a_marker_spec_the_slide_contradicts_is_refused_and_nothing_is_written(tmp_path):
    from microcal.workflows.stereo import stereo_calibrate_images

    rng = np.random.default_rng(5)
    cam = sim.platform("thesis", seed=0).camera_models["side"]
    for i, (rvec, at) in enumerate(POSES[:3]):
        image = _image(cam, _placement(cam, rvec, at), rng)
        for name in ("a", "b"):
            cv2.imwrite(str(tmp_path / f"{name}_{i}.png"), image[BOX[1] : BOX[3], BOX[0] : BOX[2]])
    out = tmp_path / "cameras.json"
    wrong = "dotgrid:60x45:500:300:markers=28,23/34,23/28,19"  # 6 and 4 steps, not 5 and 3
    with pytest.raises(InputError) as err:
        stereo_calibrate_images(wrong, [f"a={tmp_path}/a_*.png", f"b={tmp_path}/b_*.png"], out)
    message = str(err.value)
    assert "\n" not in message
    assert "do not match the spec's markers" in message
    assert "markers=28,23/33,23/28,20 would fit" in message
    assert not out.exists()


def test_the_simulator_renders_an_overfilling_slide_on_the_thesis_and_telecentric_presets():
    for preset in ("thesis", "telecentric"):
        plat = sim.platform(preset, seed=1, overrides={"calibration_target": OVERFILLING_SLIDE})
        plat.scene.show_board = False
        cam = plat.cameras["side"]
        focus = cam.formation.focus_depth_um  # in focus: the holes are a few px across
        plat.scene.fixed = _placement(cam.model, (0.0, 0.0, 0.3), (550, 450), depth_um=focus)
        image = cam.grab()
        det = detect(image, SLIDE, roi=BOX)
        assert det.found, det.reason
        truth = cam.last_truth.features_px[0]
        err = np.linalg.norm(det.q_px - truth[det.ids], axis=1)
        # Metric: RMS distance to the true projection, px (one frame with the simulated
        # camera's own noise, vignetting and blur)
        assert np.sqrt(np.mean(err**2)) < 0.1, preset


def test_slide_spec_round_trips_and_is_checked():
    assert SLIDE.markers == ((28, 23), (33, 23), (28, 20))
    assert parse_target(SLIDE.spec) == SLIDE
    assert ambiguous_turns(SLIDE) == [0]
    assert SLIDE.partial
    assert not parse_target("dotgrid:40x30:250").partial
    for spec, words in [
        ("dotgrid:10x8:3500:markers=2,2/8,2", "3 or more marker dots"),
        ("dotgrid:10x8:3500:markers=2,2/4,2/2,4/4,4", "look the same turned by 90 degrees"),
        ("dotgrid:10x8:3500:markers=2,2/12,2/2,5", "outside the 10x8 grid"),
        ("dotgrid:10x8:3500:markers=2,2/2,2/2,5", "given twice"),
        ("dotgrid:10x8:3500:markers=2;2", "expected markers=C,R/C,R"),
        ("chessboard:9x6:400:markers=2,2/7,2/2,5", "an L of neighbouring squares"),
    ]:
        with pytest.raises(InputError, match=words):
            parse_target(spec)


def test_the_bias_of_a_tilted_dot_is_its_pictures_centroid_less_its_centres_picture():
    # A homography that shrinks the image towards +x: the disc's far side is drawn smaller,
    # so its picture's centroid lies towards the near (-x) side ... and a ring's more so.
    H = np.array([[100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.2, 0.0, 1.0]])
    solid = disc_image_bias_px(H, np.zeros(2), 0.25)
    ring = disc_image_bias_px(H, np.zeros(2), 0.25, 0.1)
    assert solid[0] < -0.05
    assert abs(solid[1]) < 1e-9
    assert ring[0] < solid[0]
    # an affine map has none
    A = np.array([[80.0, 10.0, 5.0], [3.0, 90.0, 7.0], [0.0, 0.0, 1.0]])
    assert np.allclose(disc_image_bias_px(A, np.array([1.0, 2.0]), 0.3), 0.0, atol=1e-9)


@pytest.mark.parametrize(("preset", "kind"), [("thesis", "pinhole"), ("telecentric", "affine")])
def test_a_slide_moved_by_known_steps_calibrates_a_camera(preset, kind):
    """Method (a) with a slide of which only a part is in view: the numbering gives every
    visible dot its place on the slide, so the steps place it in {V}."""
    from microcal.vision.known_displacements import calibrate_known_displacements

    rng = np.random.default_rng(6)
    cam = sim.platform(preset, seed=0).camera_models["side"]
    base = _placement(cam, (0.25, -0.15, 0.3), (550, 450))
    steps = np.array([[0.0, 0.0, z] for z in (0.0, 1500.0, 3000.0)])
    dets = []
    for d in steps:
        moved = Placement(SLIDE, base.R, base.t_um + base.R @ d)
        dets.append(detect(_image(cam, moved, rng), SLIDE, roi=BOX))
        assert dets[-1].found, dets[-1].reason
    cal = calibrate_known_displacements({"side": dets}, {"side": ["a", "b", "c"]}, SLIDE, steps,
                                        {"side": cam.image_size_px}, camera_model="auto")  # fmt: skip
    model = cal.cameras["side"].model
    assert model.kind == kind
    seen = dets[0].ids
    err = np.linalg.norm(model.project(SLIDE.points_um()[seen]) - _truth(cam, base)[seen], axis=1)
    # Metric: the calibrated camera against the true one over the dots seen, px RMS
    assert np.sqrt(np.mean(err**2)) < 0.05


#: Known steps of the slide in its own frame, µm: across its plane (up to 6 pitches, so each
#: view sees a different part) and up (the points must not all lie in one plane).
CROSSING_STEPS_UM = np.array([
    [0.0, 0.0, 0.0], [-3000.0, 0.0, 0.0], [1500.0, 1500.0, 1000.0], [-1500.0, -1500.0, 2000.0],
    [0.0, 1500.0, 3000.0], [-3000.0, -1000.0, 1500.0],
])  # fmt: skip


@pytest.mark.slow
def test_a_slide_moved_by_known_steps_across_its_plane_calibrates_from_different_parts(tmp_path):
    """Method (a) end to end (``calibrate-cameras --known-displacements``) where each view
    sees a different part of the slide: the rendered box written as files (a camera whose
    image is the box), every view numbered from its markers and placed in {V} by its step."""
    from microcal.workflows.stereo import stereo_calibrate_images

    cam = sim.platform("thesis", seed=0).camera_models["side"]
    base = _placement(cam, (0.25, -0.15, 0.3), (600, 480))
    seen = []
    for name, seed in (("a", 7), ("b", 8)):
        rng = np.random.default_rng(seed)
        for i, d in enumerate(CROSSING_STEPS_UM):
            moved = Placement(SLIDE, base.R, base.t_um + base.R @ d)
            image = _image(cam, moved, rng)[BOX[1] : BOX[3], BOX[0] : BOX[2]]
            cv2.imwrite(str(tmp_path / f"{name}_{i}.png"), image)
            if name == "a":
                seen.append(set(detect(image, SLIDE).ids.tolist()))
    # each view sees dots no other view sees
    for i, ids in enumerate(seen):
        assert ids - set().union(*(s for k, s in enumerate(seen) if k != i)), i
    steps = tmp_path / "steps.csv"
    steps.write_text("dx_um,dy_um,dz_um\n" + "".join(f"{x},{y},{z}\n" for x, y, z in
                                                      CROSSING_STEPS_UM))  # fmt: skip
    out = tmp_path / "cameras.json"
    images = [f"a={tmp_path}/a_*.png", f"b={tmp_path}/b_*.png"]
    wrong = "dotgrid:60x45:500:300:markers=28,23/34,23/28,19"  # 6 and 4 steps, not 5 and 3
    with pytest.raises(InputError) as refused:  # a spec the slide contradicts: nothing written
        stereo_calibrate_images(wrong, images, out, known_displacements=steps)
    assert "\n" not in str(refused.value)
    assert "markers=28,23/33,23/28,20 would fit" in str(refused.value)
    assert not out.exists()
    cal = stereo_calibrate_images(OVERFILLING_SLIDE, [f"a={tmp_path}/a_*.png",
                                  f"b={tmp_path}/b_*.png"], out, known_displacements=steps,
                                  camera_model="pinhole")  # fmt: skip
    assert out.exists()
    every = np.array(sorted(set().union(*seen)))
    for name in ("a", "b"):
        c = cal.cameras[name]
        assert c.views_used == len(CROSSING_STEPS_UM)
        # Metric: RMS reprojection error of the dots found, px (0.7 px blur, 1 DN noise)
        assert c.rms_px < 0.05
        truth = _truth(cam, base)[every] - BOX[:2]  # the box's pixels
        err = np.linalg.norm(c.model.project(SLIDE.points_um()[every]) - truth, axis=1)
        # Metric: the calibrated camera against the true one over every dot seen, px RMS
        assert np.sqrt(np.mean(err**2)) < 0.05
