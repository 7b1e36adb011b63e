"""Tools in the simulator: a glass pipette, a tungsten needle and a gripper jaw, under bright field.

A tool is a taper seen against the light: its outer edges are two straight generators that
meet at the taper's (virtual) vertex, and its end is rounded (needle, jaw) or open (pipette).
The *tip point* (``docs/conventions.md``) lies on the tool's axis: the centre of the rounded
end's sphere (needle) or circle (jaw), the centre of the opening's ring (pipette).

Rendering is exact in the camera's ideal (undistorted) pixels, for any camera of the
camera-model protocol (pinhole or affine):

- the silhouette's edges are the generators of the taper whose tangent plane holds the line
  of sight (a cone: ``cos psi = tan(alpha) / tan(phi)``, ``phi`` the angle between the axis
  and the line of sight; the jaw, a flat plate, shows its two edges), so they project to
  straight lines through the vertex's image under either projection;
- the end is the image of the sphere (needle), the rounded corner (jaw) or the ring
  (pipette), an ellipse from the projection's Jacobian at its centre, joined to the taper at
  the generators' points of contact;
- each pixel is S x S subsamples, each undistorted and box-filtered over its width;
- the pipette's glass bends the light away from the objective where the wall is steep: its
  transmission falls with the slope of the glass's path length across the tool, so the
  walls are two dark edges and the lumen is lighter;
- the blur grows with each point's distance from the focal plane, from the objective's
  numerical aperture (:class:`Optics`): diffraction in focus, the geometric circle of
  confusion off it;
- the background is a light field, uneven across the image, optionally with a tissue-like
  texture or debris; frames get shot and read noise and are quantised.

The module is self-contained: it uses the camera models only through their public protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, check_number
from ..errors import InputError
from ..geometry.affine_camera import AffineCamera
from ..geometry.camera_kinds import AnyCamera

__all__ = [
    "TOOL_KINDS",
    "Background",
    "Optics",
    "Tool",
    "ToolPlacement",
    "ToolScene",
    "ToolTruth",
    "expose",
    "microscope_camera",
    "render_tools",
    "tool_axis",
    "tool_image",
    "um_per_px",
]

ToolKind = Literal["pipette", "needle", "jaw"]
TOOL_KINDS: tuple[ToolKind, ...] = ("pipette", "needle", "jaw")
Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class Tool:
    """A tool's shape and material.

    Attributes
    ----------
    kind : {"pipette", "needle", "jaw"}
    taper_deg : float
        Full angle between the two outer edges of the taper, degrees (5-15 for a pipette).
    tip_um : float
        Diameter of the opening (pipette) or of the rounded end (needle, jaw), µm.
    wall : float
        A pipette's wall thickness as a fraction of its outer radius (0 < wall < 1).
    transmittance : float
        Light let through by an opaque tool (needle, jaw); the pipette's follows its glass.
    """

    kind: ToolKind
    taper_deg: float = 10.0
    tip_um: float = 1.0
    wall: float = 0.3
    transmittance: float = 0.06

    def __post_init__(self) -> None:
        if self.kind not in TOOL_KINDS:
            raise InputError(f"tool: expected one of {', '.join(TOOL_KINDS)}, got {self.kind!r}")
        check_number("taper_deg", self.taper_deg, above=0, high=90)
        check_number("tip_um", self.tip_um, above=0, high=1e4)
        check_number("wall", self.wall, above=0, high=0.95)
        check_number("transmittance", self.transmittance, low=0, high=1)

    @property
    def half_angle_rad(self) -> float:
        """Half the taper's angle, rad."""
        return math.radians(self.taper_deg) / 2.0

    @property
    def end_radius_um(self) -> float:
        """Radius of the rounded end (needle, jaw) or of the opening (pipette), µm."""
        return self.tip_um / 2.0

    @property
    def vertex_to_tip_um(self) -> float:
        """Distance from the taper's vertex to the tip point along the axis, µm.

        The centre of a sphere (circle) of radius r tangent to the taper is r / sin(alpha)
        from the vertex; the opening's ring of radius r is r / tan(alpha) from it.
        """
        a = self.half_angle_rad
        r = self.end_radius_um
        return r / math.tan(a) if self.kind == "pipette" else r / math.sin(a)


def microscope_camera(
    um_per_px: float = 0.65,
    size_px: tuple[int, int] = (256, 256),
    *,
    centre_um: FloatArray | None = None,
    name: str = "scope",
) -> AffineCamera:
    """A microscope's camera looking down (-z in {G}): telecentric, no distortion.

    ``um_per_px`` is the pixel's size in the object (a 10x objective on 6.5 µm pixels: 0.65);
    ``centre_um`` is the world point at the image's centre (the origin by default), at 1 mm
    depth.
    """
    check_number("um_per_px", um_per_px, above=0)
    m = 1.0 / um_per_px
    w, h = size_px
    c = np.zeros(3) if centre_um is None else np.asarray(centre_um, dtype=np.float64)
    K = np.array([[m, 0.0, (w - 1) / 2], [0.0, m, (h - 1) / 2], [0.0, 0.0, 1.0]])
    R = np.diag([1.0, -1.0, -1.0])
    t = -R @ c + np.array([0.0, 0.0, 1000.0])
    return AffineCamera(K, np.zeros(5), R, t, (int(w), int(h)), name=name)


def tool_axis(elevation_deg: float, azimuth_deg: float) -> FloatArray:
    """The unit direction from a tool's tip towards its shank, (3,).

    ``elevation_deg`` above the x-y plane (the image plane of a camera looking along -z),
    ``azimuth_deg`` from +x towards +y.
    """
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


@dataclass(frozen=True)
class ToolPlacement:
    """A tool in the world {G}: its tip point, its axis and (a jaw) the normal of its plate.

    Attributes
    ----------
    tool : Tool
    tip_um : (3,) float
        The tip point in {G}, µm.
    axis : (3,) float
        Unit direction from the tip towards the shank.
    plate_normal : (3,) float, optional
        A jaw's plate normal (made perpendicular to the axis); by default the plate faces the
        world's z axis as nearly as the axis allows.
    """

    tool: Tool
    tip_um: FloatArray
    axis: FloatArray
    plate_normal: FloatArray | None = None

    def __post_init__(self) -> None:
        a = np.asarray(self.axis, dtype=np.float64)
        n = float(np.linalg.norm(a))
        if a.shape != (3,) or not np.isfinite(n) or n == 0:
            raise InputError(f"axis: expected a non-zero 3-vector, got {self.axis!r}")
        object.__setattr__(self, "axis", a / n)
        object.__setattr__(self, "tip_um", np.asarray(self.tip_um, dtype=np.float64))

    @property
    def vertex_um(self) -> FloatArray:
        """The taper's vertex in {G}, µm (in front of the tip point, on the axis)."""
        out: FloatArray = self.tip_um - self.axis * self.tool.vertex_to_tip_um
        return out

    def plate_basis(self) -> tuple[FloatArray, FloatArray]:
        """(normal, across): the jaw's plate normal and the in-plate direction across the axis."""
        a = self.axis
        n = np.array([0.0, 0.0, 1.0]) if self.plate_normal is None else self.plate_normal
        n = n - a * float(n @ a)
        if np.linalg.norm(n) < 1e-6:
            n = np.array([1.0, 0.0, 0.0]) - a * a[0]
        n = n / np.linalg.norm(n)
        return n, np.cross(n, a)


@dataclass(frozen=True)
class Optics:
    """The objective: numerical aperture, wavelength and where it focuses.

    Attributes
    ----------
    numerical_aperture : float
    wavelength_um : float
    focus_depth_um : float
        Depth of the focal plane (the camera model's ``depth_um``), µm.
    refractive_index : float
        Of the medium between the objective and the tool (1 in air, 1.33 in water).
    """

    numerical_aperture: float = 0.3
    wavelength_um: float = 0.55
    focus_depth_um: float = 0.0
    refractive_index: float = 1.0

    def __post_init__(self) -> None:
        check_number("numerical_aperture", self.numerical_aperture, above=0)
        check_number("refractive_index", self.refractive_index, low=1, high=2)
        if self.numerical_aperture >= self.refractive_index:
            raise InputError(
                f"numerical_aperture: expected below the medium's index "
                f"{self.refractive_index:g}, got {self.numerical_aperture:g}"
            )
        check_number("wavelength_um", self.wavelength_um, above=0.1, high=2)
        check_number("focus_depth_um", self.focus_depth_um)

    def depth_of_field_um(self, um_per_px: float) -> float:
        """Depth of field: ``lambda n / NA^2 + n e / NA`` with ``e`` the pixel in the object, µm."""
        na, n = self.numerical_aperture, self.refractive_index
        return self.wavelength_um * n / na**2 + n * um_per_px / na

    def blur_sigma_px(self, defocus_um: FloatArray | float, um_per_px: float) -> FloatArray:
        """Gaussian blur of a point ``defocus_um`` from the focal plane, px.

        Diffraction (``0.21 lambda / NA``) and the geometric circle of confusion (radius
        ``|dz| tan(asin(NA / n))``, a Gaussian of half that radius) added in quadrature.
        """
        na = self.numerical_aperture
        diffraction = 0.21 * self.wavelength_um / na
        half_cone = math.tan(math.asin(na / self.refractive_index))
        geometric = np.abs(np.asarray(defocus_um, dtype=np.float64)) * half_cone / 2.0
        out: FloatArray = np.hypot(diffraction, geometric) / um_per_px
        return out


@dataclass(frozen=True)
class Background:
    """What lies behind the tool, under uneven light.

    Attributes
    ----------
    texture : {"plain", "tissue", "debris"}
        Clear medium, a tissue-like low-contrast texture, or scattered small particles.
    contrast : float
        Relative depth of the texture (tissue) or the particles' darkness (debris).
    gradient : (float, float)
        Relative change of the light across the image's width and height (uneven
        illumination).
    level : float
        Light of the clear background as a fraction of the full scale.
    seed : int
        Seed of the texture.
    """

    texture: Literal["plain", "tissue", "debris"] = "plain"
    contrast: float = 0.1
    gradient: tuple[float, float] = (0.0, 0.0)
    level: float = 0.75
    seed: int = 0

    def __post_init__(self) -> None:
        if self.texture not in ("plain", "tissue", "debris"):
            raise InputError(f"texture: expected plain, tissue or debris, got {self.texture!r}")
        check_number("contrast", self.contrast, low=0, high=0.9)
        check_number("level", self.level, above=0, high=1)

    def image(self, shape: tuple[int, int]) -> NDArray[np.float32]:
        """The background's light, (h, w) float32 in [0, 1]."""
        h, w = shape
        rng = np.random.default_rng(self.seed)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        gx, gy = self.gradient
        light = self.level * (
            1.0 + gx * (xx / max(w - 1, 1) - 0.5) + gy * (yy / max(h - 1, 1) - 0.5)
        )
        if self.texture == "tissue":
            noise = rng.standard_normal((h, w)).astype(np.float32)
            for sigma, weight in ((12.0, 1.0), (4.0, 0.5)):  # cells and their grain
                blob = cv2.GaussianBlur(noise, (0, 0), sigma)
                light *= 1.0 + weight * self.contrast * blob / max(float(blob.std()), 1e-9) / 2
        elif self.texture == "debris":
            dark = np.zeros((h, w), dtype=np.float32)
            for _ in range(int(rng.integers(4, 12))):
                c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
                r = int(rng.integers(1, 5))
                cv2.circle(dark, c, r, float(rng.uniform(0.3, 1.0)), -1)
            dark = cv2.GaussianBlur(dark, (0, 0), 1.0)
            light *= 1.0 - self.contrast * 3.0 * dark
        out: NDArray[np.float32] = np.clip(light, 0.0, 1.0).astype(np.float32)
        return out


@dataclass
class ToolTruth:
    """Where a tool shows in one camera: for tests and the detection's population.

    Attributes
    ----------
    tip_px : (2,) float
        The tip point's image (the camera's ``project``, with distortion).
    axis_px : (2,) float
        Unit direction of the axis in the image, from the tip towards the shank.
    vertex_px : (2,) float
        The taper's vertex's image.
    in_field : bool
        The tip's image is inside the frame.
    defocus_um : float
        The tip point's distance from the focal plane, µm.
    sigma_px : float
        The blur at the tip point, px.
    um_per_px : float
        The object's size of a pixel at the tip, µm.
    """

    tip_px: FloatArray
    axis_px: FloatArray
    vertex_px: FloatArray
    in_field: bool
    defocus_um: float
    sigma_px: float
    um_per_px: float


def _view_direction(camera: AnyCamera, p_um: FloatArray) -> FloatArray:
    """Unit direction from the point ``p_um`` towards the camera, (3,)."""
    if camera.kind == "affine":
        return -np.asarray(camera.R[2], dtype=np.float64)
    centre = np.asarray(camera.centre_um, dtype=np.float64)  # type: ignore[union-attr]
    d = centre - p_um
    return d / np.linalg.norm(d)


def um_per_px(camera: AnyCamera, p_um: FloatArray) -> float:
    """The size of a pixel in the object at ``p_um`` (across the line of sight), µm."""
    J = np.asarray(camera.project_jacobian(p_um, distort=False), dtype=np.float64).reshape(2, 3)
    s = np.linalg.svd(J, compute_uv=False)
    return float(1.0 / math.sqrt(s[0] * s[1]))


@dataclass
class _Silhouette:
    """A tool's outline in ideal pixels: two edges through the vertex, a chord and an end."""

    vertex: FloatArray  # (2,)
    normals: FloatArray  # (2, 2): outward normals of the two edges
    chord_point: FloatArray  # (2,)
    chord_normal: FloatArray  # (2,): points towards the vertex (outside)
    end_centre: FloatArray  # (2,)
    end_inverse: FloatArray  # (2, 2): maps a point's offset to the end's unit disc
    end_scale: float  # smallest semi-axis of the end, px
    axis: FloatArray  # (2,): unit, from the vertex towards the shank
    tan_half: float  # tan of the image's half-angle
    depth0_um: float  # depth of the vertex
    depth_per_px: float  # change of depth per px along the image axis


def _generators(placement: ToolPlacement, w: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """The two 3D directions of the silhouette's edges from the vertex (None: seen end-on)."""
    tool, a = placement.tool, placement.axis
    alpha = tool.half_angle_rad
    if tool.kind == "jaw":
        _, across = placement.plate_basis()
        return (math.cos(alpha) * a + math.sin(alpha) * across,
                math.cos(alpha) * a - math.sin(alpha) * across)  # fmt: skip
    cos_phi = float(np.clip(w @ a, -1.0, 1.0))
    perp = w - a * cos_phi
    sin_phi = float(np.linalg.norm(perp))
    if sin_phi < 1e-9:
        return None
    u = perp / sin_phi
    v = np.cross(a, u)
    cos_psi = math.tan(alpha) * cos_phi / sin_phi
    if abs(cos_psi) >= 1.0:
        return None
    sin_psi = math.sqrt(1.0 - cos_psi * cos_psi)
    ring = [math.cos(alpha) * a + math.sin(alpha) * (cos_psi * u + s * sin_psi * v)
            for s in (1.0, -1.0)]  # fmt: skip
    return ring[0], ring[1]


def _silhouette(camera: AnyCamera, placement: ToolPlacement) -> _Silhouette | None:
    """The outline of a placed tool in the camera's ideal pixels (None: seen end-on)."""
    tool = placement.tool
    V = placement.vertex_um
    w = _view_direction(camera, V)
    gens = _generators(placement, w)
    if gens is None:
        return None
    alpha, r = tool.half_angle_rad, tool.end_radius_um
    reach = 100.0 * max(r, 1.0) / math.tan(alpha)
    pts = [V] + [V + g * reach for g in gens]
    if tool.kind == "pipette":
        contact = [V + g * (tool.vertex_to_tip_um / math.cos(alpha)) for g in gens]
    else:
        contact = [V + g * (r / math.tan(alpha)) for g in gens]
    q = camera.project(np.array(pts + contact), distort=False)
    if not np.all(np.isfinite(q)):
        return None
    v2 = q[0]
    dirs = q[1:3] - v2
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    axis2 = dirs[0] + dirs[1]
    n_axis = float(np.linalg.norm(axis2))
    if n_axis < 1e-9:
        return None
    axis2 /= n_axis
    normals = np.array([[-d[1], d[0]] for d in dirs])
    for i in range(2):  # outward: the other edge on the inside
        if normals[i] @ dirs[1 - i] > 0:
            normals[i] = -normals[i]
    tan_half = math.tan(0.5 * math.acos(float(np.clip(dirs[0] @ dirs[1], -1.0, 1.0))))
    c_pt, c_dir = q[3], q[4] - q[3]
    c_norm = np.array([-c_dir[1], c_dir[0]]) / max(float(np.linalg.norm(c_dir)), 1e-12)
    if c_norm @ (v2 - c_pt) < 0:
        c_norm = -c_norm
    centre = placement.tip_um
    J = np.asarray(camera.project_jacobian(centre, distort=False), dtype=np.float64).reshape(2, 3)
    if tool.kind == "needle":
        e1 = np.cross(w, placement.axis)
        e1 = e1 / np.linalg.norm(e1) if np.linalg.norm(e1) > 1e-9 else np.array([1.0, 0, 0])
        basis = (e1, np.cross(w, e1))
    elif tool.kind == "jaw":
        basis = (placement.axis, placement.plate_basis()[1])
    else:
        n_, across = placement.plate_basis()
        basis = (n_, across)  # any two directions across the axis: the ring's plane
    U, ends, Vt = np.linalg.svd(J @ np.column_stack(basis) * r)
    ends = np.maximum(ends, 0.02)  # a ring seen edge-on: a line 0.04 px thick
    M_inverse = Vt.T @ np.diag(1.0 / ends) @ U.T
    depth0 = float(camera.depth_um(V)[0])
    q_back = camera.project(V + placement.axis * 100.0, distort=False)[0]
    d_back = float(camera.depth_um(V + placement.axis * 100.0)[0]) - depth0
    px_back = float(np.linalg.norm(q_back - v2))
    return _Silhouette(
        v2, normals, c_pt, c_norm, camera.project(centre, distort=False)[0], M_inverse,
        float(ends[1]), axis2, tan_half, depth0, d_back / max(px_back, 1e-12),
    )  # fmt: skip


def _pipette_transmission(xi: FloatArray, wall: float) -> FloatArray:
    """Light through a hollow glass taper at ``xi`` (0 on the axis, 1 at the outer edge).

    The glass's path length across the tool, ``2 (sqrt(1 - xi^2) - sqrt(ri^2 - xi^2))``,
    bends the light by its slope; what is bent beyond the objective's aperture is lost.
    """
    ri = 1.0 - wall
    x = np.clip(np.abs(xi), 0.0, 0.995)
    slope = x / np.sqrt(1.0 - x * x)
    inner = x < ri * 0.995
    slope = np.where(inner, slope - x / np.sqrt(np.maximum(ri * ri - x * x, 1e-6)), slope)
    out: FloatArray = 0.96 - 0.8 * (1.0 - np.exp(-np.abs(slope) / 1.2))
    return out


def _shade(
    sil: _Silhouette, tool: Tool, qx: FloatArray, qy: FloatArray, width: float
) -> tuple[FloatArray, FloatArray]:
    """Coverage and transmission of a tool at ideal points (qx, qy), box-filtered over ``width``."""
    dx, dy = qx - sil.vertex[0], qy - sil.vertex[1]
    edge = np.maximum(dx * sil.normals[0, 0] + dy * sil.normals[0, 1],
                      dx * sil.normals[1, 0] + dy * sil.normals[1, 1])  # fmt: skip
    chord = (qx - sil.chord_point[0]) * sil.chord_normal[0]
    chord += (qy - sil.chord_point[1]) * sil.chord_normal[1]
    taper = np.maximum(edge, chord)
    ex, ey = qx - sil.end_centre[0], qy - sil.end_centre[1]
    ux = sil.end_inverse[0, 0] * ex + sil.end_inverse[0, 1] * ey
    uy = sil.end_inverse[1, 0] * ex + sil.end_inverse[1, 1] * ey
    rho = np.hypot(ux, uy)
    end = (rho - 1.0) * sil.end_scale
    end_cover = np.clip(0.5 - end / width, 0.0, 1.0)
    if tool.kind == "pipette":
        # The opening's ring, seen nearly edge-on, is thinner than a subsample: its share is
        # that of a band as thick as the ellipse's chord along its smallest semi-axis (a half
        # plane at the distance above would thicken it to the subsample's width, and the
        # distance scaled by the smallest semi-axis reaches far beyond the ring's ends).
        _, inv_axes, frame = np.linalg.svd(sil.end_inverse)
        minor = ex * frame[0, 0] + ey * frame[0, 1]
        major = (ex * frame[1, 0] + ey * frame[1, 1]) * inv_axes[1]
        chord_half = np.sqrt(np.clip(1.0 - major * major, 0.0, 1.0)) / inv_axes[0]
        end_cover = (np.minimum(chord_half, minor + 0.5 * width)
                     - np.maximum(-chord_half, minor - 0.5 * width)) / width  # fmt: skip
        end_cover = np.clip(end_cover, 0.0, 1.0)
    cover = np.maximum(np.clip(0.5 - taper / width, 0.0, 1.0), end_cover)
    if tool.kind != "pipette":
        return cover, np.full_like(cover, tool.transmittance)
    along = dx * sil.axis[0] + dy * sil.axis[1]
    across = np.abs(dx * sil.axis[1] - dy * sil.axis[0])
    xi = np.where(taper <= end, across / np.maximum(along * sil.tan_half, 1e-9), rho)
    return cover, _pipette_transmission(xi, tool.wall)


def _darkness(
    camera: AnyCamera,
    placement: ToolPlacement,
    sil: _Silhouette,
    box: Box,
    supersample: int,
    offset_px: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The light the tool takes away over a box (``1 - transmission``, averaged over
    ``supersample`` x ``supersample`` subsamples per pixel), (h, w), not blurred; with the
    pixels' undistorted positions ``ix``, ``iy`` (h, w) (the pixels shifted by ``-offset_px``
    first, when given)."""
    x0, y0, x1, y1 = box
    h, w = y1 - y0, x1 - x0
    gx, gy = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    centres = np.column_stack([gx.ravel(), gy.ravel()])
    if offset_px is not None:
        centres = centres - np.asarray(offset_px, dtype=np.float64)
    ideal = camera.undistort_px(centres) if camera.has_distortion else centres
    ix, iy = ideal[:, 0].reshape(h, w), ideal[:, 1].reshape(h, w)
    n = int(supersample)
    offs = (np.arange(n) + 0.5) / n - 0.5
    dark = np.zeros((h, w))
    for oy in offs:
        for ox in offs:
            cover, trans = _shade(sil, placement.tool, ix + ox, iy + oy, 1.0 / n)
            dark += cover * (1.0 - trans)
    dark /= n * n
    return dark, ix, iy


def _render_one(
    camera: AnyCamera,
    placement: ToolPlacement,
    sil: _Silhouette,
    box: Box,
    optics: Optics,
    supersample: int,
) -> NDArray[np.float32]:
    """A tool's transmission over a box (blurred by its depth), (h, w) float32, 1 outside it."""
    dark, ix, iy = _darkness(camera, placement, sil, box, supersample)
    # Blur by depth: the depth of the axis point nearest each pixel, levels of sigma between.
    along = np.maximum((ix - sil.vertex[0]) * sil.axis[0] + (iy - sil.vertex[1]) * sil.axis[1], 0)
    pitch = um_per_px(camera, placement.tip_um)
    sigma = optics.blur_sigma_px(sil.depth0_um + along * sil.depth_per_px - optics.focus_depth_um,
                                 pitch)  # fmt: skip
    return (1.0 - _blur_by_sigma(dark.astype(np.float32), sigma)).astype(np.float32)


def _blur_by_sigma(image: NDArray[np.float32], sigma: FloatArray) -> NDArray[np.float32]:
    """Gaussian blur whose sigma varies per pixel (interpolated between a few levels)."""
    lo, hi = float(sigma.min()), float(sigma.max())
    if hi - lo < 0.02 * lo + 1e-3:
        flat: NDArray[np.float32] = cv2.GaussianBlur(image, (0, 0), max(0.5 * (lo + hi), 1e-3))
        return flat
    n = max(2, math.ceil(math.log(hi / lo) / math.log(1.15)) + 1)
    levels = np.geomspace(lo, hi, n)
    blurred = [cv2.GaussianBlur(image, (0, 0), float(v)) for v in levels]
    k = np.clip(np.log(sigma / lo) / math.log(levels[1] / levels[0]), 0, n - 1 - 1e-9)
    i = np.floor(k).astype(int)
    f = (k - i).astype(np.float32)
    stack = np.stack(blurred)
    rows, cols = np.indices(image.shape)
    out = np.asarray(stack[i, rows, cols] * (1 - f) + stack[i + 1, rows, cols] * f, np.float32)
    return out


def render_tools(
    camera: AnyCamera,
    placements: list[ToolPlacement],
    optics: Optics,
    *,
    roi: Box | None = None,
    supersample: int = 4,
) -> tuple[NDArray[np.float32], list[ToolTruth]]:
    """The tools' transmission over a pixel box (1 where no tool is), noise-free.

    Parameters
    ----------
    camera : CameraModel or AffineCamera
    placements : list of ToolPlacement
    optics : Optics
    roi : (x0, y0, x1, y1), optional
        Pixel box, end exclusive; the whole image by default.
    supersample : int
        S: S x S subsamples per pixel.

    Returns
    -------
    transmission : (h, w) float32
    truths : list of ToolTruth, one per placement
    """
    w_img, h_img = camera.image_size_px
    x0, y0, x1, y1 = roi if roi is not None else (0, 0, w_img, h_img)
    out = np.ones((y1 - y0, x1 - x0), dtype=np.float32)
    truths = []
    for placement in placements:
        truths.append(_truth(camera, placement, optics))
        sil = _silhouette(camera, placement)
        if sil is None:
            continue
        pitch = um_per_px(camera, placement.tip_um)
        reach = placement.axis * 1e5
        far = float(camera.depth_um(placement.tip_um + reach)[0]) - optics.focus_depth_um
        near = float(camera.depth_um(placement.tip_um)[0]) - optics.focus_depth_um
        margin = int(4 * float(np.max(optics.blur_sigma_px(np.array([near, far]), pitch)))) + 4
        margin = min(margin, 64)
        box = (x0 - margin, y0 - margin, x1 + margin, y1 + margin)
        part = _render_one(camera, placement, sil, box, optics, supersample)
        out *= part[margin:-margin, margin:-margin]
    return out, truths


def _truth(camera: AnyCamera, placement: ToolPlacement, optics: Optics) -> ToolTruth:
    tip = placement.tip_um
    q = camera.project(np.array([tip, tip + placement.axis * 10.0, placement.vertex_um]))
    axis = q[1] - q[0]
    axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
    w, h = camera.image_size_px
    inside = bool(np.all(np.isfinite(q[0])) and -0.5 <= q[0, 0] <= w - 0.5
                  and -0.5 <= q[0, 1] <= h - 0.5)  # fmt: skip
    defocus = float(camera.depth_um(tip)[0]) - optics.focus_depth_um
    pitch = um_per_px(camera, tip)
    sigma = float(optics.blur_sigma_px(defocus, pitch))
    return ToolTruth(q[0], axis, q[2], inside, defocus, sigma, pitch)


def expose(
    light: NDArray[np.float32],
    rng: np.random.Generator,
    *,
    full_well_e: float = 10000.0,
    read_noise_e: float = 10.0,
    bit_depth: int = 8,
) -> NDArray[np.unsignedinteger]:
    """A frame of ``light`` (fractions of the full scale): shot and read noise, quantised."""
    top = 2**bit_depth - 1
    electrons = np.clip(light, 0.0, None).astype(np.float64) * full_well_e
    noisy = electrons + rng.standard_normal(light.shape) * np.sqrt(electrons + read_noise_e**2)
    dn = np.clip(np.rint(noisy * top / full_well_e), 0, top)
    out: NDArray[np.unsignedinteger] = dn.astype(np.uint8 if bit_depth == 8 else np.uint16)
    return out


@dataclass(frozen=True)
class ToolScene:
    """Everything one tool image needs besides the camera."""

    placements: list[ToolPlacement]
    optics: Optics
    background: Background = field(default_factory=Background)
    full_well_e: float = 10000.0
    read_noise_e: float = 10.0
    bit_depth: int = 8


def tool_image(
    camera: AnyCamera, scene: ToolScene, rng: np.random.Generator, *, supersample: int = 4
) -> tuple[NDArray[np.unsignedinteger], list[ToolTruth]]:
    """A whole frame of tools against their background, with noise, and where they are."""
    w, h = camera.image_size_px
    trans, truths = render_tools(camera, scene.placements, scene.optics, supersample=supersample)
    light = scene.background.image((h, w)) * trans
    frame = expose(light, rng, full_well_e=scene.full_well_e, read_noise_e=scene.read_noise_e,
                   bit_depth=scene.bit_depth)  # fmt: skip
    return frame, truths
