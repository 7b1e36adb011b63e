"""Target detection: every kind, any image format, and the cases without a target."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal import sim
from microcal.errors import InputError
from microcal.sim.render import Placement
from microcal.vision.detect import detect
from microcal.vision.roi import frames_from_region
from microcal.vision.targets import parse_target


def view(spec: str, R=None, t=(2000.0, 2000.0, 1500.0), frames=4, seed=0):
    """Averaged top-camera frames of a target placed in the thesis preset, and the truth."""
    plat = sim.platform("thesis", seed=seed)
    plat.scene.show_board = False
    target = parse_target(spec)
    R = np.eye(3) if R is None else np.asarray(R, float)
    plat.scene.fixed = Placement(target, R, np.asarray(t, float))
    cam = plat.cameras["top"]
    image = np.mean([cam.grab().astype(np.float32) for _ in range(frames)], axis=0)
    return target, image, cam.last_truth.features_px[0]


@pytest.mark.parametrize(
    "spec", ["chessboard:9x7:500", "dotgrid:40x30:250", "charuco:6x5:1500", "charuco:6x5:1500:id40"]
)
def test_each_kind_is_found_where_it_is(spec):
    target, image, truth = view(spec)
    det = detect(image, target)
    assert det.found, det.reason
    assert len(det.ids) >= (10 if target.kind == "charuco" else target.cols * target.rows)
    err = np.linalg.norm(det.q_px - truth[det.ids], axis=1)
    # Metric: RMS and worst distance to the true projection, px (4 averaged noisy frames).
    assert np.sqrt(np.mean(err**2)) < 0.2
    assert err.max() < 0.6
    assert det.quality_px < 0.3


def test_rotated_dot_grid_keeps_its_ids():
    R, _ = cv2.Rodrigues(np.deg2rad([0.0, 0.0, 8.0]))
    target, image, truth = view("dotgrid:40x30:250", R=R)
    det = detect(image, target)
    assert det.found, det.reason
    assert np.linalg.norm(det.q_px - truth[det.ids], axis=1).max() < 0.6


def test_chessboard_order_is_canonical_when_the_board_is_upside_down():
    R, _ = cv2.Rodrigues(np.deg2rad([0.0, 0.0, 180.0]))
    target, image, _ = view("chessboard:9x7:500", R=R, t=(6000.0, 5000.0, 1500.0))
    det = detect(image, target)
    assert det.found
    # The first row runs towards +x in the image, whatever the board's orientation.
    assert det.q_px[target.cols - 1, 0] > det.q_px[0, 0]


def test_formats_and_regions():
    target, image, truth = view("chessboard:9x7:500")
    for variant in (image.astype(np.uint8), (image * 257).astype(np.uint16),
                    cv2.cvtColor(image.astype(np.uint8), cv2.COLOR_GRAY2BGR)):  # fmt: skip
        det = detect(variant, target)
        assert det.found
        assert np.linalg.norm(det.q_px - truth, axis=1).max() < 0.6
    lo, hi = truth.min(axis=0) - 60, truth.max(axis=0) + 60
    det = detect(image, target, roi=(int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])))
    assert det.found
    assert np.linalg.norm(det.q_px - truth, axis=1).max() < 0.6  # whole-image coordinates


def test_no_target_is_a_result_with_a_reason():
    target = parse_target("chessboard:4x3:400")
    blank = np.random.default_rng(0).integers(60, 90, (400, 500)).astype(np.uint8)
    det = detect(blank, target)
    assert not det.found
    assert det.reason == "no 4x3 chessboard found"
    det = detect(blank, parse_target("dotgrid:10x10:250"))
    assert not det.found
    assert "expected 100" in det.reason
    assert not detect(blank, target, roi=(900, 900, 1000, 1000)).found


@pytest.mark.parametrize("turn_deg", [0.0, 90.0, 180.0, 270.0])
def test_odd_by_even_chessboard_is_numbered_from_its_own_origin_however_turned(turn_deg):
    # 5 x 4 inner corners: the squares' colours tell every turn apart.
    R, _ = cv2.Rodrigues(np.deg2rad([0.0, 0.0, turn_deg]))
    target, image, truth = view("chessboard:5x4:500", R=R, t=(5000.0, 4500.0, 1500.0))
    det = detect(image, target)
    assert det.found, det.reason
    # Metric: worst distance of each numbered corner to the true projection of that corner.
    assert np.linalg.norm(det.q_px - truth[det.ids], axis=1).max() < 0.6


def test_a_lattice_that_skips_a_row_is_not_taken_for_the_board():
    # A finder may return a lattice whose rows are two squares apart, the last one in the
    # board's margin: its "squares" straddle real ones, so light and dark levels overlap.
    from microcal.vision.detect import _not_a_chessboard
    from microcal.vision.detect import to_gray as gray_of

    _, image, truth = view("chessboard:5x4:500", t=(5000.0, 4500.0, 1500.0))
    gray = gray_of(image)
    assert _not_a_chessboard(gray, truth, 5, 4) == ""
    grid = truth.reshape(4, 5, 2)
    step = grid[1] - grid[0]
    skipped = np.concatenate([grid[0], grid[2], grid[3], grid[3] + step]).reshape(-1, 2)
    assert "do not bound alternating dark and light squares" in _not_a_chessboard(
        gray, skipped, 5, 4
    )


def test_an_image_with_nan_pixels_is_refused_with_the_reason():
    _, image, _ = view("chessboard:5x4:500", t=(5000.0, 4500.0, 1500.0))
    image = image.astype(np.float32)
    image[10, 20] = np.nan
    det = detect(image, parse_target("chessboard:5x4:500"))
    assert not det.found
    assert det.reason == "the image has 1 NaN or infinite pixels"


@pytest.mark.parametrize("spec", ["chessboard:3x2:400", "chessboard:2x2:400", "charuco:2x4:400"])
def test_boards_too_small_for_the_finders_are_refused_at_the_spec(spec):
    from microcal.errors import InputError

    with pytest.raises(InputError, match=r"expected at least 3x3"):
        parse_target(spec)


@pytest.mark.slow
def test_a_spec_smaller_than_the_board_is_never_found():
    """A 3x3 spec on the thesis's 4x3 board: the finders find parts of it (or lattices in the
    noise); each is refused with the reason, while the right spec finds every view."""
    from microcal import sim
    from microcal.kinematics.designs import make_design

    plat = sim.platform("thesis", seed=5)
    d = make_design("random", 6, [0, 0, 0], [8000, 8000, 4800], 5)
    small, whole = parse_target("chessboard:3x3:400"), parse_target("chessboard:4x3:400")
    reasons = []
    for k in range(len(d)):
        plat.manipulator.move_to_um(d[k])
        plat.clock.sleep(5.0)
        for cam in plat.cameras.values():
            image = cam.grab()
            assert detect(image, whole).found
            wrong = detect(image, small)
            assert not wrong.found, k
            reasons.append(wrong.reason)
    assert any("goes on past its" in r for r in reasons)


def test_charuco_boards_with_their_own_markers_are_told_apart_in_one_image():
    """Two devices' boards in view at once: each spec finds its own board, and only it."""
    a, b = parse_target("charuco:5x4:400"), parse_target("charuco:5x4:400:id10")
    assert b.spec == "charuco:5x4:400:280:id10"
    assert parse_target(b.spec) == b
    assert a.told_apart_from(b)
    assert not a.told_apart_from(parse_target("charuco:5x4:400:id9"))  # marker 9 is in both
    assert not parse_target("chessboard:4x3:400").told_apart_from(a)
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    canvas = np.full((600, 1300), 255, np.uint8)
    for target, x in ((a, 50), (b, 700)):
        board = cv2.aruco.CharucoBoard((5, 4), 400.0, 280.0, dictionary, target.marker_ids())
        canvas[100:500, x : x + 500] = board.generateImage((500, 400), marginSize=40)
    canvas = cv2.GaussianBlur(canvas, (5, 5), 1.0)
    for target, (low, high) in ((a, (50, 550)), (b, (700, 1200))):
        det = detect(canvas, target)
        assert det.found
        assert len(det.ids) == 12
        assert np.all((det.q_px[:, 0] > low) & (det.q_px[:, 0] < high))


@pytest.mark.parametrize(
    ("spec", "message"),
    [("chessboard:4x3:400:id3", "only a charuco board numbers its markers"),
     ("charuco:5x4:400:id245", "its 10 markers from 245 pass the dictionary's 250")],
)  # fmt: skip
def test_marker_numbers_are_checked(spec, message):
    with pytest.raises(InputError, match=message):
        parse_target(spec)


def test_a_region_of_interest_is_cut_out_before_anything_else():
    """Only the box is converted and checked: the same corners as in the cut-out image, and a
    bad pixel outside the box does not matter (inside, it is named)."""
    target, image, _ = view("chessboard:9x7:500")
    full = detect(image, target)
    q = full.q_px
    roi = (int(q[:, 0].min()) - 40, int(q[:, 1].min()) - 40,
           int(q[:, 0].max()) + 40, int(q[:, 1].max()) + 40)  # fmt: skip
    boxed = detect(image, target, roi=roi)
    cut = detect(image[roi[1] : roi[3], roi[0] : roi[2]], target)
    np.testing.assert_array_equal(boxed.q_px, cut.q_px + (roi[0], roi[1]))
    bad = image.astype(np.float32)
    bad[0, 0] = np.nan
    np.testing.assert_array_equal(detect(bad, target, roi=roi).q_px, boxed.q_px)
    bad[roi[1] + 1, roi[0] + 1] = np.inf
    assert detect(bad, target, roi=roi).reason == (
        "the region of interest has 1 NaN or infinite pixels"
    )


def test_the_same_image_gives_the_same_corners_whatever_came_before():
    """The sector-based finder draws from OpenCV's random generator; here it judges the
    half-resolution search of a stored region (its corners refused there, the board is
    then found at full resolution around them). Seeded per call, a detection does not
    depend on the detections before it (nor on the process: cameras are measured in
    parallel)."""
    plat = sim.platform("thesis", seed=0)
    board = plat.scene.board
    frame = plat.cameras["side"].grab()
    q = detect(frame, board).q_px
    square = float(np.median(np.linalg.norm(np.diff(q, axis=0), axis=1)))
    lo = np.floor(q.min(axis=0) - 3 * square).astype(int)
    hi = np.ceil(q.max(axis=0) + 3 * square).astype(int)
    region = frame[lo[1] : hi[1], lo[0] : hi[0]]
    stored = frames_from_region([region], lo, (frame.shape[1], frame.shape[0]))[0]
    first = detect(stored, board)
    assert first.found, first.reason
    for _ in range(3):
        detect(stored, board)
        detect(plat.cameras["top"].grab(), board)
    np.testing.assert_array_equal(detect(stored, board).q_px, first.q_px)


@pytest.mark.parametrize("shift_px", [(0.0, 0.0), (0.6, -0.4), (-1.5, 1.2)])
def test_a_board_followed_from_the_frame_before_gives_the_corners_a_search_gives(shift_px):
    """Corners of the frame before, off by a fraction of a square: refined from there to where
    a full search puts them (within the refinement's own convergence), numbered alike."""
    target, image, truth = view("chessboard:9x7:500", t=(2000.0, 2000.0, 1500.0))
    searched = detect(image, target)
    followed = detect(image, target, previous_px=searched.q_px + np.asarray(shift_px))
    assert followed.found
    assert followed.method == "followed"
    np.testing.assert_array_equal(followed.ids, searched.ids)
    assert np.abs(followed.q_px - searched.q_px).max() < 0.03
    assert np.sqrt(np.mean(np.sum((followed.q_px - truth) ** 2, axis=1))) < 0.1


@pytest.mark.parametrize(
    "why",
    ["moved half a square", "moved a square", "moved two squares", "numbered one corner off",
     "wrong count", "half the board hidden"],
)  # fmt: skip
def test_corners_that_no_longer_fit_are_searched_for(why):
    target, image, _ = view("chessboard:9x7:500")
    searched = detect(image, target)
    q = searched.q_px.copy()
    square = float(np.median(np.linalg.norm(np.diff(q[:9], axis=0), axis=1)))
    if why.startswith("moved"):
        squares = {"half a square": 0.5, "a square": 1.0, "two squares": 2.0}[why[6:]]
        previous = q + (squares * square, 0.0)
    elif why == "numbered one corner off":
        previous = np.roll(q, 1, axis=0)
    elif why == "wrong count":
        previous = q[:-1]
    else:
        previous = q
        image = image.copy()
        lo = q.min(axis=0).astype(int)
        image[lo[1] - 20 : int(q[:, 1].mean()), lo[0] - 20 : int(q[:, 0].max()) + 20] = 0.0
    followed = detect(image, target, previous_px=previous)
    assert followed.method != "followed"
    if why != "half the board hidden":
        np.testing.assert_allclose(followed.q_px, searched.q_px, atol=1e-9)
    else:
        assert not followed.found
