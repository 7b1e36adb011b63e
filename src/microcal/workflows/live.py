"""The work behind ``microcal ui``: a calibrated station seen live and sent by clicks.

:func:`open_live_station` opens a rig and its calibration (as ``goto`` does) into a
:class:`LiveStation`, which the station page's server (:mod:`microcal.ui`) calls and nothing
else: frames of every camera for the page (downscaled, or a full-resolution region), the
overlays (the tip the calibration predicts from the joint readings with its uncertainty, the
last measured tip, the soft limits, the target), the epipolar curve of a click, the 3D target
of clicks in two or more views with its covariance, and the moves (open or closed loop, in a
thread of their own) with a stop that holds.

What the page is given is data, not code paths: the cameras (any number, each its name and
size) and the target kind come from the rig, so a rig of one camera or another target is the
same page with other data (:meth:`LiveStation.layout`).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import FloatArray, as_array
from ..control.visual_servo import ServoStep
from ..devices.guarded_manipulator import GuardedManipulator
from ..devices.rig import Rig
from ..devices.rig_spec import RigSpec
from ..devices.shared_camera import SharedCamera
from ..errors import InputError, LimitError, MicrocalError
from ..formats.calibration_file import load_calibration
from ..formats.check_file import of_device, read_history
from ..formats.safe_open import read_regular_bytes
from ..geometry import AnyCamera, triangulate_views
from ..geometry.epipolar import epipolar_curve_px
from ..kinematics.extra_inputs import default_extra_inputs
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..procedures.station import Arrival, Station
from ..vision.measurement import _vp_of_frames
from ..vision.tip_target import TipTarget
from .click_snap import SnappedClick, snap_click
from .one_camera import FocalPlane, OneCameraProbe
from .station import open_calibrated_rig

__all__ = [
    "CLICK_STD_DISPLAY_PX",
    "ClickTarget",
    "LiveStation",
    "calibration_health",
    "open_live_station",
]

#: The standard deviation of a click, in pixels of the page's (downscaled) view: one pixel
#: of the display, uniformly anywhere in it (1 / sqrt(12)), rounded up.
CLICK_STD_DISPLAY_PX = 0.5
#: chi-square quantile of 2 degrees of freedom at 95 %: the ellipses drawn hold 95 %.
CHI2_2_95 = 5.991464547107979
#: Largest width of a view sent to the page, px, and of a full-resolution region.
MAX_VIEW_WIDTH_PX = 2048
MAX_REGION_PX = 512
#: Frames the probe grabbed within this time are shown instead of grabbing again, s (while
#: a move runs: the frames it measures, as long as they are this recent).
FRESH_S = 0.05
MOVING_FRESH_S = 0.5


class _StoppedError(MicrocalError):
    """The stop control ended a closed loop between two corrections."""


@dataclass(frozen=True)
class ClickTarget:
    """The 3D target of clicks in two or more views.

    Attributes
    ----------
    target_um : (3,) float
        In {G}.
    cov_um2 : (3, 3) float
        Its covariance from the clicks' uncertainty.
    residual_px : dict of str -> float
        Per clicked camera, how far the target projects from the click (full-resolution px).
    refusal : str, optional
        Why the target cannot be gone to (outside the soft limits), one line; None if it can.
    snapped : dict of str -> SnappedClick
        Per camera clicked after the first, where its click was taken to be (the target
        found near the epipolar line, or the click projected onto the line).
    """

    target_um: FloatArray
    cov_um2: FloatArray
    residual_px: dict[str, float]
    refusal: str | None
    snapped: dict[str, SnappedClick] = dataclasses.field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return {
            "target_um": self.target_um.tolist(),
            "cov_um2": self.cov_um2.tolist(),
            "std_um": np.sqrt(np.diagonal(self.cov_um2)).tolist(),
            "residual_px": self.residual_px,
            "refusal": self.refusal,
            "snapped": {n: s.as_dict() for n, s in self.snapped.items()},
        }


def _ellipse(q: FloatArray, cov_px2: FloatArray) -> dict[str, float]:
    """The 95 % ellipse of a pixel (2,) with covariance (2, 2): centre, semi-axes, angle (rad)."""
    vals, vecs = np.linalg.eigh(0.5 * (cov_px2 + cov_px2.T))
    vals = np.maximum(vals, 0.0)
    a, b = np.sqrt(CHI2_2_95 * vals[::-1])
    angle = math.atan2(vecs[1, 1], vecs[0, 1])
    return {"x": float(q[0]), "y": float(q[1]), "a": float(a), "b": float(b), "angle": angle}


def _to_8bit(frame: NDArray[Any], bit_depth: int) -> NDArray[np.uint8]:
    if frame.dtype == np.uint8:
        return frame
    shift = max(bit_depth - 8, 0)
    out: NDArray[np.uint8] = np.clip(frame >> shift, 0, 255).astype(np.uint8)
    return out


def _predicted(cal: ManipulatorCalibration, d: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The calibration's tip (3,) µm for joints ``d`` (3,) and its covariance (3, 3) µm²."""
    p = cal.predict_um(d[None, :])[0]
    model = cal.model
    u = d
    if model.extra_inputs:
        u = np.concatenate([d, np.ravel(default_extra_inputs(model.extra_inputs))])
    std = model.prediction_std_um(u[None, :])[0]
    scatter = cal.validation.get("std_um", 0.0) if cal.validation else 0.0
    spread = float(scatter) if isinstance(scatter, int | float) else 0.0
    return p, np.diag(std**2 + spread**2)


class LiveStation:
    """A :class:`~microcal.procedures.station.Station` for the page (module docstring).

    Parameters
    ----------
    rig : Rig
        The opened rig with the calibrated device selected; the live station closes it. Its
        manipulator is wrapped in a :class:`GuardedManipulator` (a stop that holds) and its
        cameras in :class:`SharedCamera` (the live view and the probe take turns).
    calibration : ManipulatorCalibration
    models : mapping of str -> camera model
        The calibrated cameras.
    description : str
        What the rig is, in words.
    frames : int
        Frames per camera of each measurement.
    settle_s : float
        Wait after a move before measuring.
    health : mapping, optional
        The calibration's health (:func:`calibration_health`), shown as it is.
    report : path, optional
        The latest report.html, served on request (:meth:`report_html`).
    spec : RigSpec, optional
        The rig as its file names it (the record of an acquisition started from the page).
    calibration_path : path, optional
        calibration.json (the page's checks join its history; :meth:`refresh_health`).
    """

    def __init__(
        self,
        rig: Rig,
        calibration: ManipulatorCalibration,
        models: Mapping[str, AnyCamera],
        description: str = "",
        *,
        frames: int = 5,
        settle_s: float = 1.0,
        health: Mapping[str, Any] | None = None,
        report: Path | None = None,
        spec: RigSpec | None = None,
        calibration_path: Path | None = None,
    ) -> None:
        self.health = dict(health or {})
        self.spec = spec
        self.calibration_path = calibration_path
        self.report = report
        self.manipulator = GuardedManipulator(rig.manipulator)
        self.cameras = {n: SharedCamera(c) for n, c in rig.cameras.items()}
        device = dataclasses.replace(
            rig,
            manipulator=self.manipulator,
            cameras=dict(self.cameras),
            manipulators={**rig.manipulators, rig.selected: self.manipulator},
        )
        self.models: dict[str, AnyCamera] = {n: models[n] for n in rig.cameras}
        probe = None
        self.focal_plane: FocalPlane | None = None
        if len(self.models) == 1:  # one camera: across its axis measured, along it the model's
            ((name, model),) = self.models.items()
            if isinstance(rig.board, TipTarget):  # the opener closes the rig
                raise InputError(
                    "a one-camera station measures a board on the tool, not a bare tip yet: "
                    "give the rig a board target, or calibrate two cameras"
                )
            probe = OneCameraProbe(self.cameras[name], model, rig.board,
                                   lambda d: _predicted(calibration, d), frames)  # fmt: skip
        self.station = Station(device, calibration, models, frames=frames, settle_s=settle_s,
                               on_correction=self._step, probe=probe)  # fmt: skip
        self.description = description
        self.truth = rig.truth
        self._lock = threading.Lock()  # guards the fields below
        self._worker: threading.Thread | None = None
        self._activity = "idle"
        self._joints: FloatArray = self.manipulator.position_um()
        self._measured: tuple[FloatArray, FloatArray] | None = None
        self._target: ClickTarget | None = None
        self._arrival: dict[str, Any] | None = None
        self._message = ""
        self._error = ""
        self._sharpness: dict[str, float] = {}
        self._camera_errors: dict[str, str] = {}
        self.moves_started = 0
        if probe is not None:
            self.set_focal_plane("the tip when the station opened")

    # --- what the page shows -------------------------------------------------------------

    def layout(self) -> dict[str, Any]:
        """What the page is built from: the cameras, the target kind, the device, its limits."""
        rig = self.station.rig
        return {
            "cameras": [
                {"name": n, "width_px": m.image_size_px[0], "height_px": m.image_size_px[1]}
                for n, m in self.models.items()
            ],
            "target": {"kind": rig.board.kind, "spec": rig.board.spec},
            "manipulator": rig.selected,
            "axes": list(self.manipulator.axes),
            "limits_um": self.manipulator.limits_um.tolist(),
            "rig": self.description,
            "simulated": self.truth is not None,
            "click_to_target": "rays" if len(self.models) >= 2 else "focal plane",
            "focal_plane": None if self.focal_plane is None else self.focal_plane.as_dict(),
            "health": self.health | {"report": self.report is not None},
        }

    def check_history(self) -> list[dict[str, Any]]:
        """The checks of this calibration's device, oldest first (empty without the path).

        Raises
        ------
        FormatError
            The history cannot be read.
        """
        if self.calibration_path is None:
            return []
        single = len(load_calibration(self.calibration_path).manipulators) == 1
        name = self.station.calibration.name
        return of_device(read_history(self.calibration_path), name, single)

    def refresh_health(self) -> None:
        """Read the calibration's health again (after a check joined its history)."""
        if self.calibration_path is None:
            return
        single = len(load_calibration(self.calibration_path).manipulators) == 1
        cal = self.station.calibration
        self.health = calibration_health(self.calibration_path, cal.name, single,
                                         cal.validation or {})  # fmt: skip

    def report_html(self) -> bytes:
        """The latest report.html beside the calibration (a regular file, never a link).

        Raises
        ------
        InputError
            There is none.
        FormatError
            It is not a regular file.
        """
        if self.report is None:
            raise InputError("report: there is no report.html beside the calibration")
        return read_regular_bytes(self.report)

    def frame_jpeg(
        self,
        camera: str,
        width_px: int = 640,
        region: tuple[int, int, int] | None = None,
        quality: int = 80,
    ) -> bytes:
        """One frame of ``camera`` as JPEG: downscaled to ``width_px``, or with ``region``
        ``(x, y, size)`` a square of the full-resolution frame centred on pixel (x, y).

        Raises
        ------
        InputError
            An unknown camera, a width or region out of range.
        DeviceError, FrameError
            The camera failed (its error in words); the page shows it.
        """
        cam = self._camera(camera)
        # while a move measures, show the probe's frames rather than grab more between them
        moving = self.moving
        frame = None
        if moving or cam.busy():
            frame = cam.latest(MOVING_FRESH_S if moving else FRESH_S)
        if frame is None:
            try:
                frame = cam.grab()
            except MicrocalError as exc:
                with self._lock:
                    self._camera_errors[camera] = str(exc)
                raise
        with self._lock:
            self._camera_errors.pop(camera, None)
        image = _to_8bit(frame, cam.bit_depth)
        h, w = image.shape[:2]
        if region is not None:
            x, y, size = region
            if not 16 <= size <= MAX_REGION_PX:
                raise InputError(f"region size: expected 16 to {MAX_REGION_PX} px, got {size}")
            x0 = int(np.clip(x - size // 2, 0, max(w - size, 0)))
            y0 = int(np.clip(y - size // 2, 0, max(h - size, 0)))
            image = image[y0 : y0 + size, x0 : x0 + size]
        else:
            if not 16 <= width_px <= MAX_VIEW_WIDTH_PX:
                raise InputError(f"width: expected 16 to {MAX_VIEW_WIDTH_PX} px, got {width_px}")
            height = max(1, round(h * width_px / w))
            image = cv2.resize(image, (width_px, height), interpolation=cv2.INTER_LINEAR)
            lap = cv2.Laplacian(image, cv2.CV_32F)
            with self._lock:
                self._sharpness[camera] = float(lap.var())
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        if not ok:  # pragma: no cover - OpenCV encodes any 8-bit image
            raise InputError(f"{camera}: the frame could not be encoded")
        return bytes(data.tobytes())

    def _camera(self, camera: str) -> SharedCamera:
        if camera not in self.cameras:
            raise InputError(f"camera {camera!r}: this rig has {', '.join(self.cameras)}")
        return self.cameras[camera]

    def _project(self, p_um: FloatArray, cov_um2: FloatArray) -> dict[str, dict[str, float]]:
        """A point (3,) with covariance in each camera: its 95 % ellipse, full-resolution px."""
        out = {}
        for n, m in self.models.items():
            q = m.project(p_um[None, :])[0]
            J = m.project_jacobian(p_um[None, :])[0]
            if np.all(np.isfinite(q)):
                out[n] = _ellipse(q, J @ cov_um2 @ J.T)
        return out

    def predicted_um(self, d_um: ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
        """Where the calibration puts the tip for joints ``d_um`` (the last read by default):
        position (3,) µm and covariance (3, 3) µm² (the coefficients' uncertainty and the
        validation's scatter per axis)."""
        d = self._joints if d_um is None else as_array(d_um, "d_um", (3,))
        return _predicted(self.station.calibration, d)

    def limit_edges_um(self, samples: int = 9) -> list[FloatArray]:
        """The soft limits' box of joints as 12 edges in {G} (each (samples, 3) µm), through
        the calibration."""
        lim = self.manipulator.limits_um
        edges = []
        t = np.linspace(0.0, 1.0, samples)
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            for i in (0, 1):
                for j in (0, 1):
                    d = np.empty((samples, 3))
                    d[:, axis] = lim[axis, 0] + t * (lim[axis, 1] - lim[axis, 0])
                    d[:, others[0]] = lim[others[0], i]
                    d[:, others[1]] = lim[others[1], j]
                    edges.append(self.station.calibration.predict_um(d))
        return edges

    def overlays(self) -> dict[str, dict[str, Any]]:
        """Per camera, in its full-resolution pixels: the predicted tip and its ellipse, the
        last measured tip, the target, and the soft limits' edges (lists of points)."""
        p, cov = self.predicted_um()
        with self._lock:
            measured, target = self._measured, self._target
        out: dict[str, dict[str, Any]] = {n: {} for n in self.models}
        for key, value in (
            ("predicted", (p, cov)),
            ("measured", measured),
            ("target", None if target is None else (target.target_um, target.cov_um2)),
        ):
            if value is None:
                continue
            for n, e in self._project(*value).items():
                out[n][key] = e
        edges = self.limit_edges_um()
        for n, m in self.models.items():
            out[n]["limits"] = [np.round(m.project(e), 1).tolist() for e in edges]
        return out

    # --- clicks ------------------------------------------------------------------------

    def epipolar(self, camera: str, q_px: ArrayLike) -> dict[str, list[list[float]]]:
        """The curve a click ``q_px`` (2,) in ``camera`` (full-resolution px) can lie on in
        every other camera: lists of (x, y) px, empty where it does not cross the view."""
        source = self.models[self._camera(camera).name]
        q = as_array(q_px, "click", (2,))
        near, _ = self.predicted_um()
        return {
            n: np.round(epipolar_curve_px(source, q, m, near, samples=129), 2).tolist()
            for n, m in self.models.items()
            if n != camera
        }

    def target_from_clicks(
        self,
        clicks_px: Mapping[str, ArrayLike],
        click_std_px: Mapping[str, float],
        offset_um: float = 0.0,
        first: str | None = None,
    ) -> ClickTarget:
        """The 3D target of clicks in two or more cameras, or of one click on a one-camera
        rig (its focal plane moved ``offset_um`` along the camera's axis), with its covariance.

        Parameters
        ----------
        clicks_px : mapping of camera -> (2,) float
            Full-resolution pixels (distortion included).
        click_std_px : mapping of camera -> float
            Each click's standard deviation, full-resolution px.
        offset_um : float
            One camera: the target's distance from the focal plane along the camera's axis
            (positive: away from the camera), µm.
        first : str, optional
            The camera clicked first: every other click is taken onto its epipolar curve,
            onto the rig's target where that is found near the curve (:mod:`.click_snap`).

        Raises
        ------
        InputError
            Fewer than two clicks on a rig of two or more cameras, an unknown camera, clicks
            whose rays do not meet, a click whose ray does not reach the focal plane.
        """
        if not math.isfinite(offset_um):
            raise InputError(f"offset: expected a number of µm, got {offset_um!r}")
        if len(clicks_px) == 1 and self.focal_plane is not None:
            ((name, click),) = clicks_px.items()
            self._camera(name)
            click_px = as_array(click, f"click in {name}", (2,))
            p, cov = self.focal_plane.target(
                click_px, float(click_std_px.get(name, 1.0)), offset_um
            )
            if not np.all(np.isfinite(p)):
                raise InputError("target: the click's ray does not reach the focal plane")
            residual = {
                name: float(np.linalg.norm(self.models[name].project(p[None, :])[0] - click_px))
            }
            target = ClickTarget(p, cov, residual, self.refusal(p))
            with self._lock:
                self._target = target
            return target
        if len(clicks_px) < 2:
            raise InputError(
                "target: a click gives a ray, not a point; click in a second view, on the "
                "epipolar line"
            )
        names = [self._camera(n).name for n in clicks_px]
        cams = [self.models[n] for n in names]
        raw = [as_array(clicks_px[n], f"click in {n}", (2,)) for n in names]
        std = [float(click_std_px.get(n, 1.0)) for n in names]
        snapped: dict[str, SnappedClick] = {}
        if first is not None and first in names:
            curves = self.epipolar(first, raw[names.index(first)])
            for i, n in enumerate(names):
                if n == first:
                    continue
                feature = self.feature_px(n)
                fq, fs = (None, 1.0) if feature is None else feature
                snapped[n] = snap_click(curves[n], raw[i], std[i], fq, fs)
                raw[i], std[i] = snapped[n].q_px, snapped[n].std_px
        q = [m.undistort_px(r[None, :]) for m, r in zip(cams, raw, strict=True)]
        p, cov, _ = triangulate_views(cams, q, [s**2 * np.eye(2) for s in std])
        if not np.all(np.isfinite(p)):
            raise InputError("target: the clicks' rays do not meet; click on the epipolar line")
        residual = {
            n: float(np.linalg.norm(m.project(p)[0] - r))
            for n, m, r in zip(names, cams, raw, strict=True)
        }
        target = ClickTarget(p[0], cov[0], residual, self.refusal(p[0]), snapped)
        with self._lock:
            self._target = target
        return target

    def feature_px(self, camera: str) -> tuple[FloatArray, float] | None:
        """The rig's target (its virtual point, or a tool's tip) found in a frame of
        ``camera`` now: pixel (2,) and its standard deviation, px; None when it is not found
        or the camera fails."""
        cam = self._camera(camera)
        frame = cam.latest(MOVING_FRESH_S if self.moving else FRESH_S)
        try:
            frame = cam.grab() if frame is None else frame
        except MicrocalError:
            return None
        got = _vp_of_frames([frame], self.station.rig.board, self.models[camera], None)
        if isinstance(got, str):
            return None
        vps, cov, _ = got
        sigma = float(getattr(self.models[camera], "projection_sigma_px", 0.0))
        std = math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0) + sigma**2)
        return vps.mean(axis=0), max(std, 0.01)

    def set_focal_plane(self, source: str | None = None) -> dict[str, object]:
        """One camera: take the focal plane through the tip where the calibration puts it
        now (the tip in focus); what it is now.

        Raises
        ------
        InputError
            The rig has two cameras or more (a second click gives the depth).
        """
        if len(self.models) != 1:
            raise InputError(
                "focal plane: for a one-camera rig; here a second view gives the depth"
            )
        (model,) = self.models.values()
        p, cov = self.predicted_um()
        when = source or f"the tip at {time.strftime('%H:%M:%S')}"
        plane = FocalPlane.through(model, p, cov, when)
        with self._lock:
            self.focal_plane = plane
        return plane.as_dict()

    def refusal(self, p_um: FloatArray) -> str | None:
        """Why the tip cannot be sent to ``p_um`` (3,) in {G}, one line; None if it can."""
        try:
            self.station.check_reach(p_um)
        except MicrocalError as exc:
            return str(exc)
        return None

    # --- moves ---------------------------------------------------------------------------

    @property
    def moving(self) -> bool:
        """True while a move or a measurement runs."""
        worker = self._worker
        return worker is not None and worker.is_alive()

    def go(
        self,
        target_um: ArrayLike,
        mode: Literal["open", "closed"] = "closed",
        tolerance_um: float | None = None,
    ) -> None:
        """Start sending the tip to ``target_um`` (3,) in {G}; returns at once (see
        :meth:`state`).

        Raises
        ------
        InputError
            A move or measurement is under way, an unknown mode or a bad tolerance.
        LimitError
            The target's joints leave the soft limits: refused before anything moves.
        """
        target = as_array(target_um, "target_um", (3,))
        if mode not in ("open", "closed"):
            raise InputError(f"mode: expected 'open' or 'closed', got {mode!r}")
        if tolerance_um is not None and not (math.isfinite(tolerance_um) and tolerance_um > 0):
            raise InputError(f"tolerance: expected a number of µm > 0, got {tolerance_um!r}")
        refusal = self.refusal(target)
        if refusal is not None:
            raise LimitError(refusal)
        self._start(f"going {mode} loop", lambda: self._go(target, mode, tolerance_um))

    def measure(self) -> None:
        """Start measuring the tip with the cameras (see :meth:`state`)."""
        self._start("measuring", self._measure)

    def _start(self, activity: str, work: Callable[[], None]) -> None:
        with self._lock:
            if self._worker is not None and self._worker.is_alive():
                raise InputError(f"busy: {self._activity}; wait, or stop")
            self.manipulator.resume()
            self._activity, self._error, self._message = activity, "", ""
            self.moves_started += 1
            self._worker = threading.Thread(
                target=self._run, args=(work,), daemon=True, name="microcal-station-move"
            )
            self._worker.start()

    def _run(self, work: Callable[[], None]) -> None:
        try:
            work()
        except _StoppedError:
            self._finish(error="stopped by the stop control")
        except MicrocalError as exc:
            text = str(exc)
            if self.manipulator.halted:
                text = "stopped by the stop control"
            self._finish(error=text)
        except Exception as exc:  # a device's unforeseen failure: in words, the server goes on
            self._finish(error=f"unexpected {type(exc).__name__}: {exc}")
        else:
            self._finish()

    def _finish(self, error: str = "") -> None:
        try:
            joints = self.manipulator.position_um()
        except MicrocalError:
            joints = self._joints
        with self._lock:
            self._joints = joints
            self._activity = "idle"
            if error:
                self._error = error

    def _step(self, step: ServoStep) -> None:
        with self._lock:
            self._joints = np.asarray(step.d_um, dtype=np.float64)
            self._measured = (step.measured_um, step.cov_um2)
            self._message = (
                f"correction {step.iteration}: error {np.linalg.norm(step.error_um):.2f} µm"
            )
        if self.manipulator.halted:
            raise _StoppedError("stopped by the stop control")

    def _go(self, target: FloatArray, mode: Literal["open", "closed"], tol: float | None) -> None:
        started = time.perf_counter()
        arrival = self.station.move_to_um(target, mode, tol)
        self._arrived(arrival, time.perf_counter() - started)

    def _arrived(self, a: Arrival, took_s: float) -> None:
        out: dict[str, Any] = a.as_dict() | {
            "took_s": took_s,
            "residual_um": float(np.linalg.norm(a.error_um)),
        }
        if self.truth is not None:
            true = np.asarray(self.truth(), dtype=np.float64)
            out["truth_um"] = true.tolist()
            out["truth_error_um"] = float(np.linalg.norm(true - a.target_um))
        with self._lock:
            self._arrival = out
            self._measured = (a.measured_um, a.cov_um2)
            self._joints = a.d_um

    def _measure(self) -> None:
        p, cov = self.station.where_um()
        with self._lock:
            self._measured = (p, cov)
            self._message = "measured"

    def show_joints(self, d_um: ArrayLike) -> None:
        """The joints (3,) µm as a run under way read them (the device is not asked while a
        run moves it): the page's tip and predictions follow."""
        d = np.asarray(d_um, dtype=np.float64)
        if d.shape == (3,) and np.all(np.isfinite(d)):
            with self._lock:
                self._joints = d

    def stop(self) -> None:
        """Stop now: the device is told to stop and no further move is sent."""
        self.manipulator.halt()
        with self._lock:
            if self._activity != "idle":
                self._activity = "stopping"

    def wait(self, timeout_s: float = 60.0) -> bool:
        """Wait for the move under way (if any); True when none is left."""
        worker = self._worker
        if worker is not None:
            worker.join(timeout_s)
        return not self.moving

    def state(self) -> dict[str, Any]:
        """What the page shows besides the frames: device, activity, results, errors."""
        with self._lock:  # no move starts meanwhile: one thread talks to the device at a time
            if not self.moving:
                try:
                    self._joints = self.manipulator.position_um()
                except MicrocalError as exc:
                    self._error = str(exc)
        p, cov = self.predicted_um()
        with self._lock:
            measured, target = self._measured, self._target
            return {
                "activity": self._activity,
                "joints_um": self._joints.tolist(),
                "predicted_um": p.tolist(),
                "predicted_std_um": np.sqrt(np.diagonal(cov)).tolist(),
                "measured_um": None if measured is None else measured[0].tolist(),
                "target": None if target is None else target.as_dict(),
                "arrival": self._arrival,
                "message": self._message,
                "error": self._error,
                "camera_errors": dict(self._camera_errors),
                "sharpness": dict(self._sharpness),
                "halted": self.manipulator.halted,
                "focal_plane": None if self.focal_plane is None else self.focal_plane.as_dict(),
            }

    def close(self) -> None:
        """Stop any move and close the rig."""
        if self.moving:
            self.stop()
            self.wait(10.0)
        self.station.close()


def calibration_health(
    calibration: str | Path, name: str, single: bool, validation: Mapping[str, object]
) -> dict[str, Any]:
    """When the calibration was made, its validation RMS and its checks (oldest first: when,
    the verdict, the offset and whether it was flagged); a history that cannot be read is
    said in ``history_error`` instead of failing the station."""
    cal = load_calibration(calibration)
    provenance = dict(cal.provenance)
    out: dict[str, Any] = {"path": str(calibration), "created": provenance.get("created"),
                           "software": provenance.get("software"),
                           "validation_rms_um": validation.get("rms_um")}  # fmt: skip
    try:
        checks = of_device(read_history(calibration), name, single)
    except MicrocalError as exc:
        return out | {"checks": [], "history_error": str(exc)}
    keys = ("created", "verdict", "offset_um", "offset_std_um", "flag")
    out["checks"] = [{k: c.get(k) for k in keys} for c in checks[-100:]]
    return out


#: The station page's refusal of a rig of one camera on a focus drive.
ONE_CAMERA_NOT_SERVED = (
    "the station page does not serve a rig of one camera on a focus drive yet; on such a rig "
    "microcal goto, evaluate and check take --scope scope.json --objective NAME "
    "(docs/microscope.md)"
)


def open_live_station(
    rig: str = "sim",
    calibration: str = "calibration.json",
    *,
    manipulator: str | None = None,
    seed: int | None = None,
    frames: int = 5,
    settle_s: float | None = None,
) -> LiveStation:
    """Open the rig and its calibration for the station page.

    Parameters
    ----------
    rig : str
        ``"sim"`` or a rig file.
    calibration : str
        calibration.json with the cameras.
    manipulator : str, optional
    seed : int, optional
        The simulated rig's seed.
    frames : int
        Frames per camera of each measurement.
    settle_s : float, optional
        Wait after a move before measuring (the station's default: 1 s).

    Raises
    ------
    InputError, FormatError, DeviceError
        As ``microcal goto``: one line each; nothing is left open.
    """
    c = open_calibrated_rig(rig, calibration, manipulator=manipulator, seed=seed,
                            one_camera_refused=ONE_CAMERA_NOT_SERVED)  # fmt: skip
    try:
        description = "; ".join(f"{k}: {v}" for k, v in c.opened.description.items())
        device = c.device
        left_out = [n for n in device.cameras if n not in c.models]
        if left_out and len(left_out) < len(device.cameras):  # the cameras calibrated
            cameras = {n: cam for n, cam in device.cameras.items() if n in c.models}
            unused = [device.cameras[n].close for n in left_out]  # closed with the rig
            device = dataclasses.replace(device, cameras=cameras,
                                         resources=[*device.resources, *unused])  # fmt: skip
            description += f"; camera(s) {', '.join(left_out)} not calibrated, left out"
        single = len(load_calibration(calibration).manipulators) == 1
        health = calibration_health(calibration, c.entry.name, single, c.entry.validation)
        report = Path(calibration).with_name("report.html")
        return LiveStation(device, c.entry, c.models, description, frames=frames,
                           settle_s=1.0 if settle_s is None else settle_s, health=health,
                           report=report if report.is_file() else None, spec=c.spec,
                           calibration_path=Path(calibration))  # fmt: skip
    except BaseException:
        c.opened.close()
        raise
