"""Calibrating a one-camera microscope against its X-Y stage and focus drive.

The stage (or a manipulator carrying the slide) moves a calibration slide by known steps
across the field, the focus drive steps through the depth of field, a frame is grabbed at
each position and the slide's features are found in it; :func:`~microcal.vision.stage_affine.
fit_stage_affine` then gives the image-to-stage affine map (Micro-Manager's convention), the
pixel size, the distortion and the focus axis's angle, each with its uncertainty. The stage
and the focus are returned to where they started.

Works on callables (``move_stage``, ``move_focus``, ``grab``), so the same procedure serves
a hardware rig, the simulator (:class:`~microcal.sim.stage_slide.StageSlideScope`) and the
tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, check_number
from ..errors import InputError
from ..vision.detect import detect, to_gray
from ..vision.focal_surface import FieldCurvature, fit_field_curvature, region_sharpness
from ..vision.stage_affine import (
    ScopeCalibration,
    SlideView,
    fit_stage_affine,
    follow_numbering,
)
from ..vision.targets import Target

__all__ = ["ScopePlan", "ScopeRun", "calibrate_scope", "scope_plan"]


@dataclass(frozen=True)
class ScopePlan:
    """Where the views are taken, relative to the stage's and the focus's start.

    Attributes
    ----------
    positions : (V, 3) float
        Stage x, y and focus offsets of each view, µm.
    """

    positions: FloatArray

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3 or not np.all(np.isfinite(pos)):
            raise InputError(f"positions: expected (V, 3) finite µm, got shape {pos.shape}")
        object.__setattr__(self, "positions", pos)


def scope_plan(field_um: float, depth_um: float, *, grid: int = 3, focus_steps: int = 5,
               travel: float = 0.2) -> ScopePlan:  # fmt: skip
    """A plan: a ``grid`` x ``grid`` square of stage positions spanning ``±travel`` of the
    field at the start's focus, and ``focus_steps`` focus positions across ``±depth_um`` at
    the grid's centre and at two of its corners (so the focus axis is measured over the field).

    Parameters
    ----------
    field_um : float
        The field's width in the object (image width times the nominal pixel size), µm.
    depth_um : float
        Half the focus range to step through (within which the slide is still found), µm.
    """
    check_number("field_um", field_um, above=0)
    check_number("depth_um", depth_um, above=0)
    if grid < 2 or focus_steps < 2:
        raise InputError("scope plan: expected a grid of 2 or more and 2 focus steps or more")
    span = travel * field_um
    xs = np.linspace(-span, span, grid)
    pos = [(x, y, 0.0) for y in xs for x in xs]
    zs = [z for z in np.linspace(-depth_um, depth_um, focus_steps) if abs(z) > 1e-12]
    for x, y in ((0.0, 0.0), (-span, -span), (span, span)):
        pos += [(x, y, z) for z in zs]
    return ScopePlan(np.array(pos))


@dataclass
class ScopeRun:
    """What :func:`calibrate_scope` did.

    Attributes
    ----------
    calibration : ScopeCalibration
    views : list of SlideView
        The views the slide was found in.
    missed : list of str
        One line per view the slide was not found in (its position and the reason).
    frames : int
        Frames grabbed.
    renumbered : list of str
        One line per view whose marker-based numbering disagreed with the stage's moves and
        that was numbered again from the first fit's prediction.
    curvature : FieldCurvature or None
        The focal surface, when a focus sweep was asked for.
    """

    calibration: ScopeCalibration
    views: list[SlideView] = field(default_factory=list)
    missed: list[str] = field(default_factory=list)
    frames: int = 0
    renumbered: list[str] = field(default_factory=list)
    curvature: FieldCurvature | None = None


def calibrate_scope(
    move_stage: Callable[[FloatArray], None],
    move_focus: Callable[[float], None],
    grab: Callable[[], NDArray[np.generic]],
    target: Target,
    plan: ScopePlan,
    *,
    start_stage_um: FloatArray | None = None,
    start_focus_um: float = 0.0,
    progress: Callable[[int, int], None] | None = None,
    sweep_um: FloatArray | None = None,
) -> ScopeRun:
    """Move the slide through the plan's views, find it in each frame, fit the calibration.

    The stage is moved only when a view's stage position differs from the last one's, so
    the focus steps at one position share its error of position (the focus axis is then
    measured free of it).

    Parameters
    ----------
    move_stage : callable
        ``move_stage(xy_um)``: move the X-Y stage (or the slide's manipulator) to (2,) µm and
        return once there.
    move_focus : callable
        ``move_focus(z_um)``: move the focus drive and return once there.
    grab : callable
        One frame, (h, w) or (h, w, 3).
    target : Target
        The slide (a dot grid with markers, or a target seen whole in every view).
    plan : ScopePlan
    start_stage_um, start_focus_um :
        The positions the plan's offsets are added to (the stage's and focus's current
        ones), and where they are left at the end.
    progress : callable, optional
        ``progress(done, total)`` after each view.
    sweep_um : (K,) float, optional
        Focus offsets of a sweep at the start's stage position for the field curvature
        (:func:`~microcal.vision.focal_surface.fit_field_curvature`), increasing; none by
        default.

    Returns
    -------
    ScopeRun

    Raises
    ------
    InputError
        The slide was found in too few views (the reasons of the missed ones are named).
    """
    start = np.zeros(2) if start_stage_um is None else np.asarray(start_stage_um, float)
    views: list[SlideView] = []
    missed: list[str] = []
    size: tuple[int, int] | None = None
    total = len(plan.positions)
    here: FloatArray | None = None  # the stage stays where it is for focus steps
    try:
        for k, (dx, dy, dz) in enumerate(plan.positions):
            xy = start + (dx, dy)
            z = start_focus_um + float(dz)
            if here is None or not np.allclose(here, xy, rtol=0, atol=1e-9):
                move_stage(xy)
                here = xy
            move_focus(z)
            image = np.asarray(grab())
            size = (int(image.shape[1]), int(image.shape[0]))
            det = detect(image, target)
            if det.found:
                views.append(SlideView(xy.copy(), z, det.ids, det.q_px))
            elif (ref := _focused_at(views, xy)) is not None and target.kind == "dotgrid":
                # defocused: the markers' holes may be lost, the dots are where they were
                ids, q = follow_numbering(to_gray(image), ref.ids, ref.q_px)
                if len(ids) >= 6:
                    views.append(SlideView(xy.copy(), z, ids, q))
                else:
                    missed.append(f"view {k + 1} (stage {dx:+.1f}, {dy:+.1f} µm, focus "
                                  f"{dz:+.2f} µm): {det.reason}")  # fmt: skip
            else:
                missed.append(f"view {k + 1} (stage {dx:+.1f}, {dy:+.1f} µm, focus {dz:+.2f} "
                              f"µm): {det.reason}")  # fmt: skip
            if progress is not None:
                progress(k + 1, total)
        sharp = []
        if sweep_um is not None:
            if here is None or not np.allclose(here, start, rtol=0, atol=1e-9):
                move_stage(start)
            for dz in np.asarray(sweep_um, dtype=np.float64):
                move_focus(start_focus_um + float(dz))
                sharp.append(region_sharpness(np.asarray(grab())))
    finally:
        move_stage(start)
        move_focus(start_focus_um)
    if size is None:
        raise InputError("scope calibration: the plan has no views")
    try:
        cal = fit_stage_affine(views, target.points_um(), size)
    except InputError as exc:
        why = f" (first miss: {missed[0]})" if missed else ""
        raise InputError(f"{exc}{why}") from None
    renumbered = []
    if cal.rejected:  # numbered again from the stage's prediction, then fitted again
        for k, miss_px in cal.rejected:
            views[k] = _renumbered(views[k], cal, target)
            v = views[k]
            renumbered.append(f"stage {v.stage_um[0]:.1f}, {v.stage_um[1]:.1f} µm, focus "
                              f"{v.focus_um:.2f} µm: numbered again from the stage's "
                              f"prediction (the markers' numbering missed it by {miss_px:.1f} "
                              "px RMS)")  # fmt: skip
        cal = fit_stage_affine(views, target.points_um(), size)
    for k, miss_px in cal.rejected:
        v = views[k]
        missed.append(f"stage {v.stage_um[0]:.1f}, {v.stage_um[1]:.1f} µm, focus "
                      f"{v.focus_um:.2f} µm: left out, its features miss the stage's moves by "
                      f"{miss_px:.1f} px RMS (the slide numbered wrongly)")  # fmt: skip
    kept = [v for k, v in enumerate(views) if k not in {j for j, _ in cal.rejected}]
    curvature = None
    if sweep_um is not None:
        curvature = fit_field_curvature(np.asarray(sweep_um, float), np.array(sharp))
    frames = total + (0 if sweep_um is None else len(sweep_um))
    return ScopeRun(cal, kept, missed, frames, renumbered, curvature)


def _renumbered(view: SlideView, cal: ScopeCalibration, target: Target) -> SlideView:
    """A view's features numbered by the fitted model's prediction at its stage and focus:
    each takes the number of the slide's point predicted within a third of a pitch."""
    predicted = cal.predict_px(target.points_um(), view.stage_um, view.focus_um)
    pitch_px = target.pitch_um / cal.pixel_size_um
    d = np.linalg.norm(view.q_px[:, None, :] - predicted[None, :, :], axis=2)
    nearest = d.argmin(axis=1)
    ok = d[np.arange(len(nearest)), nearest] < pitch_px / 3
    ids, first = np.unique(nearest[ok], return_index=True)
    return SlideView(view.stage_um, view.focus_um, ids.astype(np.intp), view.q_px[ok][first])


def _focused_at(views: list[SlideView], xy: FloatArray) -> SlideView | None:
    """The first view found at stage position ``xy`` (taken before its focus steps)."""
    for v in views:
        if np.allclose(v.stage_um, xy, atol=1e-9):
            return v
    return None


def field_um(image_size_px: tuple[int, int], um_per_px: float) -> float:
    """The field's smaller side in the object, µm."""
    return float(min(image_size_px)) * um_per_px


def depth_for(numerical_aperture: float, wavelength_um: float = 0.55) -> float:
    """Half a focus range within which a slide of about 40 pixels' pitch is still found:
    the wave-optical depth of field ``λ / NA²``, µm."""
    check_number("numerical_aperture", numerical_aperture, above=0)
    return wavelength_um / (numerical_aperture**2) if numerical_aperture < 1.5 else math.nan
