"""The report's figures, drawn with matplotlib and returned as PNG data URIs.

Each function takes plain arrays and returns a ``data:image/png;base64,...`` string, so the
HTML stays one self-contained file. Figures use matplotlib's object interface (no pyplot
state), so building a report touches no global settings.

Names from the run's files (cameras, views, devices) are drawn as plain text: cut to
:data:`~.bounds.MAX_LABEL_CHARS` characters, their dollar signs escaped so that matplotlib
never reads them as mathematics. A series of more than :data:`~.bounds.MAX_POINTS` points is
drawn thinned evenly, and a figure's panels are one per camera given (the caller bounds them).
"""

from __future__ import annotations

import base64
import io
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from matplotlib.ticker import MaxNLocator

from .._validation import FloatArray
from .bounds import MAX_LABEL_CHARS, MAX_ROWS, clip, thinned

__all__ = [
    "calibration_coverage",
    "calibration_residuals",
    "command_design",
    "decoupling",
    "measurement_uncertainty",
    "per_view_rms",
    "prediction_errors",
    "projection_uncertainty",
    "residual_field",
    "settle_times",
]

DPI = 90
AXES = "xyz"
CONDITION_COLOURS = {"uncalibrated": "tab:red", "matrix": "tab:blue", "optimal": "tab:green"}


class FigureUri(str):
    """A figure drawn by this module, as a PNG data URI (the report shows it whole)."""

    __slots__ = ()


def _uri(fig: Figure) -> FigureUri:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return FigureUri("data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii"))


def label(text: object) -> str:
    """A name from an input file as a figure's plain text: cut short, no mathematics."""
    return clip(str(text), MAX_LABEL_CHARS).replace("$", r"\$")


def _image_axes(ax: Axes, w: int, h: int, title: str) -> None:
    """Axes that show a w x h image's pixel frame (v down), labelled."""
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u, px")
    ax.set_ylabel("v, px")
    ax.set_title(title, fontsize=9)


def per_view_rms(per_view_px: Mapping[str, Mapping[str, float]]) -> str:
    """Bar chart of the reprojection RMS of every view, one panel per camera.

    Parameters
    ----------
    per_view_px : {camera: {view: rms px}}
    """
    fig = Figure(figsize=(4.2 * len(per_view_px), 3.0), layout="constrained")
    for k, (cam, all_views) in enumerate(per_view_px.items()):
        ax = fig.add_subplot(1, len(per_view_px), k + 1)
        views = dict(list(all_views.items())[:MAX_ROWS])
        ax.bar(range(len(views)), list(views.values()), color="tab:blue")
        ax.set_xticks(range(len(views)), [label(v) for v in views], rotation=60, fontsize=7)
        ax.set_ylabel("RMS, px")
        cut = f" (first {len(views)} of {len(all_views)})" if len(views) < len(all_views) else ""
        ax.set_title(f"{label(cam)}: reprojection error per view{cut}")
    return _uri(fig)


def calibration_residuals(residuals_px: Mapping[str, FloatArray]) -> str:
    """Scatter of the reprojection residuals (dx, dy) of all views, one panel per camera.

    Parameters
    ----------
    residuals_px : {camera: (N, 4) float}
        Detected x, y and residual dx, dy of every target point used.
    """
    fig = Figure(figsize=(3.6 * len(residuals_px), 3.4), layout="constrained")
    for k, (cam, r) in enumerate(residuals_px.items()):
        ax = fig.add_subplot(1, len(residuals_px), k + 1)
        drawn = r[thinned(len(r))]
        ax.scatter(drawn[:, 2], drawn[:, 3], s=2, alpha=0.4, color="tab:blue", linewidths=0)
        lim = max(float(np.abs(r[:, 2:]).max()) * 1.05, 1e-3) if len(r) else 1.0
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.axhline(0, color="grey", lw=0.5)
        ax.axvline(0, color="grey", lw=0.5)
        ax.set_xlabel("dx, px")
        ax.set_ylabel("dy, px")
        ax.set_title(f"{label(cam)}: residuals ({len(r)} points)")
    return _uri(fig)


def calibration_coverage(
    residuals_px: Mapping[str, FloatArray], image_size_px: Mapping[str, Sequence[int]]
) -> str:
    """Where in each image the target points lay: coverage of the sensor by the calibration.

    Parameters
    ----------
    residuals_px : {camera: (N, 4) float}
    image_size_px : {camera: (width, height)}
    """
    fig = Figure(figsize=(4.3 * len(residuals_px), 3.3), layout="constrained")
    for k, (cam, r) in enumerate(residuals_px.items()):
        w, h = image_size_px[cam]
        ax = fig.add_subplot(1, len(residuals_px), k + 1)
        counts, xe, ye = _cells(r[:, 0], r[:, 1], w, h)
        shown = np.ma.masked_equal(counts, 0)  # cells without a point stay white
        im = ax.pcolormesh(xe, ye, shown, cmap="Blues", vmin=0, shading="flat")
        fig.colorbar(im, ax=ax, label="points per cell")
        _image_axes(ax, w, h, f"{label(cam)}: target points over the {w} x {h} image")
    return _uri(fig)


#: Cells across an image's longer side in the coverage and residual maps.
CELLS_ACROSS = 16


def _cells(
    x: FloatArray, y: FloatArray, w: int, h: int, weights: FloatArray | None = None
) -> tuple[np.ndarray, FloatArray, FloatArray]:
    """Points binned on a grid of square cells over a w x h image: (rows, cols) sums (counts
    without ``weights``) and the cells' edges in x and y, px."""
    side = max(w, h) / CELLS_ACROSS
    xe = np.linspace(0, w, max(1, round(w / side)) + 1)
    ye = np.linspace(0, h, max(1, round(h / side)) + 1)
    sums, _, _ = np.histogram2d(y, x, bins=(ye, xe), weights=weights)
    return sums, xe, ye


def projection_uncertainty(
    maps_px: Mapping[str, FloatArray], image_size_px: Mapping[str, Sequence[int]]
) -> str:
    """Map of each camera's 1-sigma projection uncertainty over its image.

    Parameters
    ----------
    maps_px : {camera: (rows, cols) float}
        The uncertainty on a grid spanning the image, corners included, px.
    image_size_px : {camera: (width, height)}
    """
    fig = Figure(figsize=(4.3 * len(maps_px), 3.3), layout="constrained")
    for k, (cam, m) in enumerate(maps_px.items()):
        w, h = image_size_px[cam]
        ax = fig.add_subplot(1, len(maps_px), k + 1)
        im = ax.imshow(m, extent=(0, w, h, 0), cmap="viridis", interpolation="bilinear",
                       vmin=0.0)  # fmt: skip
        levels = [v for v in (0.05, 0.1, 0.2, 0.5, 1.0, 2.0) if m.min() < v < m.max()]
        if levels:
            gx = np.linspace(0, w, m.shape[1])
            gy = np.linspace(0, h, m.shape[0])
            cs = ax.contour(gx, gy, m, levels=levels, colors="white", linewidths=0.6)
            ax.clabel(cs, fontsize=7, fmt="%g")
        fig.colorbar(im, ax=ax, label="1-sigma, px")
        _image_axes(ax, w, h, f"{label(cam)}: projection uncertainty")
    return _uri(fig)


def residual_field(
    residuals_px: Mapping[str, FloatArray], image_size_px: Mapping[str, Sequence[int]]
) -> str:
    """Reprojection residuals drawn where they lie in the image, magnified.

    Parameters
    ----------
    residuals_px : {camera: (N, 4) float}
        Detected x, y and residual dx, dy of every target point used.
    image_size_px : {camera: (width, height)}
    """
    fig = Figure(figsize=(4.0 * len(residuals_px), 3.5), layout="constrained")
    for k, (cam, r) in enumerate(residuals_px.items()):
        w, h = image_size_px[cam]
        ax = fig.add_subplot(1, len(residuals_px), k + 1)
        n, xe, ye = _cells(r[:, 0], r[:, 1], w, h)
        sx = _cells(r[:, 0], r[:, 1], w, h, r[:, 2])[0]
        sy = _cells(r[:, 0], r[:, 1], w, h, r[:, 3])[0]
        seen = n > 0
        mean_x = np.where(seen, sx / np.maximum(n, 1), 0.0)
        mean_y = np.where(seen, sy / np.maximum(n, 1), 0.0)
        cx, cy = np.meshgrid((xe[:-1] + xe[1:]) / 2, (ye[:-1] + ye[1:]) / 2)
        longest = float(np.max(np.hypot(mean_x, mean_y)[seen])) if seen.any() else 0.0
        key_px = _round_key(longest)
        scale = 0.8 * (xe[1] - xe[0]) / key_px  # the key's length fills most of a cell
        arrows = ax.quiver(cx[seen], cy[seen], mean_x[seen] * scale, -mean_y[seen] * scale,
                           angles="xy", scale_units="xy", scale=1.0, width=0.006,
                           color="tab:red")  # fmt: skip
        ax.plot(cx[seen], cy[seen], ".", ms=1.5, color="grey")  # cells with points
        _image_axes(ax, w, h, f"{label(cam)}: mean residual per cell")
        ax.title.set_horizontalalignment("left")
        ax.title.set_x(0.0)
        ax.quiverkey(arrows, 0.86, 1.04, key_px * scale, f"{key_px:g} px", labelpos="E",
                     coordinates="axes", fontproperties={"size": 8})  # fmt: skip
    return _uri(fig)


def _round_key(value: float) -> float:
    """A round length for an arrow key near ``value`` (1, 2 or 5 times a power of ten)."""
    if not value > 0:
        return 1.0
    exponent = np.floor(np.log10(value))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10**exponent >= value * 0.7:
            return float(m * 10**exponent)
    return float(10 ** (exponent + 1))


def command_design(d_um: FloatArray, n_fit: int | None) -> str:
    """The joint commands in joint space (thesis Fig 4.2), fitting and validation poses apart.

    Parameters
    ----------
    d_um : (N, 3) float
    n_fit : int, optional
        The first ``n_fit`` poses fit the model; the rest validate.
    """
    fig = Figure(figsize=(10.5, 3.6), layout=ConstrainedLayoutEngine(wspace=0.08))
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    n = len(d_um) if n_fit is None else n_fit
    fit, validate = d_um[:n], d_um[n:]
    fit, validate = fit[thinned(len(fit))], validate[thinned(len(validate))]
    ax.scatter(*fit.T, s=6, color="tab:blue", label="fit")
    if n < len(d_um):
        ax.scatter(*validate.T, s=6, color="tab:orange", label="validate")
    ax.set_xlabel("dx, µm", fontsize=8, labelpad=2)
    ax.set_ylabel("dy, µm", fontsize=8, labelpad=2)
    ax.set_zlabel("dz, µm", fontsize=8, labelpad=2)
    ax.tick_params(labelsize=7, pad=0)
    ax.set_box_aspect(None, zoom=0.82)
    fig.legend(loc="outside lower center", ncols=2, fontsize=8)
    for k, (i, j) in enumerate(((0, 1), (0, 2))):
        ax2 = fig.add_subplot(1, 3, k + 2)
        ax2.scatter(fit[:, i], fit[:, j], s=5, color="tab:blue")
        ax2.scatter(validate[:, i], validate[:, j], s=5, color="tab:orange")
        ax2.set_xlabel(f"d{AXES[i]}, µm")
        ax2.set_ylabel(f"d{AXES[j]}, µm")
    return _uri(fig)


def measurement_uncertainty(std_um: FloatArray) -> str:
    """Histograms of the reported standard deviation of every measured pose, per axis.

    Parameters
    ----------
    std_um : (N, 3) float
    """
    fig = Figure(figsize=(9.0, 2.8), layout="constrained")
    for k in range(3):
        ax = fig.add_subplot(1, 3, k + 1)
        values = std_um[:, k][np.isfinite(std_um[:, k])]
        middle = float(np.median(values)) if values.size else 0.0
        # all but equal (within 1 % of their median): one bar on a readable axis, not ticks
        # that differ in the sixth digit
        narrow = values.size and float(np.ptp(values)) < 0.01 * abs(middle)
        span = (0.98 * middle, 1.02 * middle) if narrow and middle else None
        ax.hist(values, bins=25, range=span, color="tab:blue")
        ax.xaxis.set_major_locator(MaxNLocator(4))  # labels apart however narrow the spread
        ax.ticklabel_format(axis="x", useOffset=False)  # the values, not offsets from one
        ax.set_xlabel(f"std {AXES[k]}, µm")
        ax.set_ylabel("poses")
    return _uri(fig)


def settle_times(settle_s: FloatArray) -> str:
    """Histogram of the settle time of every pose (after the device reported stopped).

    Parameters
    ----------
    settle_s : (N,) float
    """
    fig = Figure(figsize=(4.5, 2.8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    ax.hist(settle_s, bins=25, color="tab:blue")
    ax.set_xlabel("settle, s")
    ax.set_ylabel("poses")
    return _uri(fig)


def prediction_errors(errors: Mapping[str, tuple[np.ndarray, FloatArray]]) -> str:
    """Eq 5.1 error of each model at every validation pose (thesis Figs 5.3 and 5.4).

    Parameters
    ----------
    errors : {model kind: ((n,) int poses, (n,) float errors µm)}
    """
    fig = Figure(figsize=(9.0, 3.2), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    colours = {"matrix": "tab:blue", "polynomial": "tab:green"}
    for kind, (poses, err) in errors.items():
        colour = colours.get(kind, "tab:grey")
        drawn = thinned(len(err))
        ax.plot(poses[drawn], err[drawn], "o-", ms=3, lw=0.8, color=colour, label=label(kind))
        ax.axhline(float(np.mean(err)), color=colour, ls="--", lw=0.8)
    ax.set_xlabel("validation pose")
    ax.set_ylabel("prediction error, µm")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    return _uri(fig)


def decoupling(condition: str, runs: Mapping[str, tuple[FloatArray, np.ndarray]]) -> str:
    """Undesired displacement along each segment of the decoupling path (Figs 5.6 to 5.8).

    Parameters
    ----------
    condition : str
        Uncalibrated, matrix or optimal (for the title).
    runs : {source: ((N, 3) float, (N,) int)}
        Per source ("vision", "truth"): the positions along the path, µm, and the axis moving
        at each sample. The first source is drawn solid, the others dashed.
    """
    fig = Figure(figsize=(10.5, 2.9), layout="constrained")
    colours = {0: "tab:red", 1: "tab:blue", 2: "tab:green"}
    for moving in range(3):
        ax = fig.add_subplot(1, 3, moving + 1)
        for k, (source, (samples_um, segment)) in enumerate(runs.items()):
            idx = np.flatnonzero(segment == moving)
            idx = idx[thinned(idx.size)]
            if not idx.size:
                continue
            p = samples_um[idx]
            travel = p[:, moving] - p[0, moving]
            for axis in range(3):
                if axis != moving:
                    ax.plot(
                        travel,
                        p[:, axis] - p[0, axis],
                        "o-" if k == 0 else "--",
                        ms=2.5,
                        lw=0.8,
                        color=colours[axis],
                        label=f"{AXES[axis]} ({label(source)})",
                    )
        ax.axhline(0, color="grey", lw=0.5)
        ax.set_xlabel(f"{AXES[moving]} travel, µm")
        ax.set_ylabel("undesired, µm")
        ax.set_title(f"moving {AXES[moving]}", fontsize=10)
    handles: dict[str, Artist] = {}
    for ax in fig.axes:
        for handle, text in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(text, handle)
    if handles:
        fig.legend(handles=list(handles.values()), labels=list(handles),
                   loc="outside right upper", fontsize=9)  # fmt: skip
    fig.suptitle(f"decoupling, {label(condition)}", fontsize=10)
    return _uri(fig)


def check_history(
    offsets_um: FloatArray,
    std_um: FloatArray,
    verdicts: list[str],
    devices: list[str] | None = None,
    first_check: int = 1,
) -> str:
    """Offset found by each check of a calibration, per axis, with ±2 standard deviations.

    Parameters
    ----------
    offsets_um, std_um : (n, 3) float
    verdicts : n str
    devices : n str, optional
        The device each check was of; with more than one, each check's tick names it.
    first_check : int
        The number of the first check drawn (the history's earlier checks left out).
    """
    fig = Figure(figsize=(7.0, 3.0), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    k = np.arange(first_check, first_check + len(offsets_um))
    for a, (axis, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"),
                                           strict=True)):  # fmt: skip
        ax.errorbar(k + (a - 1) * 0.08, offsets_um[:, a], yerr=2 * std_um[:, a], fmt="o",
                    ms=3, color=colour, label=axis, capsize=2)  # fmt: skip
    for i, verdict in enumerate(verdicts):
        if verdict != "valid":
            ax.annotate(label(verdict), (k[i], float(np.max(offsets_um[i]))), fontsize=7,
                        textcoords="offset points", xytext=(0, 6), ha="center")  # fmt: skip
    ax.axhline(0.0, color="grey", lw=0.6)
    ax.set_xticks(k)
    if devices is not None and len(set(devices)) > 1:
        ax.set_xticks(k, [f"{i}\n{label(name)}" for i, name in zip(k, devices, strict=True)])
    ax.set_xlabel("check")
    ax.set_ylabel("offset, µm (±2 std)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    return _uri(fig)
