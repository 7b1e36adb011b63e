"""The tip's depth from one camera and a focus drive: a focus sweep, or the tool's own
reference z-stack.

Both methods work on a ``grab_at_focus(z_um) -> frame`` callable (a frame an array or a
:class:`~microcal.vision.lazy_frame.RegionFrame`; the callable moves the focus, approaching
from one side, and grabs) and on the tip's region of the frame; each returns a
:class:`DepthEstimate`: the depth in the focus drive's coordinates (the focus reading at
which the tip point is in focus), its variance, and its cost in frames and seconds.

- :func:`depth_by_sweep`: frames at up to 15 focus positions around the tip. A tool seen
  at an angle is in focus at a different depth along its length, so the sharpness is taken
  in strips across the tool's image axis (the gradient energy of the tool, that of the
  background beside it removed), each strip's best focus found to a fraction of the step
  (``1 / S^2`` of a blurred edge is a parabola in the defocus), and a line through the
  strips' best focus against their position along the axis is read at the tip point (found
  along the axis where the tool's darkness begins, in the frame nearest its focus). The
  variance comes from the line's fit.
- :func:`depth_by_stack`: one frame against the tool's reference z-stack
  (:class:`ReferenceStack`, grabbed once at known focus offsets): the frame's window is
  aligned on the stack to a fraction of a pixel, then fitted as a mix of two neighbouring
  planes (plus an offset and a tilt of the light): the mix gives the focus offset between
  the planes. The alignment also gives the tip's x, y.
- :func:`depth_by_best_plane`: the peers' method, the baseline (the plane that correlates
  best wins: z in whole steps of the stack).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, check_number
from ..errors import DetectionError, InputError
from .detect import to_gray
from .lazy_frame import RegionFrame

__all__ = [
    "ALIGN_ACROSS_SIGMA_PX",
    "ALIGN_SIGMA_PX",
    "ANCHOR_SIGMA_PX",
    "INTERPOLATION_SIGMA",
    "LINEAR_ALIGN_SIGMA_PX",
    "MAX_SWEEP_FRAMES",
    "QUADRATIC_ALIGN_SIGMA_PX",
    "QUADRATIC_SIGMA",
    "STACK_ABOVE_UM",
    "SWEEP_APEX_SIGMA_PX",
    "SWEEP_DEPTH_FLOOR_UM",
    "SWEEP_DEPTH_OFFSET_UM",
    "DepthEstimate",
    "ReferenceStack",
    "axis_cov_px",
    "build_stack",
    "depth_by_best_plane",
    "depth_by_stack",
    "depth_by_sweep",
    "depth_from_stack_at",
    "grab_stack",
    "sweep_dither_um",
    "sweep_positions_um",
]

#: How far above the expected focus the stack method takes its frame, µm.
STACK_ABOVE_UM = 1.0
#: The most frames a focus sweep takes.
MAX_SWEEP_FRAMES = 15
#: The error of the interpolation between two planes of a stack ``s`` µm apart, 1 sigma:
#: ``a s + b s^2`` µm with ``(a, b)`` these (the blur does not change linearly between
#: planes; measured on the simulator's pipette, ``docs/vision.md``).
INTERPOLATION_SIGMA = (0.1, 0.06)
#: The error of the quadratic interpolation through three planes (the default), 1 sigma:
#: ``hypot(a, b s)`` µm with ``(a, b)`` these: a floor (the sample behind the tool differs
#: from the stack's) and a part growing with the spacing; measured on seeds 100-119 of the
#: ``patch`` preset against the truth less the stack's own focus error (0.068 µm at 0.5 µm
#: planes, 0.107 µm at 1 µm, 200 tips each, less the fit's own variance).
QUADRATIC_SIGMA = (0.045, 0.095)
#: The error of aligning a frame on a stack's best plane, 1 sigma per axis, px per µm of
#: the planes' spacing (measured as :data:`INTERPOLATION_SIGMA`): the baseline's.
ALIGN_SIGMA_PX = 1.0
#: The same with the planes' places interpolated (linear, quadratic): along the tool's image
#: axis ``hypot(a, b s)`` px with ``(a, b)`` these, ``s`` the spacing in µm (a tool seen at an
#: angle looks shifted along its axis when its focus changes, so the places between planes
#: are uncertain along it), and :data:`ALIGN_ACROSS_SIGMA_PX` across; measured against the
#: truth less the stack's own anchor error, which is stated apart
#: (:attr:`DepthEstimate.shared_cov_px`). Without the tool's axis, ``hypot(a, b s)`` per axis.
LINEAR_ALIGN_SIGMA_PX = (0.0, 0.65)
QUADRATIC_ALIGN_SIGMA_PX = (0.05, 0.8)
#: The alignment's error across the tool's axis, 1 sigma, px (the edges fix it).
ALIGN_ACROSS_SIGMA_PX = 0.03
#: Where the depth line, read at the tip point, lies above the tip point's focus, µm: the
#: strips' focus is that of the glass's edges, not of the axis (measured on the simulator's
#: pipette at NA 0.8, seeds 100-139, 200 tips: +0.028 µm, 0.026 µm 1 sigma); taken off. On
#: another tool or objective the remainder is a constant offset of the tip point, which a
#: calibration takes into its origin.
SWEEP_DEPTH_OFFSET_UM = 0.028
#: A floor of the depth's error, 1 sigma, µm: a strip's focus read between frames is off by
#: -0.02 to +0.01 µm depending on where it falls between them (seeds 100-109, 40 tips at
#: each of 7 places: 0.012 µm 1 sigma over the places), which :func:`sweep_dither_um`
#: spreads from sweep to sweep.
SWEEP_DEPTH_FLOOR_UM = 0.012
#: How well the sweep finds the tip's image, 1 sigma along the tool's image axis and across
#: it, px (measured as :data:`SWEEP_DEPTH_OFFSET_UM`: 0.20 and 0.50 px, mostly the tissue's
#: texture behind the tool, 0.05 px without it); the along part also moves the depth line's
#: reading.
SWEEP_APEX_SIGMA_PX = (0.20, 0.50)
#: A reference stack's anchor (the tip's image found by a sweep with the tool held at the
#: calibration's start pose), 1 sigma along and across the tool's image axis, px: measured on
#: seeds 100-139 of ``patch`` (40 anchors: 0.17 and 0.34 px), where sweeps at tips spread
#: over the working volume read 0.20 and 0.50 px (:data:`SWEEP_APEX_SIGMA_PX`; why is not
#: found: not the tip's height in the volume).
ANCHOR_SIGMA_PX = (0.17, 0.34)
#: The golden ratio's fractional part (the sweep's dither, :func:`sweep_dither_um`).
_GOLDEN = 0.6180339887498949
#: The stack methods compare images less their smooth part, a Gaussian of this sigma, px.
SMOOTH_PX = 5.0

Box = tuple[int, int, int, int]
Frame = RegionFrame | NDArray[np.generic]
GrabAtFocus = Callable[[float], Frame]


@dataclass(frozen=True)
class DepthEstimate:
    """The tip's depth from focus (and its image position where the method gives one).

    Attributes
    ----------
    z_um : float
        The focus drive's reading at which the tip point is in focus, µm.
    var_um2 : float
        Its variance, µm^2.
    frames : int
        Frames grabbed for it.
    seconds : float
        Time it took on the caller's clock, s.
    method : str
        ``"sweep"``, ``"stack"`` or ``"best plane"``.
    apex_px : (2,) float
        The tip point's image in the frame nearest its focus (NaN when not measured).
    cov_px : (2, 2) float
        Its covariance, px^2.
    focus_um : (K,) float
        The focus positions of the frames grabbed.
    shared_cov_px : (2, 2) float
        The part of :attr:`cov_px` that every estimate made with the same reference shares
        (a stack's anchor: its error moves all of them alike), px^2; zero for the sweep.
    shared_var_um2 : float
        The part of :attr:`var_um2` shared alike (a stack's own focus), µm^2.
    cov_z_px : (2,) float
        Covariance of :attr:`z_um` with :attr:`apex_px`, µm px (the sweep reads the depth
        where it finds the tip along the tool's axis, so the two errors go together).
    """

    z_um: float
    var_um2: float
    frames: int
    seconds: float
    method: str
    apex_px: FloatArray = field(default_factory=lambda: np.full(2, np.nan))
    cov_px: FloatArray = field(default_factory=lambda: np.full((2, 2), np.nan))
    focus_um: FloatArray = field(default_factory=lambda: np.zeros(0))
    shared_cov_px: FloatArray = field(default_factory=lambda: np.zeros((2, 2)))
    shared_var_um2: float = 0.0
    cov_z_px: FloatArray = field(default_factory=lambda: np.zeros(2))

    @property
    def sigma_um(self) -> float:
        """Standard deviation of :attr:`z_um`, µm."""
        return math.sqrt(self.var_um2)


def _window(frame: Frame, box: Box) -> NDArray[np.float32]:
    """The frame's pixels over ``box`` as float32 grey."""
    x0, y0, x1, y1 = box
    if isinstance(frame, np.ndarray):
        return to_gray(frame[y0:y1, x0:x1])
    return to_gray(np.asarray(frame.region(x0, y0, x1, y1)))


def _shape_of(frame: Frame) -> tuple[int, int]:
    h, w = frame.shape[:2]
    return int(h), int(w)


def _check_box(box: Box, shape: tuple[int, int]) -> Box:
    h, w = shape
    x0, y0, x1, y1 = (int(v) for v in box)
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h or x1 - x0 < 16 or y1 - y0 < 16:
        raise InputError(
            f"tip region: expected a box of at least 16 x 16 px inside the {w} x {h} frame, "
            f"got {tuple(box)} (is the tip outside the field?)"
        )
    return x0, y0, x1, y1


def axis_cov_px(axis_px: Sequence[float] | FloatArray, along_px: float, across_px: float
                ) -> FloatArray:  # fmt: skip
    """A covariance of ``along_px`` (1 sigma) along the image direction ``axis_px`` (2,) and
    ``across_px`` across it, (2, 2) px^2."""
    a = _unit(axis_px)
    n = np.array([-a[1], a[0]])
    out: FloatArray = along_px**2 * np.outer(a, a) + across_px**2 * np.outer(n, n)
    return out


def _unit(axis_px: Sequence[float] | FloatArray) -> FloatArray:
    a = np.asarray(axis_px, dtype=np.float64)
    n = float(np.linalg.norm(a)) if a.shape == (2,) else math.nan
    if not (math.isfinite(n) and n > 0):
        raise InputError(f"axis_px: expected a non-zero 2-vector, got {axis_px!r}")
    out: FloatArray = a / n
    return out


# --- the focus sweep ------------------------------------------------------------------------


def sweep_positions_um(centre_um: float, frames: int = 13, step_um: float = 0.5) -> FloatArray:
    """The sweep's focus positions, ascending, (frames,) µm: ``step_um`` apart about
    ``centre_um`` moved by :func:`sweep_dither_um` (at most half a step)."""
    n = int(check_number("frames", frames, low=5, high=MAX_SWEEP_FRAMES, integer=True))
    check_number("step_um", step_um, above=0, high=10)
    centre = centre_um + sweep_dither_um(centre_um, step_um)
    out: FloatArray = np.asarray(centre + step_um * (np.arange(n) - (n - 1) / 2.0), np.float64)
    return out


def sweep_dither_um(centre_um: float, step_um: float) -> float:
    """How far the sweep's frames are moved from ``centre_um``, µm, in ``[-step/2, step/2)``.

    A strip's focus is read between frames by a parabola, which puts it a little off by an
    amount that depends on where the focus falls between two frames: on the simulator's
    pipette -0.02 µm when the tip's focus is on a frame, +0.01 µm a third of a step from it
    (``docs/vision.md``). A sweep centred on a good prior (a tip looked for again where it
    was found, the focus following a calibrated model) would put every tip on a frame and
    repeat the same error; moved by a fraction of the step that changes with the centre (the
    fractional part of a large multiple of it: deterministic, so a run and its resumption
    agree), the error varies from sweep to sweep about its mean, which the depth's offset
    and floor state (:data:`SWEEP_DEPTH_OFFSET_UM`, :data:`SWEEP_DEPTH_FLOOR_UM`).
    """
    fraction = math.fmod(abs(centre_um) * 1000.0 * _GOLDEN, 1.0)
    return float(step_um * (fraction - 0.5))


@dataclass(frozen=True)
class _Strips:
    """Pixel masks of strips across the tool and of the background beside it."""

    origin: FloatArray  # (2,) the strips' origin in the region, px
    offsets_px: FloatArray  # (J,) position of each strip along the axis, from the origin
    tool: list[NDArray[np.bool_]]
    background: list[NDArray[np.bool_]]
    along: FloatArray  # (h, w) position along the axis of each pixel
    across: FloatArray  # (h, w) signed distance from the axis


def _strips(shape: tuple[int, int], origin: FloatArray, axis: FloatArray, half_px: float,
            width_px: float, reach_px: float) -> _Strips:  # fmt: skip
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    dx, dy = xx - origin[0], yy - origin[1]
    along = dx * axis[0] + dy * axis[1]
    across = -dx * axis[1] + dy * axis[0]
    offsets = np.arange(-2.0 * width_px, reach_px + 1e-9, width_px)
    tool, bg = [], []
    for s in offsets:
        band = np.abs(along - s) <= width_px / 2.0
        tool.append(band & (np.abs(across) <= half_px))
        bg.append(band & (np.abs(across) > half_px + 6.0) & (np.abs(across) <= 2 * half_px + 6))
    return _Strips(np.asarray(origin, dtype=np.float64), offsets, tool, bg, along, across)


def _gradient_energy(gray: NDArray[np.float32]) -> NDArray[np.float32]:
    """Squared gradient of a lightly smoothed image, relative to its mean light."""
    g = cv2.GaussianBlur(gray, (0, 0), 0.8)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    out: NDArray[np.float32] = (gx * gx + gy * gy) / np.float32(max(float(g.mean()), 1e-6) ** 2)
    return out


def _peak_of(z: FloatArray, s: FloatArray) -> tuple[float, float] | None:
    """The focus of a strip's sharpness ``s`` (K,) over ``z`` (K,): vertex of the parabola
    fitted to ``1 / s^2`` around the sharpest frame, and its variance; None when the
    sharpest frame is at the sweep's end or the strip shows no tool."""
    k = int(np.argmax(s))
    if k == 0 or k == len(s) - 1 or s[k] <= 0:
        return None
    lo, hi = max(0, k - 2), min(len(s), k + 3)
    ok = s[lo:hi] > 0.05 * s[k]
    zz, yy = z[lo:hi][ok], 1.0 / s[lo:hi][ok] ** 2
    if len(zz) < 3:
        return None
    zc = zz - z[k]
    A = np.column_stack([np.ones_like(zc), zc, zc * zc])
    wts = 1.0 / yy  # relative errors of s: errors of 1/s^2 grow with it
    coef, *_ = np.linalg.lstsq(A * wts[:, None], yy * wts, rcond=None)
    _, c1, c2 = coef
    if c2 <= 0:
        return None
    vertex = -c1 / (2 * c2)
    step = float(np.median(np.diff(z)))
    if abs(vertex) > 1.5 * step:
        return None
    res = (A @ coef - yy) * wts
    dof = max(len(zz) - 3, 1)
    s2 = float(res @ res) / dof if len(zz) > 3 else 0.0
    cov = np.linalg.pinv((A * wts[:, None]).T @ (A * wts[:, None])) * max(s2, 1e-12)
    grad = np.array([0.0, -1.0 / (2 * c2), c1 / (2 * c2 * c2)])
    var = float(grad @ cov @ grad)
    return float(z[k] + vertex), var


def depth_by_sweep(
    grab_at_focus: GrabAtFocus,
    region: Box,
    axis_px: Sequence[float] | FloatArray,
    centre_um: float,
    *,
    frames: int = 13,
    step_um: float = 0.5,
    half_width_px: float = 10.0,
    strip_px: float = 3.0,
    reach_px: float = 24.0,
    end_offset_px: float = 0.0,
    clock: Callable[[], float] = time.perf_counter,
) -> DepthEstimate:
    """The tip's depth by a focus sweep (see the module docstring).

    Parameters
    ----------
    grab_at_focus : callable
        ``grab_at_focus(z_um)`` moves the focus to ``z_um`` and returns a frame.
    region : (x0, y0, x1, y1)
        The tip's region (end exclusive), the tip near its middle, the tool's shank
        leaving it along ``axis_px``.
    axis_px : (2,) float
        The tool's direction in the image, from the tip towards the shank.
    centre_um : float
        Where the tip is expected in focus (the sweep is centred there).
    frames, step_um : int, float
        The sweep: at most :data:`MAX_SWEEP_FRAMES` frames ``step_um`` apart.
    half_width_px, strip_px, reach_px : float
        Half the width of the strips across the tool, their length along it, and how far
        behind the tip they go.
    end_offset_px : float
        The tip point's distance behind where the tool's darkness begins along its axis, px
        (a pipette's opening seen at an angle: its radius times the sine of the angle).
    clock : callable
        The time source the cost is measured on (the rig's clock for simulated time).

    Returns
    -------
    DepthEstimate
        ``method="sweep"``, with the tip point's image (its position along the axis from
        the frame nearest its focus; across from the strips' centre line).

    Raises
    ------
    InputError
        A region outside the frame, a bad axis or sweep.
    DetectionError
        No strip's focus inside the sweep: the tip is outside the focus range swept, or no
        tool in the region.
    """
    axis = _unit(axis_px)
    zs = sweep_positions_um(centre_um, frames, step_um)
    t0 = clock()
    windows: list[NDArray[np.float32]] = []
    for z in zs:
        frame = grab_at_focus(float(z))
        if not windows:
            region = _check_box(region, _shape_of(frame))
        windows.append(_window(frame, region))
    x0, y0, x1, y1 = region
    origin = np.array([(x1 - x0 - 1) / 2.0, (y1 - y0 - 1) / 2.0])
    energies = [_gradient_energy(w) for w in windows]
    strips = _centred_strips(windows, energies, origin, axis, half_width_px, strip_px, reach_px)
    origin = strips.origin
    sharp = np.array(  # (J strips, K frames)
        [
            [float(e[t].mean() - e[b].mean()) for e in energies]
            for t, b in zip(strips.tool, strips.background, strict=True)
        ]
    )
    # where the tool begins: first in the sharpest frame, then in the frame nearest the tip's focus
    k = int(np.argmax(np.clip(sharp, 0.0, None).sum(axis=0)))
    start, _ = _tool_start(windows[k], strips, half_width_px)
    peaks = [(s, _peak_of(zs, sharp[j])) for j, s in enumerate(strips.offsets_px)
             if s >= start + 1.0]  # fmt: skip
    found = [(s, p) for s, p in peaks if p is not None]
    if len(found) < 3:
        raise DetectionError(
            f"focus sweep: the tip's focus is not inside the sweep {zs[0]:.1f} to {zs[-1]:.1f} "
            f"µm (or no tool in the region): {len(found)} of {len(peaks)} strips peaked inside"
        )
    a, g, cov = _line(np.array([s for s, _ in found]), np.array([p[0] for _, p in found]),
                      np.array([max(p[1], 1e-4) for _, p in found]))  # fmt: skip
    k = int(np.argmin(np.abs(zs - (a + g * start))))
    start, centre_line = _tool_start(windows[k], strips, half_width_px)
    tip_s = start + end_offset_px
    z_tip = a + g * tip_s - SWEEP_DEPTH_OFFSET_UM
    var = float(np.array([1.0, tip_s]) @ cov @ np.array([1.0, tip_s]))
    along, across = SWEEP_APEX_SIGMA_PX
    var += (g * along) ** 2 + SWEEP_DEPTH_FLOOR_UM**2  # the start's error; between frames
    apex = np.array([x0, y0]) + origin + tip_s * axis + centre_line * np.array([-axis[1], axis[0]])
    cov_px = axis_cov_px(axis, along, across)
    cov_z = g * along**2 * axis  # the start's error moves the apex and the depth alike
    return DepthEstimate(z_tip, var, len(zs), clock() - t0, "sweep", apex, cov_px, zs,
                         cov_z_px=cov_z)  # fmt: skip


#: The strips follow the tool's centre line across the axis until it is this close to theirs,
#: px, at most :data:`RECENTRE_ROUNDS` times (a centroid inside a band about the expected line
#: is pulled towards that line when the tool lies beside it).
RECENTRE_PX = 0.1
RECENTRE_ROUNDS = 8


def _centred_strips(
    windows: list[NDArray[np.float32]],
    energies: list[NDArray[np.float32]],
    origin: FloatArray,
    axis: FloatArray,
    half_px: float,
    strip_px: float,
    reach_px: float,
) -> _Strips:
    """The strips about the tool's own centre line: moved across the axis, from ``origin``
    (the region's middle), to the darkness's centre line in the sharpest frame until they
    sit on it. A tool that leaves the region across the axis is refused."""
    k = int(np.argmax([float(e.mean()) for e in energies]))
    normal = np.array([-axis[1], axis[0]])
    h, w = windows[0].shape
    for _ in range(RECENTRE_ROUNDS):
        strips = _strips((h, w), origin, axis, half_px, strip_px, reach_px)
        _, across = _tool_start(windows[k], strips, half_px)
        if abs(across) <= RECENTRE_PX:
            break
        origin = origin + across * normal
        if not (
            half_px <= origin[0] <= w - 1 - half_px and half_px <= origin[1] <= h - 1 - half_px
        ):
            raise DetectionError(
                "focus sweep: the tool lies beside the tip's region, not through it "
                "(the tip is far from where it was looked for)"
            )
    return strips


def _line(s: FloatArray, z: FloatArray, v: FloatArray) -> tuple[float, float, FloatArray]:
    """``z = a + g s`` weighted by ``1 / v``, outliers (beyond 3 sigma) dropped: a, g and
    their covariance (scaled by the residuals when they exceed ``v``)."""
    keep = np.ones(len(s), dtype=bool)
    for _ in range(3):
        A = np.column_stack([np.ones(int(keep.sum())), s[keep]])
        wv = 1.0 / v[keep]
        N = A.T @ (A * wv[:, None])
        coef = np.linalg.solve(N, A.T @ (z[keep] * wv))
        res = z - (coef[0] + coef[1] * s)
        chi2 = float(res[keep] ** 2 @ wv) / max(int(keep.sum()) - 2, 1)
        scale = math.sqrt(max(chi2, 1.0))
        new = np.abs(res) <= 3.0 * scale * np.sqrt(v)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
    cov: FloatArray = np.asarray(np.linalg.inv(N) * scale**2, dtype=np.float64)
    return float(coef[0]), float(coef[1]), cov


def _tool_start(gray: NDArray[np.float32], strips: _Strips, half_px: float) -> tuple[float, float]:
    """Where the tool's darkness begins along the axis, px from the strips' origin (where the
    mean darkness across the tool rises to half its level just behind the tip), and the
    tool's centre line across the axis there, px."""
    along, across = strips.along, strips.across
    beside = (np.abs(across) > half_px + 6.0) & (np.abs(across) <= 2 * half_px + 6)
    inside = np.abs(across) <= half_px
    bins = np.arange(math.floor(along.min()), math.ceil(along.max()) + 1)
    idx = np.digitize(along, bins)
    centres = np.full(len(bins) + 1, np.nan)
    dark = np.full(len(centres), np.nan)
    sway = np.full(len(centres), np.nan)
    rel = np.zeros_like(gray)
    for i in np.unique(idx):
        m = idx == i
        t, b = m & inside, m & beside
        if t.sum() > 3 and b.sum() > 3:
            # where the bin's tool pixels lie along the axis: its middle only on average (a
            # tool along a pixel row puts every pixel on the bin's lower edge)
            centres[i] = float(np.mean(along[t]))
            bg = float(np.median(gray[b]))
            rel[m] = np.abs(gray[m] - bg) / max(bg, 1e-6)
            dark[i] = float(np.mean(rel[t]))
            wts = rel[t]
            sway[i] = float(np.sum(wts * across[t]) / max(float(wts.sum()), 1e-9))
    ok = np.isfinite(dark)
    c, d, sw = centres[ok], dark[ok], sway[ok]
    sm = np.convolve(d, np.ones(3) / 3.0, mode="same")
    start = 0.0
    front_at, behind_at = (-1e9, -8.0), (4.0, 14.0)  # first about the region's middle
    for _ in range(3):
        front = d[(c > front_at[0]) & (c < front_at[1])]
        behind = d[(c > behind_at[0]) & (c < behind_at[1])]
        if len(front) == 0 or len(behind) == 0:
            break
        half = 0.5 * (float(np.median(front)) + float(np.median(behind)))
        for i in range(1, len(c)):
            if c[i] > front_at[1] and sm[i - 1] < half <= sm[i]:
                start = float(c[i - 1] + (half - sm[i - 1]) / (sm[i] - sm[i - 1]))
                break
        front_at, behind_at = (start - 14.0, start - 5.0), (start + 4.0, start + 12.0)
    line = sw[(c > start + 2.0) & (c < start + 12.0)]
    return _edge_fit(c, d, start), float(np.median(line)) if len(line) else 0.0


def _edge_fit(c: FloatArray, d: FloatArray, start: float) -> float:
    """The tool's start refined: a blurred step with a sloping top fitted to the darkness
    profile ``d`` over ``c`` within 12 px of ``start``."""
    from scipy.optimize import least_squares
    from scipy.special import erf

    m = np.abs(c - start) <= 12.0
    cc, dd = c[m], d[m]
    if len(cc) < 8:
        return start

    def model(p: FloatArray) -> FloatArray:
        a0, sig, lo, hi, slope = p
        step = 0.5 * (1.0 + erf((cc - a0) / (math.sqrt(2.0) * abs(sig) + 1e-6)))
        out: FloatArray = lo + (hi - lo + slope * (cc - a0)) * step
        return out

    front, behind = dd[cc < start - 3], dd[cc > start + 3]
    p0 = np.array([start, 1.5, float(np.median(front)) if len(front) else 0.0,
                   float(np.median(behind)) if len(behind) else 0.2, 0.0])  # fmt: skip
    fit = least_squares(lambda p: model(p) - dd, p0, method="lm")
    a0 = float(fit.x[0])
    return a0 if fit.success and abs(a0 - start) < 6.0 else start


# --- the reference z-stack -----------------------------------------------------------------


@dataclass(frozen=True)
class ReferenceStack:
    """The tool's own z-stack: windows around its tip at known focus offsets.

    Attributes
    ----------
    planes : (K, h, w) float32
        The windows less their smooth part, the tip at :attr:`anchor_px` in each.
    offsets_um : (K,) float
        Each plane's focus minus the tip's focus, µm (ascending, evenly spaced).
    anchor_px : (2,) float
        The tip point in the windows' pixels.
    focus_var_um2 : float
        Variance of the tip's focus the offsets count from (how well the calibration knew
        it), µm^2: it enters every depth measured with the stack.
    anchor_cov_px : (2, 2) float
        Covariance of :attr:`anchor_px`, px^2: it enters every tip position found with it.
    axis_px : (2,) float or None
        The tool's direction in the image, tip to shank, where known: the alignment's error
        is then stated along and across it.
    """

    planes: NDArray[np.float32]
    offsets_um: FloatArray
    anchor_px: FloatArray
    focus_var_um2: float = 0.0
    anchor_cov_px: FloatArray = field(default_factory=lambda: np.zeros((2, 2)))
    axis_px: FloatArray | None = None

    @property
    def step_um(self) -> float:
        """The planes' spacing, µm."""
        return float(self.offsets_um[1] - self.offsets_um[0])


def build_stack(
    frames: Sequence[Frame],
    offsets_um: Sequence[float] | FloatArray,
    tip_px: Sequence[float] | FloatArray,
    *,
    half_px: int = 24,
    focus_var_um2: float = 0.0,
    tip_cov_px: FloatArray | None = None,
    axis_px: Sequence[float] | FloatArray | None = None,
) -> ReferenceStack:
    """A reference stack from frames of the tool in one place, the focus at ``offsets_um``
    from the tip's focus (known to ``focus_var_um2``), the tip point's image at ``tip_px``
    (known to ``tip_cov_px``), the tool's image direction ``axis_px`` (2,) where known.

    Raises
    ------
    InputError
        Frames and offsets differ in number, fewer than 3 planes, uneven spacing, or the
        window leaves the frame.
    """
    off = np.asarray(offsets_um, dtype=np.float64)
    if len(frames) != len(off) or len(off) < 3:
        raise InputError(
            f"reference stack: expected 3 or more frames, one per offset, got {len(frames)} "
            f"frames and {len(off)} offsets"
        )
    order = np.argsort(off)
    d = np.diff(off[order])
    if np.any(d <= 0) or np.ptp(d) > 1e-6 * max(abs(float(d.mean())), 1.0):
        raise InputError("reference stack: expected evenly spaced, distinct focus offsets")
    tip = np.asarray(tip_px, dtype=np.float64)
    cx, cy = round(float(tip[0])), round(float(tip[1]))
    box = (cx - half_px, cy - half_px, cx + half_px + 1, cy + half_px + 1)
    shape = frames[0].shape[:2]
    box = _check_box(box, (int(shape[0]), int(shape[1])))
    planes = np.stack([_high_pass(_window(frames[i], box)) for i in order])
    anchor = tip - (box[0], box[1])
    cov = np.zeros((2, 2)) if tip_cov_px is None else np.asarray(tip_cov_px, dtype=np.float64)
    axis = None if axis_px is None else _unit(axis_px)
    return ReferenceStack(planes, off[order], anchor, float(focus_var_um2), cov, axis)


def grab_stack(
    grab_at_focus: GrabAtFocus,
    tip_focus_um: float,
    tip_px: Sequence[float] | FloatArray,
    *,
    reach_um: float = 4.0,
    step_um: float = 0.5,
    half_px: int = 24,
    tip_focus_var_um2: float = 0.0,
    tip_cov_px: FloatArray | None = None,
    axis_px: Sequence[float] | FloatArray | None = None,
) -> ReferenceStack:
    """Grab the tool's reference stack: frames at ``tip_focus_um + offsets`` from
    ``-reach_um`` to ``reach_um`` in steps of ``step_um`` (ascending), the tool held still;
    ``tip_focus_var_um2`` and ``tip_cov_px`` are the variance of ``tip_focus_um`` and the
    covariance of ``tip_px`` (from a focus sweep), ``axis_px`` the tool's image direction."""
    check_number("step_um", step_um, above=0, high=10)
    n = round(2 * reach_um / step_um) + 1
    offsets: FloatArray = np.asarray(step_um * (np.arange(n) - (n - 1) / 2.0), np.float64)
    frames = [grab_at_focus(float(tip_focus_um + o)) for o in offsets]
    return build_stack(frames, offsets, tip_px, half_px=half_px,
                       focus_var_um2=tip_focus_var_um2, tip_cov_px=tip_cov_px,
                       axis_px=axis_px)  # fmt: skip


def _high_pass(gray: NDArray[np.float32]) -> NDArray[np.float32]:
    """The image less its smooth part (a Gaussian of :data:`SMOOTH_PX`): the tool's edges
    stay, the slow shading of the light and of the sample behind the tool goes."""
    out: NDArray[np.float32] = gray - cv2.GaussianBlur(gray, (0, 0), SMOOTH_PX)
    return out


def _align(window: NDArray[np.float32], plane: NDArray[np.float32]) -> tuple[float, FloatArray]:
    """The correlation of ``plane`` in ``window`` (larger) and its sub-pixel place (x, y) of
    the plane's origin in the window."""
    score = cv2.matchTemplate(window, plane, cv2.TM_CCOEFF_NORMED)
    _, best, _, (bx, by) = cv2.minMaxLoc(score)
    h, w = score.shape
    dx = dy = 0.0
    if 0 < bx < w - 1:
        a, b, c = score[by, bx - 1], score[by, bx], score[by, bx + 1]
        den = a - 2 * b + c
        dx = 0.5 * (a - c) / den if den < 0 else 0.0
    if 0 < by < h - 1:
        a, b, c = score[by - 1, bx], score[by, bx], score[by + 1, bx]
        den = a - 2 * b + c
        dy = 0.5 * (a - c) / den if den < 0 else 0.0
    return float(best), np.array([bx + dx, by + dy])


def _stack_scores(
    frame: Frame, stack: ReferenceStack, near_px: Sequence[float] | FloatArray, search_px: int
) -> tuple[Box, NDArray[np.float32], FloatArray, FloatArray]:
    """The search window around ``near_px`` and every plane's correlation and place."""
    K, h, w = stack.planes.shape
    near = np.asarray(near_px, dtype=np.float64)
    x0 = round(float(near[0] - stack.anchor_px[0])) - search_px
    y0 = round(float(near[1] - stack.anchor_px[1])) - search_px
    box = (x0, y0, x0 + w + 2 * search_px, y0 + h + 2 * search_px)
    box = _check_box(box, _shape_of(frame))
    win = _high_pass(_window(frame, box))
    scores, places = np.zeros(K), np.zeros((K, 2))
    for k in range(K):
        scores[k], places[k] = _align(win, stack.planes[k])
    return box, win, scores, places


def depth_by_best_plane(
    frame: Frame,
    focus_um: float,
    stack: ReferenceStack,
    near_px: Sequence[float] | FloatArray,
    *,
    search_px: int = 12,
) -> DepthEstimate:
    """The peers' method: the plane that correlates best gives the offset (whole steps).

    The variance is that of a uniform error over one step (``step^2 / 12``).
    """
    t0 = time.perf_counter()
    box, _, scores, places = _stack_scores(frame, stack, near_px, search_px)
    k = int(np.argmax(scores))
    apex = np.array([box[0], box[1]]) + places[k] + stack.anchor_px
    var = stack.step_um**2 / 12.0 + stack.focus_var_um2
    return DepthEstimate(float(focus_um - stack.offsets_um[k]), var, 1,
                         time.perf_counter() - t0, "best plane", apex,
                         _apex_cov(stack, ALIGN_SIGMA_PX * stack.step_um), np.array([focus_um]),
                         shared_cov_px=stack.anchor_cov_px.copy(),
                         shared_var_um2=stack.focus_var_um2)  # fmt: skip


def depth_by_stack(
    frame: Frame,
    focus_um: float,
    stack: ReferenceStack,
    near_px: Sequence[float] | FloatArray,
    *,
    search_px: int = 12,
    min_score: float = 0.5,
    interpolation: str = "quadratic",
) -> DepthEstimate:
    """The tip's depth from one frame against the tool's reference stack (see the module
    docstring).

    Parameters
    ----------
    frame : (H, W) array or RegionFrame
        Grabbed with the focus at ``focus_um``.
    focus_um : float
    stack : ReferenceStack
    near_px : (2,) float
        Where the tip is expected in the frame (within ``search_px``).

    Raises
    ------
    InputError
        The search window leaves the frame.
    DetectionError
        No plane correlates (no tool like the reference there), or the best plane is the
        stack's first or last (the tip is outside the stack's focus range).
    """
    t0 = time.perf_counter()
    box, win, scores, places = _stack_scores(frame, stack, near_px, search_px)
    k = int(np.argmax(scores))
    if scores[k] < min_score:
        raise DetectionError(
            f"reference stack: no tool like the reference near the tip, or the tip far "
            f"outside the stack's focus range (best correlation {scores[k]:.2f}, at least "
            f"{min_score:g})"
        )
    K = len(scores)
    if k == 0 or k == K - 1:
        raise DetectionError(
            f"reference stack: the tip is outside the stack's focus range "
            f"({stack.offsets_um[0]:+.1f} to {stack.offsets_um[-1]:+.1f} µm from it)"
        )
    place = places[k]
    _, h, w = stack.planes.shape
    centre = (place[0] + (w - 1) / 2.0, place[1] + (h - 1) / 2.0)
    patch = cv2.getRectSubPix(win, (w, h), centre)
    step = stack.step_um
    if interpolation == "linear":
        j = k - 1 if scores[k - 1] >= scores[k + 1] else k  # the pair of planes around the tip
        t, var_t = _mix(patch, stack.planes[j], stack.planes[j + 1])
        offset = stack.offsets_um[j] + t * step
        tc = min(max(t, 0.0), 1.0)  # the planes' places, interpolated as their images are
        weights = np.array([1.0 - tc, tc])
        between = weights @ places[j : j + 2]
        a, b = INTERPOLATION_SIGMA
        var_interp = (a * step + b * step**2) ** 2
        align = _align_sigma(LINEAR_ALIGN_SIGMA_PX, step)
    elif interpolation == "quadratic":
        t, var_t = _mix_quadratic(patch, stack.planes[k - 1 : k + 2])
        offset = stack.offsets_um[k] + t * step
        between = _lagrange3(min(max(t, -1.0), 1.0)) @ places[k - 1 : k + 2]
        a, b = QUADRATIC_SIGMA
        var_interp = a**2 + (b * step) ** 2
        align = _align_sigma(QUADRATIC_ALIGN_SIGMA_PX, step)
    else:
        raise InputError(
            f"reference stack: interpolation must be 'quadratic' or 'linear', got {interpolation!r}"
        )
    apex = np.array([box[0], box[1]]) + between + stack.anchor_px
    var = var_t * step**2 + var_interp + stack.focus_var_um2
    return DepthEstimate(float(focus_um - offset), float(var), 1, time.perf_counter() - t0,
                         "stack", apex, _apex_cov(stack, *align), np.array([focus_um]),
                         shared_cov_px=stack.anchor_cov_px.copy(),
                         shared_var_um2=stack.focus_var_um2)  # fmt: skip


def _lagrange3(t: float) -> FloatArray:
    """The weights of three evenly spaced planes at ``-1, 0, 1`` read at ``t``, (3,)."""
    return np.array([0.5 * t * (t - 1.0), 1.0 - t * t, 0.5 * t * (t + 1.0)])


def _mix_quadratic(patch: NDArray[np.float32], planes: NDArray[np.float32]) -> tuple[float, float]:
    """``patch ~ c0 + cx x + cy y + g I(t)``, ``I(t)`` the quadratic through three planes
    (at ``t = -1, 0, 1``): the ``t`` of least squares (in ``[-1.5, 1.5]``) and its variance.

    The light's offset and tilt are projected out once; then the fit's residual at ``t`` is
    ``|p|^2 - (l.b)^2 / (l.G l)`` with ``l`` the weights at ``t``, ``G`` and ``b`` the three
    planes' Gram matrix and their products with the patch, so ``t`` is found on a fine grid
    and refined by a parabola; its variance is ``2 s^2`` over the residual's curvature.
    """
    h, w = patch.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = np.column_stack([np.ones(h * w), (xx.ravel() - w / 2) / w, (yy.ravel() - h / 2) / h])
    q, _ = np.linalg.qr(base)
    y = patch.ravel().astype(np.float64)
    P = planes.reshape(3, -1).T.astype(np.float64)
    y = y - q @ (q.T @ y)
    P = P - q @ (q.T @ P)
    G, b, yy2 = P.T @ P, P.T @ y, float(y @ y)
    ts = np.linspace(-1.5, 1.5, 301)
    L = np.stack([_lagrange3(float(t)) for t in ts])  # (T, 3)
    num = (L @ b) ** 2
    den = np.einsum("ti,ij,tj->t", L, G, L)
    rss = yy2 - num / np.maximum(den, 1e-12)
    i = int(np.argmin(rss))
    dt = ts[1] - ts[0]
    t = float(ts[i])
    curv = 0.0
    if 0 < i < len(ts) - 1:
        r0, r1, r2 = rss[i - 1], rss[i], rss[i + 1]
        curv = (r0 - 2 * r1 + r2) / dt**2
        if curv > 0:
            t += float(0.5 * dt * (r0 - r2) / (r0 - 2 * r1 + r2))
    s2 = float(rss[i]) / max(len(y) - 4, 1)
    var = 2.0 * s2 / curv if curv > 0 else 0.25
    return t, float(var)


def _align_sigma(along: tuple[float, float], step_um: float) -> tuple[float, float]:
    """The alignment's 1 sigma along the tool's axis (``hypot(a, b s)``) and across, px."""
    return math.hypot(along[0], along[1] * step_um), ALIGN_ACROSS_SIGMA_PX


def _apex_cov(stack: ReferenceStack, along_px: float, across_px: float | None = None
              ) -> FloatArray:  # fmt: skip
    """The tip's image found by the stack: the anchor's covariance (shared by every tip
    found with the stack) and the alignment's (against another sample behind the tool):
    ``along_px`` along the tool's axis and ``across_px`` across it, or ``along_px`` per axis
    where either is not known."""
    if stack.axis_px is None or across_px is None:
        own = np.eye(2) * along_px**2
    else:
        own = axis_cov_px(stack.axis_px, along_px, across_px)
    out: FloatArray = stack.anchor_cov_px + own
    return out


def depth_from_stack_at(
    grab_at_focus: GrabAtFocus,
    prior_um: float,
    stack: ReferenceStack,
    near_px: Sequence[float] | FloatArray,
    *,
    above_um: float = STACK_ABOVE_UM,
    clock: Callable[[], float] = time.perf_counter,
) -> DepthEstimate:
    """The stack method as a procedure: one frame ``above_um`` above the expected focus
    ``prior_um`` (where the shank rising through the focal plane is sharp), matched by
    :func:`depth_by_stack`; the cost counts the move and the frame on ``clock``."""
    t0 = clock()
    focus = float(prior_um) + float(above_um)
    frame = grab_at_focus(focus)
    est = depth_by_stack(frame, focus, stack, near_px)
    return dataclasses.replace(est, seconds=clock() - t0 + est.seconds)


def _mix(
    patch: NDArray[np.float32], a: NDArray[np.float32], b: NDArray[np.float32]
) -> tuple[float, float]:
    """``patch ~ c0 + cx x + cy y + u a + v b``: the mix ``t = v / (u + v)`` and its variance."""
    h, w = patch.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    A = np.column_stack([np.ones(h * w), (xx.ravel() - w / 2) / w, (yy.ravel() - h / 2) / h,
                         a.ravel().astype(np.float64), b.ravel().astype(np.float64)])  # fmt: skip
    y = patch.ravel().astype(np.float64)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    s2 = float(res @ res) / max(len(y) - 5, 1)
    cov = np.linalg.inv(A.T @ A) * s2
    u, v = float(coef[3]), float(coef[4])
    total = u + v
    if abs(total) < 1e-9:
        return 0.5, 0.25
    t = v / total
    grad = np.array([-v / total**2, u / total**2])  # d t / d (u, v)
    var = float(grad @ cov[3:, 3:] @ grad)
    return float(np.clip(t, -0.5, 1.5)), var
