"""The simulated microscope camera (a :class:`Camera` backend): rendered frames.

A grab renders every target in the scene into the frame (only the pixels they cover), blurs
each by its defocus, applies vignetting, converts to electrons, adds shot and read noise and
quantises to the camera's bit depth. The noise of the regions the targets cover is drawn
fresh for every frame; the background's comes from a pool of noise (two frames' worth,
drawn once) read at a random offset, which looks the same and costs nothing. The scene may
shake against the camera by a small random offset per frame (vibration). Faults are
injected at given rates: dropped frames and timeouts raise the exceptions a real driver
would; occlusion and glare spoil the image.

Only the box the targets cover is rendered and converted pixel by pixel; the background's
signal and noise level are the same in every frame and kept per camera, so a frame outside
the box costs one multiplication (noise level times the pool) and one rounding addition,
and only where it is read: :meth:`SimCamera.grab_lazy` gives an :class:`ExposedFrame` whose
background is exposed by region when asked for (``grab`` exposes all of it). The frames are
the same, bit for bit, as converting the whole image each time gives.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, check_number
from ..devices.base import Camera, Clock
from ..errors import DeviceTimeoutError, FrameError, InputError
from ..geometry.camera_kinds import AnyCamera
from .render import Placement, Reflectance, render_region, roi_of
from .slide_render import render_slide
from .tool_render import render_tool_region, tool_roi
from .tools import ToolPlacement

__all__ = [
    "CameraFaults", "ExposedFrame", "ImageFormation", "PaintJob", "Painted", "SimCamera",
    "paint", "paint_here",
]  # fmt: skip


@dataclass(frozen=True)
class ImageFormation:
    """How light becomes numbers in the simulated camera.

    Attributes
    ----------
    full_well_e : float
        Electrons at the top of the output range.
    illumination : float
        Signal of a white (reflectance 1) object at the nominal exposure, as a fraction of the
        full well.
    read_noise_e : float
        Read noise, electrons RMS.
    vignetting : float
        Relative loss of light at the image corners (quadratic in the radius).
    blur_sigma_px : float
        Blur (optics) of an object in the focal plane, px.
    defocus_px_per_mm : float
        Growth of the blur per mm of depth away from the focal plane.
    focus_depth_um : float
        Depth of the focal plane from the camera centre, µm.
    jitter_px : (float, float)
        Standard deviation of the per-frame shift of the scene (vibration), px.
    supersample : int
        Subsamples per pixel side in the rendering.
    nominal_exposure_s : float
        Exposure at which ``illumination`` holds; the signal scales with the exposure.
    readout_s : float
        Simulated time a frame takes besides the exposure.
    """

    full_well_e: float = 6000.0
    illumination: float = 0.85
    read_noise_e: float = 300.0
    vignetting: float = 0.2
    blur_sigma_px: float = 1.7
    defocus_px_per_mm: float = 0.4
    focus_depth_um: float = 0.0
    jitter_px: tuple[float, float] = (0.0, 0.0)
    supersample: int = 2
    nominal_exposure_s: float = 0.02
    readout_s: float = 0.03

    def __post_init__(self) -> None:
        check_number("full_well_e", self.full_well_e, above=0)
        check_number("illumination", self.illumination, above=0, high=10)
        check_number("read_noise_e", self.read_noise_e, low=0)
        check_number("vignetting", self.vignetting, low=0, high=0.99)
        check_number("blur_sigma_px", self.blur_sigma_px, low=0, high=50)
        check_number("defocus_px_per_mm", self.defocus_px_per_mm, low=0)
        check_number("focus_depth_um", self.focus_depth_um)
        if len(self.jitter_px) != 2:
            raise InputError(f"jitter_px: expected [along, across] px, got {self.jitter_px!r}")
        for v in self.jitter_px:
            check_number("jitter_px", v, low=0, high=50)
        check_number("supersample", self.supersample, low=1, high=8, integer=True)
        check_number("nominal_exposure_s", self.nominal_exposure_s, above=0)
        check_number("readout_s", self.readout_s, low=0)


@dataclass(frozen=True)
class CameraFaults:
    """Fault rates per grab (0 = never)."""

    drop_rate: float = 0.0
    timeout_rate: float = 0.0
    occlusion_rate: float = 0.0
    glare_rate: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            check_number(f.name, getattr(self, f.name), low=0, high=1)


@dataclass
class FrameTruth:
    """What the last frame showed, for tests: time, vibration shift and true features."""

    t_s: float
    offset_px: FloatArray
    features_px: list[FloatArray] = field(default_factory=list)  # per placement, (N, 2)
    placements: list[Placement | ToolPlacement] = field(default_factory=list)
    spoiled: str = ""  # "occlusion" or "glare" when a fault spoiled the frame


class SimCamera(Camera):
    """A camera that renders the scene through a camera model (pinhole or affine).

    Parameters
    ----------
    model : CameraModel or AffineCamera
        The true camera (intrinsics, distortion, pose).
    scene : callable t_s -> list of Placement or ToolPlacement
        The targets (boards, slides, tools) in view at a given time.
    clock : Clock
    rng : numpy.random.Generator
    pixel_size_um : float
        Physical pixel size (informational).
    bit_depth : int
    formation : ImageFormation
    faults : CameraFaults
    """

    def __init__(
        self,
        model: AnyCamera,
        scene: Callable[[float], list[Placement | ToolPlacement]],
        clock: Clock,
        rng: np.random.Generator,
        *,
        pixel_size_um: float = 4.4,
        bit_depth: int = 8,
        formation: ImageFormation | None = None,
        faults: CameraFaults | None = None,
        reflectance: Reflectance | None = None,
    ) -> None:
        super().__init__(model.name, model.image_size_px, pixel_size_um, bit_depth, 0.02)
        self.model = model
        self.scene = scene
        self.clock = clock
        self.rng = rng
        self.formation = formation or ImageFormation()
        self._exposure_s = self.formation.nominal_exposure_s
        self.faults = faults or CameraFaults()
        self.reflectance = reflectance or Reflectance()
        w, h = model.image_size_px
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        self._vignette = (1.0 - self.formation.vignetting * r2).astype(np.float32)
        self.last_truth: FrameTruth | None = None
        # Background noise comes from a pool read at a random offset each frame; the regions
        # the targets cover get freshly drawn noise (see grab).
        self._pool = self.rng.standard_normal(2 * w * h, dtype=np.float32)
        self._rois: list[tuple[int, int, int, int]] = []
        #: Paints each frame's targets (:func:`paint`): here, at the grab, by default; a
        #: painter of another process (:class:`~microcal.sim.paint_process.PaintProcess`)
        #: paints while this one goes on, the frame's noise drawn at the grab all the same.
        self.painter: Callable[[PaintJob], Painted] = paint_here
        # The background's mean DN and noise level (h, w) by (level, gain, DN per e-, read
        # noise^2): the same for every frame at one exposure.
        self._background: dict[tuple[float, ...], tuple[FloatArray32, FloatArray32]] = {}

    def _blur_sigma(self, placement: Placement | ToolPlacement) -> float:
        f = self.formation
        if isinstance(placement, ToolPlacement):  # a tool: blurred as deep as its tip
            centre = placement.tip_um
        else:
            centre = placement.R @ placement.target.centre_um + placement.t_um
        depth = float(self.model.depth_um(centre)[0])
        defocus = f.defocus_px_per_mm * abs(depth - f.focus_depth_um) / 1000.0
        return float(np.hypot(f.blur_sigma_px, defocus))

    def render_reflectance(
        self, t_s: float, offset_px: FloatArray
    ) -> tuple[NDArray[np.float32], FrameTruth]:
        """Noise-free reflectance image of the scene at ``t_s`` (blurred, no vignetting)."""
        w, h = self.model.image_size_px
        level, box, patch, truth = self._render_box(t_s, offset_px)
        image = np.full((h, w), level, dtype=np.float32)
        if box is not None and patch is not None:
            x0, y0, x1, y1 = box
            image[y0:y1, x0:x1] = patch
        return image, truth

    def _render_box(
        self, t_s: float, offset_px: FloatArray
    ) -> tuple[float, Box | None, NDArray[np.float32] | None, FrameTruth]:
        """The scene at ``t_s`` as the background level and the box the targets cover.

        Returns the background's reflectance, the box (x0, y0, x1, y1) holding every
        placement's region (None when no target is in view), the reflectance image over that
        box (blurred, no vignetting), and the frame's truth. Sets ``_rois``.
        """
        job, truth = self._plan(t_s, offset_px)
        box, patch = paint(job)
        return job.level, box, patch, truth

    def _plan(self, t_s: float, offset_px: FloatArray) -> tuple[PaintJob, FrameTruth]:
        """What a frame at ``t_s`` shows, to be painted (:func:`paint`), and its truth.
        Sets ``_rois``."""
        placements = self.scene(t_s)
        # A dot grid's glass plate (25 mm in the thesis) fills the view: glass is the background.
        plate = any(isinstance(p, Placement) and p.target.kind == "dotgrid" for p in placements)
        level = self.reflectance.glass if plate else self.reflectance.background
        truth = FrameTruth(t_s, offset_px)
        self._rois = []
        items: list[tuple[Placement | ToolPlacement, Box, float]] = []
        for placement in placements:
            sigma = self._blur_sigma(placement)
            truth.placements.append(placement)
            if isinstance(placement, ToolPlacement):  # a tool on the end-effector: its tip
                roi = tool_roi(self.model, placement, 4.0 * sigma + 3.0, offset_px)
                truth.features_px.append(self.model.project(placement.tip_um[None]) + offset_px)
            else:
                roi = roi_of(self.model, placement, 4.0 * sigma + 3.0, offset_px)
                truth.features_px.append(
                    self.model.project(placement.points_world_um()) + offset_px
                )
            if roi is None:
                continue
            self._rois.append(roi)
            items.append((placement, roi, sigma))
        job = PaintJob(self.model, self.formation.supersample, self.reflectance,
                       np.asarray(offset_px, dtype=np.float64), level, tuple(items))  # fmt: skip
        return job, truth

    def _spoil(self, image: NDArray[np.float32], truth: FrameTruth) -> None:
        f = self.faults
        kind = ""
        if f.occlusion_rate and self.rng.random() < f.occlusion_rate:
            kind = "occlusion"
        elif f.glare_rate and self.rng.random() < f.glare_rate:
            kind = "glare"
        if not kind or not truth.features_px:
            return
        pts = truth.features_px[0]
        centre = pts[self.rng.integers(len(pts))]
        spread = float(np.ptp(pts[:, 0]) + np.ptp(pts[:, 1])) / 4 + 5
        axes = (int(spread * self.rng.uniform(0.6, 1.2)), int(spread * self.rng.uniform(0.4, 0.9)))
        value = 0.02 if kind == "occlusion" else 1.4
        cv2.ellipse(image, (int(centre[0]), int(centre[1])), axes, float(self.rng.uniform(0, 180)),
                    0, 360, value, -1)  # fmt: skip
        truth.spoiled = kind

    def _close(self) -> None:
        pass  # nothing to release: closing only marks the device closed

    def _grab(self) -> NDArray[np.unsignedinteger]:
        return self._grab_frame().full()

    def grab_lazy(self) -> ExposedFrame:
        """One frame as :meth:`grab` gives it, exposed only where it is read.

        The same random draws and the same pixels as :meth:`grab`: the box the targets cover
        is exposed now, any other region of the frame when it is asked for
        (:meth:`ExposedFrame.region`, or the whole frame by :meth:`ExposedFrame.full`).
        """
        self._check_open("grab")
        return self._grab_frame()

    def pass_frame(self) -> None:
        """Let one frame pass that nobody reads: its time and every random draw a grab makes
        (so later frames are those a grab here would have been followed by), nothing painted
        or exposed."""
        self._check_open("grab")
        self._grab_frame(paint=False)

    def _grab_frame(self, paint: bool = True) -> ExposedFrame:
        f = self.faults
        if f.timeout_rate and self.rng.random() < f.timeout_rate:
            self.clock.sleep(1.0)
            raise DeviceTimeoutError(f"{self.name}: no frame within the timeout")
        if f.drop_rate and self.rng.random() < f.drop_rate:
            self.clock.sleep(self.exposure_s + self.formation.readout_s)
            raise FrameError(f"{self.name}: frame dropped (incomplete transfer)")
        t = self.clock.now_s()
        offset = self.rng.normal(0.0, 1.0, 2) * np.asarray(self.formation.jitter_px)
        fm = self.formation
        top = 2**self.bit_depth - 1
        k = np.float32(top / fm.full_well_e)  # DN per electron
        signal = fm.full_well_e * fm.illumination * (self.exposure_s / fm.nominal_exposure_s)
        gain = np.float32(signal) * k
        read2 = np.float32((fm.read_noise_e * k) ** 2)
        if f.occlusion_rate or f.glare_rate:  # a fault may paint anywhere: the whole image
            image, truth = self.render_reflectance(t, offset)
            self._spoil(image, truth)
            whole = (0, 0, image.shape[1], image.shape[0])
            frame = self._expose(lambda: (whole, image), None, whole, gain, k, read2, top)
        else:
            job, truth = self._plan(t, offset)
            painted = self.painter(job) if paint else _unpainted
            frame = self._expose(painted, self._background_of(job.level, gain, k, read2),
                                 job.box, gain, k, read2, top)  # fmt: skip
        self.clock.sleep(self.exposure_s + fm.readout_s)
        self.last_truth = truth
        return frame

    def _background_of(
        self, level: float, gain: np.float32, k: np.float32, read2: np.float32
    ) -> tuple[FloatArray32, FloatArray32]:
        """Mean DN and noise level (h, w) of a frame showing only the background ``level``."""
        key = (level, float(gain), float(k), float(read2))
        hit = self._background.get(key)
        if hit is None:
            w, h = self.model.image_size_px
            flat = np.full((h, w), level, dtype=np.float32)
            hit = _dn_and_spread(flat, self._vignette, gain, k, read2)
            if len(self._background) >= 2:
                self._background.pop(next(iter(self._background)))
            self._background[key] = hit
        return hit

    def _expose(
        self,
        painted: Callable[[], tuple[Box | None, NDArray[np.float32] | None]],
        background: tuple[FloatArray32, FloatArray32] | None,
        box: Box | None,
        gain: np.float32,
        k: np.float32,
        read2: np.float32,
        top: int,
    ) -> ExposedFrame:
        """The frame: vignetting, electrons, shot and read noise, quantisation.

        ``painted()`` gives the box and the reflectance over it (the whole image when
        ``background`` is None); elsewhere the image is the background, whose mean DN and
        noise level are ``background``. Mean DN, then noise of std ``sqrt(DN * k +
        (read_noise * k)^2)`` DN: the pool's at a random offset, fresh over every rendered
        region. The noise is drawn now; the box is exposed when the frame is first read (the
        reflectance may still be being painted in another process, :func:`paint_process`),
        the background where the frame is read (:class:`ExposedFrame`).
        """
        h, w = self._vignette.shape
        start = int(self.rng.integers(0, h * w))
        pool = self._pool[start : start + h * w].reshape(h, w)
        if box is None:
            return ExposedFrame((h, w), self.dtype, top, pool, background, None, None)
        fresh = [
            (roi, self.rng.standard_normal((roi[3] - roi[1], roi[2] - roi[0]), dtype=np.float32))
            for roi in self._rois
        ]
        vignette = self._vignette
        dtype = self.dtype

        def inner() -> NDArray[np.unsignedinteger]:
            _, patch = painted()
            assert box is not None
            assert patch is not None
            x0, y0, x1, y1 = box
            dn, spread = _dn_and_spread(patch, vignette[y0:y1, x0:x1], gain, k, read2)
            noisy = spread * pool[y0:y1, x0:x1]
            for (rx0, ry0, rx1, ry1), noise in fresh:
                region = (slice(ry0 - y0, ry1 - y0), slice(rx0 - x0, rx1 - x0))
                noisy[region] = spread[region] * noise
            return _quantise(dn, noisy, top, dtype)

        return ExposedFrame((h, w), self.dtype, top, pool, background, box, inner)


class ExposedFrame:
    """A simulated frame whose background is exposed where it is read.

    The box the targets cover is exposed when the frame is first read (``inner``: an array,
    or a function giving it once the reflectance is painted); the rest is
    the background's mean DN plus its noise level times the frame's slice of the noise pool,
    quantised when a region of it is asked for: pixel for pixel what exposing the whole frame
    at once gives (every operation is per pixel); a
    :class:`~microcal.vision.lazy_frame.RegionFrame`.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        dtype: type[np.unsignedinteger],
        top: int,
        pool: FloatArray32,
        background: tuple[FloatArray32, FloatArray32] | None,
        box: Box | None,
        inner: NDArray[np.unsignedinteger] | Callable[[], NDArray[np.unsignedinteger]] | None,
    ) -> None:
        self._shape = shape
        self._dtype = dtype
        self._top = top
        self._pool = pool
        self._background = background
        self._box = box
        self._inner = inner
        self._full: NDArray[np.unsignedinteger] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the whole frame, px."""
        return self._shape

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.unsignedinteger]:
        """The frame's pixels over [x0, x1) x [y0, y1) (inside the frame), a new array."""
        if self._full is not None:
            return self._full[y0:y1, x0:x1].copy()
        if self._background is not None:
            dn0, spread0 = self._background
            part = (slice(y0, y1), slice(x0, x1))
            out = _quantise(dn0[part], cv2.multiply(spread0[part], self._pool[part]),
                            self._top, self._dtype)  # fmt: skip
        else:
            out = np.empty((y1 - y0, x1 - x0), dtype=self._dtype)
        if self._box is not None and self._inner is not None:
            if callable(self._inner):
                self._inner = self._inner()
            bx0, by0, bx1, by1 = self._box
            ox0, oy0, ox1, oy1 = max(x0, bx0), max(y0, by0), min(x1, bx1), min(y1, by1)
            if ox0 < ox1 and oy0 < oy1:
                out[oy0 - y0 : oy1 - y0, ox0 - x0 : ox1 - x0] = self._inner[
                    oy0 - by0 : oy1 - by0, ox0 - bx0 : ox1 - bx0
                ]
        return out

    def full(self) -> NDArray[np.unsignedinteger]:
        """The whole frame, (h, w), exposed on the first call (later calls: the same array)."""
        if self._full is None:
            h, w = self._shape
            self._full = self.region(0, 0, w, h)
        return self._full


FloatArray32 = NDArray[np.float32]
Box = tuple[int, int, int, int]
#: A painted frame, asked for when it is read: the box and the reflectance over it.
Painted = Callable[[], tuple[Box | None, NDArray[np.float32] | None]]


@dataclass(frozen=True)
class PaintJob:
    """What one frame shows, to be painted by :func:`paint` (here or in another process).

    Attributes
    ----------
    model : CameraModel or AffineCamera
    supersample : int
    reflectance : Reflectance
    offset_px : (2,) float
        The frame's vibration shift.
    level : float
        The background's reflectance.
    items : tuple of (placement, roi, sigma)
        Each target in view: its placement, its region (x0, y0, x1, y1) and its blur, px.
    """

    model: AnyCamera
    supersample: int
    reflectance: Reflectance
    offset_px: FloatArray
    level: float
    items: tuple[tuple[Placement | ToolPlacement, Box, float], ...]

    @property
    def box(self) -> Box | None:
        """The box holding every target's region (None when none is in view)."""
        return _bounding_box([roi for _, roi, _ in self.items]) if self.items else None


def paint(job: PaintJob) -> tuple[Box | None, NDArray[np.float32] | None]:
    """The reflectance over the job's box (blurred, no vignetting): every target rendered in
    its region over the background level, each blurred by its own defocus; (None, None)
    when no target is in view."""
    box = job.box
    if box is None:
        return None, None
    bx, by = box[0], box[1]
    patch = np.full((box[3] - by, box[2] - bx), job.level, dtype=np.float32)
    for placement, (x0, y0, x1, y1), sigma in job.items:
        value: NDArray[np.floating[Any]]
        alpha: NDArray[np.floating[Any]]
        if isinstance(placement, ToolPlacement):
            value, alpha = render_tool_region(
                job.model, placement, (x0, y0, x1, y1), supersample=job.supersample,
                offset_px=job.offset_px,
            )  # fmt: skip
        else:
            render = render_slide if placement.target.markers else render_region
            value, alpha = render(
                job.model, placement, (x0, y0, x1, y1), supersample=job.supersample,
                offset_px=job.offset_px, reflectance=job.reflectance,
            )  # fmt: skip
        region = patch[y0 - by : y1 - by, x0 - bx : x1 - bx]
        blend = value - region
        blend *= alpha
        blend += region
        region[...] = cv2.GaussianBlur(blend, (0, 0), sigma)
    return box, patch


def _unpainted() -> tuple[Box | None, NDArray[np.float32] | None]:
    raise RuntimeError("a frame let pass (SimCamera.pass_frame) has no pixels")


def paint_here(job: PaintJob) -> Painted:
    """Paint a frame now, in this process (a :class:`SimCamera`'s default painter)."""
    done = paint(job)
    return lambda: done


def _bounding_box(boxes: list[Box]) -> Box:
    """The smallest box (x0, y0, x1, y1) holding every box of the list."""
    x0, y0, x1, y1 = zip(*boxes, strict=True)
    return min(x0), min(y0), max(x1), max(y1)


def _dn_and_spread(
    image: FloatArray32, vignette: FloatArray32, gain: np.float32, k: np.float32, read2: np.float32
) -> tuple[FloatArray32, FloatArray32]:
    """Mean DN (``image`` scaled in place) and the noise's std in DN, both (h, w) float32.

    ``image`` is reflectance, ``vignette`` the light kept, ``gain`` DN of reflectance 1,
    ``k`` DN per electron, ``read2`` the read noise's variance in DN^2.
    """
    dn = image
    dn *= vignette
    dn *= gain
    spread = np.multiply(dn, k)
    np.maximum(spread, 0, out=spread)
    spread += read2
    np.sqrt(spread, out=spread)
    return dn, spread


def _quantise(
    dn: FloatArray32, noise: FloatArray32, top: int, dtype: type[np.unsignedinteger]
) -> NDArray[np.unsignedinteger]:
    """``clip(rint(dn + noise), 0, top)`` (round half to even) as ``dtype``, (h, w)."""
    if dtype == np.uint8 and top == 255:  # one pass, the same rounding and saturation
        out: NDArray[np.unsignedinteger] = cv2.add(dn, noise, dtype=cv2.CV_8U)
        return out
    total = dn + noise
    np.rint(total, out=total)
    np.clip(total, 0, top, out=total)
    return total.astype(dtype)
