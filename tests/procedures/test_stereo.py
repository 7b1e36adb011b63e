"""Camera calibration from views (procedures.stereo): the lens model is checked before any
image is loaded, and real photographs, the BoofCV Bumblebee2 chessboard stereo set, calibrate.

The images are not in the repository: they are read from ``../shared/data`` beside it (see
that folder's PROVENANCE.md for their source, licence and the reference results), and the
tests skip with the reason when it is absent.

Reference (PROVENANCE.md): OpenCV 5.0 with default flags, 11 x 11 sub-pixel windows: mono RMS
0.0873 / 0.0840 px, stereo RMS 0.0953 px with the right corner list of one pair reversed by
hand, |T| 120.55 mm; BoofCV's own result |T| 120.05 mm, 0.48 deg between the cameras;
the nominal baseline is 120 mm.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.errors import InputError
from microcal.procedures.stereo import calibrate_views
from microcal.vision.detect import detect
from microcal.vision.targets import parse_target
from support.opencv_best_window import OpenCVReference

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "boofcv_bumblebee2_chess"
TARGET = "chessboard:6x4:30000"

pytestmark = pytest.mark.skipif(
    not (DATA / "left01.jpg").is_file(),
    reason=f"the real stereo photographs are not here ({DATA} is absent)",
)


def _files() -> dict[str, list[Path]]:
    return {side: sorted(DATA.glob(f"{side}*.jpg")) for side in ("left", "right")}


@pytest.fixture(scope="module")
def calibration():
    files = _files()
    return calibrate_views(
        {cam: [f.name for f in fs] for cam, fs in files.items()},
        lambda cam, i: [cv2.imread(str(files[cam][i]))],
        parse_target(TARGET),
    )


@pytest.fixture(scope="module")
def opencv():
    """OpenCV's figures on the same photographs at each cornerSubPix half-window 2..8."""
    return OpenCVReference(_files(), (6, 4))


#: BoofCV's baseline in its stereo.yaml (PROVENANCE.md: |T| derived from rightToLeft), µm.
BOOFCV_BASELINE_UM = 120_051.0


def test_mono_and_stereo_rms_at_most_opencvs_best_window(calibration, opencv):
    # Metric: RMS reprojection error, px; OpenCV's at its best half-window for this set,
    # computed here (mono: calibrateCamera, default model; stereo: stereoCalibrate with those
    # intrinsics fixed).
    for cam in ("left", "right"):
        best, _ = opencv.best_mono_rms_px(cam)
        assert calibration.cameras[cam].rms_px <= best, cam
    best, _ = opencv.best_stereo_rms_px("left", "right")
    assert calibration.rms_px <= best


def test_the_default_baseline_is_within_0_3_percent_of_the_makers(calibration):
    # The default settings (the lens model chosen per camera: radial2 left,
    # radial2-tangential right, then the joint refinement of intrinsics and poses).
    # Metric: |baseline - BoofCV's| / BoofCV's (+0.12 % measured; +0.32 % with each camera's
    # intrinsics fixed from its own calibration).
    assert abs(calibration.baseline_um - BOOFCV_BASELINE_UM) / BOOFCV_BASELINE_UM <= 0.003


def test_the_baseline_of_the_makers_lens_model_is_within_0_3_percent_of_theirs():
    # Like for like: BoofCV's stereo.yaml was calibrated with k1, k2 only (info.txt).
    # Metric: |baseline - BoofCV's| / BoofCV's.
    files = _files()
    cal = calibrate_views({cam: [f.name for f in fs] for cam, fs in files.items()},
                          lambda cam, i: [cv2.imread(str(files[cam][i]))], parse_target(TARGET),
                          lens_model="radial2")  # fmt: skip
    assert abs(cal.baseline_um - BOOFCV_BASELINE_UM) / BOOFCV_BASELINE_UM <= 0.003


def test_consistency_without_a_reference(calibration):
    figures = calibration.consistency
    # Metric: the triangulated 30 mm squares along both axes, relative, mean and worst
    # ninth of the left image.
    for axis in ("x", "y"):
        assert abs(figures["pitch"][axis]["error"]) <= 0.002
        assert abs(figures["pitch"][axis]["worst_cell_error"]) <= 0.005
    # Metric: held-out views' RMS over the views fitted (folds of the 11 views).
    for f in figures["held_out"]["cameras"].values():
        assert f["ratio"] <= 1.2
    assert figures["held_out"]["joint"]["ratio"] <= 1.3


def test_mono_rms_is_within_3_percent_of_opencvs_default(calibration):
    # Metric: RMS reprojection error over all corners of all views, px, against the
    # reference's OpenCV figures (0.0873 / 0.0840) plus 3 %.
    assert calibration.cameras["left"].rms_px <= 0.090
    assert calibration.cameras["right"].rms_px <= 0.087
    for c in calibration.cameras.values():
        assert c.views_used == 11
        assert c.lens_model["name"] != "radial1"  # a wide-angle lens needs more than k1


def test_stereo_geometry_matches_the_rig(calibration):
    assert calibration.rms_px <= 0.10  # px, stereo RMS over both cameras
    # Metric: |baseline - 120 mm| / 120 mm, and the rotation angle between the cameras.
    assert abs(calibration.baseline_um - 120_000.0) / 120_000.0 <= 0.005
    assert calibration.angle_deg < 1.0
    assert calibration.views_rejected == []


def test_the_pairs_numbered_from_opposite_ends_are_turned_and_reported(calibration):
    turned = calibration.turned_views
    # The 6 x 4 board looks the same turned: microcal's detector numbers these four right
    # images from the other end of the board than the left ones (docs/vision.md).
    assert {t["image"] for t in turned} == {"right01.jpg", "right02.jpg", "right04.jpg",
                                            "right08.jpg"}  # fmt: skip
    assert all(t["turn_deg"] == 180 and t["camera"] == "right" for t in turned)
    # Each pair's corners, once turned as reported, correspond between the images: after
    # the mean disparity is taken out the same corner lies close in both, much closer than
    # with the other numbering.
    left = _files()["left"]
    right = _files()["right"]
    target = parse_target(TARGET)
    names = {t["image"] for t in turned}
    for lf, rf in zip(left, right, strict=True):
        dl = detect(cv2.imread(str(lf), cv2.IMREAD_GRAYSCALE), target)
        dr = detect(cv2.imread(str(rf), cv2.IMREAD_GRAYSCALE), target)
        chosen, other = (dr.q_px[::-1], dr.q_px) if rf.name in names else (dr.q_px, dr.q_px[::-1])

        def spread(q, ql=dl.q_px):
            d = q - ql
            return float(np.sqrt(np.mean(np.sum((d - d.mean(axis=0)) ** 2, axis=1))))

        # Metric: RMS of the corner-to-corner offsets about their mean, px.
        assert spread(chosen) < 0.25 * spread(other), rf.name


def test_corners_agree_with_opencvs_reference_detection():
    # Metric: per image, RMS distance between microcal's corners and OpenCV's classic
    # detector refined by cornerSubPix (11 x 11 window, as the reference), corner for corner
    # in OpenCV's numbering or its reverse (the board looks the same turned); both estimate
    # the same corners.
    target = parse_target(TARGET)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.001)
    for f in _files()["left"] + _files()["right"]:
        gray = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(gray, (6, 4))
        assert ok, f.name
        ref = cv2.cornerSubPix(gray, c, (5, 5), (-1, -1), crit).reshape(-1, 2)
        det = detect(gray, target)
        assert det.found, f.name
        rms = min(float(np.sqrt(np.mean(np.sum((det.q_px - r) ** 2, axis=1))))
                  for r in (ref, ref[::-1]))  # fmt: skip
        assert rms < 0.15, f.name


def test_diagnostics_say_what_limits_this_set(calibration):
    for c in calibration.cameras.values():
        d = c.diagnostics
        assert d is not None
        assert d.verdict
        # The set has no view reaching some image corners: the verdict must say so.
        empty = [k for k in ("top-left", "top-right", "bottom-left", "bottom-right")
                 if d.coverage[k] == 0]  # fmt: skip
        assert empty
        assert any("near the corners" in v for v in d.verdict)
        # Metric: projection uncertainty at the image centre vs the worst corner, px.
        u = d.uncertainty_px
        assert u["centre"] < 0.2 < u["corners"]


def test_stereo_calibrate_command_on_the_photographs(tmp_path):

    out = tmp_path / "cameras.json"
    result = CliRunner().invoke(
        app,
        ["stereo-calibrate", "--target", TARGET, "--images", f"left={DATA}/left*.jpg",
         "--images", f"right={DATA}/right*.jpg", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "turned the corner numbering of camera right" in result.output
    assert "lens model of left" in result.output
    assert "target pitch triangulated along y" in result.output
    data = json.loads(out.read_text())
    left = data["cameras"]["left"]
    assert left["lens_model"]["candidates"][0]["name"] == "radial1"
    assert left["diagnostics"]["verdict"]
    assert data["stereo"]["turned_views"]
    assert abs(data["stereo"]["baseline_um"] - 120_000.0) <= 600.0
    assert set(data["stereo"]["consistency"]) == {"held_out", "pitch"}


#: The board named to the procedure in the refusals (no image is read).
REFUSED_TARGET = "chessboard:7x4:25000"


class _Loader:
    """A view loader that records what it was asked for."""

    def __init__(self):
        self.calls = []

    def __call__(self, cam, i):
        self.calls.append((cam, i))
        raise AssertionError("no image should be read")


NAMES_BY_CAMERA = {"left": ["l0.png", "l1.png"], "right": ["r0.png", "r1.png"]}


def test_procedure_checks_the_lens_model_before_loading():
    load = _Loader()
    with pytest.raises(InputError, match="lens model 'nope'"):
        calibrate_views(NAMES_BY_CAMERA, load, parse_target(REFUSED_TARGET), lens_model="nope")
    assert load.calls == []


def test_procedure_refuses_a_lens_model_with_known_displacements_before_loading():
    load = _Loader()
    with pytest.raises(InputError, match="--lens-model"):
        calibrate_views(NAMES_BY_CAMERA, load, parse_target(REFUSED_TARGET),
                        displacements_um=np.zeros((2, 3)), lens_model="radial1")  # fmt: skip
    assert load.calls == []
