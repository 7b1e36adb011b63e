"""A tool's tip point in {G} from its taper's vertex and axis seen by two or more cameras.

The vertex where a taper's edges meet is a fixed point of the tool (a jaw's plate's corner,
a cone's apex: every silhouette generator passes through it), so the cameras' vertices
(:func:`~microcal.vision.tip_wedge.fit_wedge`, in ideal pixels) triangulate like any point.
The tool's axis in {G} is the direction ``a`` whose image is each camera's axis: with ``J_i``
the camera's projection Jacobian at the vertex and ``m_i`` the normal of its image axis,
``m_i^T J_i a = 0`` for every camera (the null direction of the stacked rows). The tip point
(``docs/conventions.md``) lies on the axis at the distance the tool's size gives:
``r / sin(alpha)`` from the vertex for a rounded end (needle, jaw: the centre of a circle of
radius ``r`` tangent to a taper of half-angle ``alpha``), ``r / tan(alpha)`` for a pipette's
opening. That needs a spec with the taper and the end's size (``tip:jaw:30:40``).

Its covariance: the triangulated vertex's plus the axis's, the latter from each camera's
axis angle variance moved through ``a`` (numerically). Apart from it,
:func:`vertex_model_cov_um2` gives the part that frames and poses do not average away: the
vertex fit's own error along each camera's axis (:data:`VERTEX_ALONG_MODEL_PX`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..geometry import AnyCamera, triangulate_views
from .detect import to_gray
from .tip import detect_tip
from .tip_target import TipTarget
from .tip_wedge import fit_wedge

__all__ = [
    "VERTEX_ALONG_MODEL_PX",
    "VertexView",
    "camera_vertex",
    "takes_3d_vertex_path",
    "tip_from_vertices",
    "vertex_model_cov_um2",
]

#: The vertex's error along its image axis that is not noise, px (1 sigma): the thesis-gripper's
#: jaw without noise, seen by the true cameras at ten poses over the travel, has its vertex
#: 0.016-0.026 px towards the shank on the top camera and -0.002 to +0.021 px on the side
#: camera (0.2-0.5 µm along the jaw in {G}). It changes slowly over the travel, so frames and
#: poses do not average it away.
VERTEX_ALONG_MODEL_PX = 0.02


@dataclass(frozen=True)
class VertexView:
    """One camera's view of a taper over a pose's frames.

    Attributes
    ----------
    vertex_px : (2,) float
        The vertex, mean over the frames, ideal pixels.
    cov_px2 : (2, 2) float
        Covariance of that mean.
    axis : (2,) float
        The image axis (unit, vertex towards shank), mean over the frames.
    axis_var : float
        Variance of the mean axis's angle, rad^2.
    frames : int
    edges : (2, 2) float
        The edges' unit directions (vertex towards shank), the axis's left one first.
    edge_vars : (2,) float
        Variances of the mean edges' angles, rad^2.
    """

    vertex_px: FloatArray
    cov_px2: FloatArray
    axis: FloatArray
    axis_var: float
    frames: int
    edges: FloatArray
    edge_vars: FloatArray


def takes_3d_vertex_path(target: TipTarget) -> bool:
    """Whether a tool's tip point is taken from its vertex and axis in 3D: a jaw whose spec
    gives its taper and end's size (a needle's cone would take its axis from its image
    bisector, :func:`tip_from_vertices`, but is not measured this way yet)."""
    return target.kind == "jaw" and target.taper_deg > 0 and target.tip_um > 0


def vertex_to_tip_um(target: TipTarget) -> float:
    """Distance from the taper's vertex to the tip point along the axis, µm."""
    r, a = 0.5 * target.tip_um, target.half_angle_rad
    return r / math.tan(a) if target.kind == "pipette" else r / math.sin(a)


def camera_vertex(
    frames: Sequence[NDArray[np.generic]], target: TipTarget, camera: AnyCamera
) -> VertexView | str:
    """The taper's vertex and axis in one camera's frames of a pose (or why not).

    The tool is found in the first frame (:func:`~microcal.vision.tip.detect_tip`, the model
    fit; again in a frame where the edges' fit from it fails), then its edges fitted in each
    (:func:`~microcal.vision.tip_wedge.fit_wedge`); the frames' vertices are averaged and
    their covariance is the fits' mean over the frames' count. A frame whose fit fails is
    left out; when half or more fail, the last reason is the answer.
    """
    J = np.asarray(camera.project_jacobian(np.zeros(3), distort=False), dtype=np.float64)
    s = np.linalg.svd(J.reshape(2, 3), compute_uv=False)
    end_px = 0.5 * target.tip_um / math.tan(target.half_angle_rad) * math.sqrt(s[0] * s[1])
    vs, covs, axes, avars, edges, evars = [], [], [], [], [], []
    det = None
    why = "no frames"
    for image in frames:
        gray = to_gray(np.asarray(image))
        # the tool stands still during a pose: the first frame's detection starts every fit
        fit = fit_wedge(gray, camera, det, end_px=end_px) if det is not None else None
        if fit is None or isinstance(fit, str):
            found = detect_tip(gray, target, method="model fit")
            if not found.found:
                why = found.reason
                continue
            det = found
            fit = fit_wedge(gray, camera, det, end_px=end_px)
        if isinstance(fit, str):
            why = fit
            continue
        vs.append(fit.vertex_px)
        covs.append(fit.cov[:2, :2])
        axes.append(fit.axis)
        avars.append(fit.axis_angle_var)
        edges.append(fit.edges)
        evars.append(fit.edge_vars)
    n = len(vs)
    if 2 * n < len(frames) or n == 0:  # a frame may fail; most must not
        return why
    axis = np.mean(axes, axis=0)
    axis /= np.linalg.norm(axis)
    e = np.mean(edges, axis=0)
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    return VertexView(np.mean(vs, axis=0), np.mean(covs, axis=0) / n, axis,
                      float(np.mean(avars)) / n, n, e, np.mean(evars, axis=0) / n)  # fmt: skip


def _axis_3d(
    cameras: Sequence[AnyCamera], x_um: FloatArray, axes: Sequence[FloatArray]
) -> FloatArray:
    """The unit direction in {G} whose image is each camera's axis at ``x_um``, (3,)."""
    rows, Js = [], []
    for cam, ax in zip(cameras, axes, strict=True):
        J = np.asarray(cam.project_jacobian(x_um, distort=False), dtype=np.float64).reshape(2, 3)
        Js.append(J)
        rows.append(np.array([-ax[1], ax[0]]) @ J)
    a: FloatArray = np.linalg.svd(np.array(rows))[2][-1]
    if sum(float((J @ a) @ ax) for J, ax in zip(Js, axes, strict=True)) < 0:
        a = -a
    return a


def _turned(v: FloatArray, angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _direction(
    cameras: Sequence[AnyCamera],
    x_um: FloatArray,
    dirs: Sequence[FloatArray],
    vars_: Sequence[float],
) -> tuple[FloatArray, FloatArray]:
    """A line's unit direction in {G} from its image directions at ``x_um`` (3,), and its
    covariance (3, 3) from the image angles' variances (numerically)."""
    a = _axis_3d(cameras, x_um, dirs)
    cov = np.zeros((3, 3))
    step = 1e-4
    for i, var in enumerate(vars_):
        turned = list(dirs)
        turned[i] = _turned(dirs[i], step)
        g = (_axis_3d(cameras, x_um, turned) - a) / step
        cov += np.outer(g, g) * var
    return a, cov


def _plate_axis(
    cameras: Sequence[AnyCamera], x_um: FloatArray, views: Sequence[VertexView], angle: float
) -> tuple[FloatArray, FloatArray]:
    """A flat taper's axis in {G}: the bisector of its two edges, each a line in {G} from the
    cameras' images of it (the image's bisector is not the axis's image when the plate is
    seen aslant). Which edge is which in each camera: the pairing with the first camera whose
    edges meet at the taper's known ``angle``."""
    edges = [v.edges for v in views]
    vars_ = [v.edge_vars for v in views]
    for i in range(1, len(views)):
        spreads = []
        for order in (edges[i], edges[i][::-1]):
            g = [_axis_3d([cameras[0], cameras[i]], x_um, [edges[0][k], order[k]]) for k in (0, 1)]
            spreads.append(abs(math.acos(float(np.clip(g[0] @ g[1], -1.0, 1.0))) - angle))
        if spreads[1] < spreads[0]:
            edges[i], vars_[i] = edges[i][::-1].copy(), vars_[i][::-1].copy()
    g0, c0 = _direction(cameras, x_um, [e[0] for e in edges], [v[0] for v in vars_])
    g1, c1 = _direction(cameras, x_um, [e[1] for e in edges], [v[1] for v in vars_])
    s = g0 + g1
    norm = float(np.linalg.norm(s))
    P = (np.eye(3) - np.outer(s, s) / norm**2) / norm
    return s / norm, P @ (c0 + c1) @ P.T


def tip_from_vertices(
    views: Mapping[str, VertexView], cameras: Mapping[str, AnyCamera], target: TipTarget
) -> tuple[FloatArray, FloatArray] | str:
    """The tip point in {G} (3,) and its covariance (3, 3), µm, from two or more cameras'
    vertices and axes (see the module); or why not."""
    names = [n for n in cameras if n in views]
    if len(names) < 2:
        return f"the taper's vertex is seen by {len(names)} camera(s), two are needed"
    cams = [cameras[n] for n in names]
    p, c, _ = triangulate_views(cams, [views[n].vertex_px[None] for n in names],
                                [views[n].cov_px2 for n in names])  # fmt: skip
    x, cx = p[0], c[0]
    if not np.all(np.isfinite(x)):
        return "the cameras' vertices do not triangulate"
    length = vertex_to_tip_um(target)
    if target.kind == "jaw":
        a, cov_a = _plate_axis(cams, x, [views[n] for n in names], 2 * target.half_angle_rad)
    else:
        a, cov_a = _direction(cams, x, [views[n].axis for n in names],
                              [views[n].axis_var for n in names])  # fmt: skip
    tip: FloatArray = x + length * a
    return tip, cx + length**2 * cov_a


def vertex_model_cov_um2(
    views: Mapping[str, VertexView], cameras: Mapping[str, AnyCamera]
) -> FloatArray:
    """The tip point's covariance (3, 3) µm² from :data:`VERTEX_ALONG_MODEL_PX` along each
    camera's image axis, independent between cameras (to first order: each camera's vertex
    moved along its axis and the vertices triangulated again; the axis in {G} is left as it
    is). Zero when fewer than two cameras see the vertex."""
    names = [n for n in cameras if n in views]
    out: FloatArray = np.zeros((3, 3))
    if len(names) < 2:
        return out
    cams = [cameras[n] for n in names]
    covs = [views[n].cov_px2 for n in names]
    q = [views[n].vertex_px[None] for n in names]
    base = triangulate_views(cams, q, covs)[0][0]
    step = 0.1  # px: the triangulation is smooth at this scale
    for i, n in enumerate(names):
        moved = list(q)
        moved[i] = q[i] + step * views[n].axis
        d = (triangulate_views(cams, moved, covs)[0][0] - base) / step
        out = out + VERTEX_ALONG_MODEL_PX**2 * np.outer(d, d)
    return out
