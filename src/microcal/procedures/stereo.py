"""Stereo calibration from a set of images per camera (the procedure behind the command).

Frames of one view (the pages of a multi-page file) are averaged before detection: with a
still target this lowers the noise as the square root of their number. A slide numbered from
marker dots is refused when its hollow dots contradict the spec's markers; calibrated from
free poses, its dots' positions are measured along with the cameras
(:mod:`~microcal.vision.slide_geometry`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import FormatError, InputError
from ..vision.detect import Detection, detect, to_gray
from ..vision.lens_models import lens_model as named_lens_model
from ..vision.stereo_calibration import (
    StereoCalibration,
    calibrate_known_displacements,
    calibrate_unknown_poses,
)
from ..vision.targets import Target

__all__ = ["calibrate_views"]

Loader = Callable[[str, int], Sequence[NDArray[np.generic]]]


def calibrate_views(
    names: Mapping[str, Sequence[str]],
    load: Loader,
    target: Target,
    *,
    displacements_um: FloatArray | None = None,
    reference_view: int = 0,
    lens_model: str = "auto",
    camera_model: str = "pinhole",
    progress: Callable[[int, int], None] | None = None,
) -> StereoCalibration:
    """Detect the target in every view of every camera and calibrate.

    Parameters
    ----------
    names : dict camera -> list of view names (file names), one per view, same count each.
    load : callable (camera, view index) -> frames of that view
        Raise FormatError for a file that cannot be read: the view is rejected, not fatal.
    target : Target
    displacements_um : (V, 3) float, optional
        Known displacements: method (a). Without them: method (b).
    reference_view : int
        For method (b): the view whose target frame becomes {V}.
    lens_model : str
        For method (b): ``"auto"`` (chosen per camera by held-out error) or a model's name
        (:data:`~microcal.vision.lens_models.LENS_MODELS`).
    camera_model : str
        For method (a): ``"pinhole"``, ``"affine"`` or ``"auto"`` (see
        :func:`~microcal.vision.known_displacements.calibrate_known_displacements`); method
        (b) calibrates pinhole cameras only.
    """
    if displacements_um is None and camera_model == "affine":
        raise InputError(
            "--camera-model affine: an affine (telecentric) camera is calibrated from known "
            "displacements (--known-displacements, method a); tilted views calibrate pinhole "
            "cameras"
        )
    if lens_model != "auto":
        named_lens_model(lens_model)  # an unknown name fails before any image is read
        if displacements_um is not None:
            raise InputError(
                "--lens-model: the known-displacement method (a) fixes its own lens model; "
                "leave --lens-model out or calibrate from tilted views (method b)"
            )
    n_views = min((len(v) for v in names.values()), default=0)
    if displacements_um is None and n_views and not 0 <= reference_view < n_views:
        raise InputError(
            f"--reference-view {reference_view}: expected a view from 0 to {n_views - 1} "
            f"(the {n_views} views given)"
        )
    detections: dict[str, list[Detection]] = {}
    sizes: dict[str, tuple[int, int]] = {}
    total = sum(len(v) for v in names.values())
    done = 0
    for cam, views in names.items():
        detections[cam] = []
        for i in range(len(views)):
            try:
                frames = load(cam, i)
                image = np.mean([to_gray(f) for f in frames], axis=0)
                sizes.setdefault(cam, (image.shape[1], image.shape[0]))
                if (image.shape[1], image.shape[0]) != sizes[cam]:
                    w, h = sizes[cam]
                    det = Detection.none(
                        f"image is {image.shape[1]}x{image.shape[0]} px, the others {w}x{h}"
                    )
                else:
                    det = detect(image, target)
            except FormatError as exc:
                det = Detection.none(str(exc))
            detections[cam].append(det)
            done += 1
            if progress:
                progress(done, total)
        if cam not in sizes:
            raise FormatError(f"camera {cam}: none of its images could be read")
    if target.markers:
        from ..vision.marker_grid import check_marker_spec

        check_marker_spec(target, [d for ds in detections.values() for d in ds])
    if displacements_um is not None:
        return calibrate_known_displacements(
            detections, names, target, displacements_um, sizes, camera_model=camera_model
        )
    note = ""
    if target.markers:  # a slide's dots are measured along with the cameras
        from ..vision.slide_geometry import measure_slide

        target, note = measure_slide(target, detections, sizes)
    cal = calibrate_unknown_poses(
        detections, names, target, sizes, reference_view=reference_view, lens_model=lens_model
    )
    if note:
        cal.notes.append(note)
    return cal
