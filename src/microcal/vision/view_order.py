"""Views out of order against their known displacements (method (a)).

Method (a) pairs the i-th image of each camera with the i-th displacement. Two images
exchanged (two of one camera, or one view's images of two cameras given to each other's
``--images``) still calibrate, to a camera that fits nothing well. Here every camera's views are
fitted by the linear DLT (thesis Eq 3.7-3.15) as given, then greedily re-paired: exchanging
two views of one camera, or one view between two cameras of the same image size. When the
re-paired views fit the steps several times better than the given order, the order is wrong:
a right order cannot be improved by exchanging views, whatever the lens or the noise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from ..geometry import estimate_projection_matrix
from ..geometry.reprojection import reprojection_error
from .detect import Detection
from .targets import Target

__all__ = ["MISORDER_FACTOR", "ORDER_CHECK_FLOOR_PX", "check_view_order"]

#: The views are out of order when re-pairing them divides the RMS by this factor or more.
MISORDER_FACTOR = 3.0
#: Below this linear-fit RMS (px) the order is not searched: views exchanged there would move
#: the features by less than this, a pixel or so, many times the detection noise of ~0.1 px.
ORDER_CHECK_FLOOR_PX = 1.0
#: Exchanges tried at most (each the best of all single exchanges).
_MAX_EXCHANGES = 8


@dataclass(frozen=True)
class _Slot:
    """Where a detection sits: its camera and view."""

    camera: str
    view: int


def _fit(
    dets: Sequence[Detection], views: Sequence[int], target: Target, disp: FloatArray
) -> tuple[float, bool]:
    """Sum of squared DLT reprojection errors of ``views`` (px², inf when not determined) and
    whether the camera is a proper one (most points in front of it, not a mirror image)."""
    pts = target.points_um()
    p = np.vstack([pts[dets[i].ids] + disp[i] for i in views])
    q = np.vstack([dets[i].q_px for i in views])
    try:
        P = estimate_projection_matrix(p, q)
    except (DegenerateDataError, InputError):
        return float("inf"), False
    err = reprojection_error(P, p, q)
    total = float(np.sum(err**2))
    depth = P[2, :3] @ p.T + P[2, 3]
    return (total if np.isfinite(total) else float("inf")), bool(np.median(depth) > 0)


def check_view_order(
    detections: Mapping[str, Sequence[Detection]],
    image_names: Mapping[str, Sequence[str]],
    target: Target,
    displacements_um: FloatArray,
    image_size_px: Mapping[str, tuple[int, int]],
) -> None:
    """Refuse views that fit their displacements far better exchanged.

    Parameters
    ----------
    detections : dict camera -> list of Detection
        One per view, numbered alike (a symmetric board's turns already settled).
    image_names : dict camera -> list of str
    target : Target
    displacements_um : (V, 3) float
    image_size_px : dict camera -> (w, h)
        Only cameras of one size can have had their images exchanged.

    Raises
    ------
    InputError
        Naming the images to exchange and what to check.
    """
    disp = np.asarray(displacements_um, dtype=np.float64)
    dets = {cam: list(d) for cam, d in detections.items()}
    used = {cam: [i for i, d in enumerate(ds) if d.found] for cam, ds in dets.items()}
    n_points = {cam: sum(len(dets[cam][i].ids) for i in used[cam]) for cam in dets}
    sse = {cam: _fit(dets[cam], used[cam], target, disp)[0] for cam in dets if used[cam]}
    start = dict(sse)

    def rms(cams: Sequence[str], table: Mapping[str, float]) -> float:
        n = sum(n_points[c] for c in cams)
        return float(np.sqrt(sum(table[c] for c in cams) / n)) if n else 0.0

    suspects = [c for c in sse if np.isfinite(sse[c]) and rms([c], sse) > ORDER_CHECK_FLOOR_PX]
    if not suspects:
        return
    origin = {_Slot(c, i): _Slot(c, i) for c in dets for i in range(len(dets[c]))}
    for _ in range(_MAX_EXCHANGES):
        tried = []
        for a, b in _exchanges(dets, used, suspects, image_size_px):
            trial = _exchanged(dets, a, b)
            cams = sorted({a.camera, b.camera})
            fits = {c: _fit(trial[c], used[c], target, disp) for c in cams}
            after = {c: f[0] for c, f in fits.items()}
            if sum(after.values()) < sum(sse[c] for c in cams):
                gain = sum(sse[c] for c in cams) - sum(after.values())
                tried.append((gain, all(f[1] for f in fits.values()), a, b, after))
        if not tried:
            break
        # Steps along one line, evenly spaced, fit as well reversed, by a mirrored camera:
        # of the exchanges that gain about the most, a proper camera's is taken.
        top = max(t[0] for t in tried)
        best = max((t for t in tried if t[0] >= 0.9 * top), key=lambda t: (t[1], t[0]))
        _, _, a, b, after = best
        dets = _exchanged(dets, a, b)
        sse.update(after)
        origin[a], origin[b] = origin[b], origin[a]
    cams = sorted({s.camera for s, o in origin.items() if s != o}, key=list(dets).index)
    if not cams or rms(cams, start) < MISORDER_FACTOR * rms(cams, sse):
        return
    moved = [s for s in origin if origin[s] != s and s.camera in cams]
    names = ", ".join(image_names[s.camera][s.view] for s in moved)
    across = any(origin[s].camera != s.camera for s in moved)
    fix = (
        "check that each --images glob names its own camera's images"
        if across
        else "check that the images, sorted by name, follow the rows of --known-displacements"
    )
    raise InputError(
        f"views out of order: {names} fit the known displacements far better in another "
        f"order (reprojection RMS {rms(cams, sse):.3g} px reordered, {rms(cams, start):.3g} px "
        f"as given); {fix}"
    )


def _exchanges(
    dets: Mapping[str, Sequence[Detection]],
    used: Mapping[str, Sequence[int]],
    suspects: Sequence[str],
    sizes: Mapping[str, tuple[int, int]],
) -> list[tuple[_Slot, _Slot]]:
    """Every exchange of two views of a suspect camera, and of one view between a suspect
    camera and another of its image size."""
    out = []
    for cam in suspects:
        views = used[cam]
        out += [(_Slot(cam, i), _Slot(cam, j)) for k, i in enumerate(views) for j in views[k + 1 :]]
        for other in dets:
            if other == cam or sizes.get(other) != sizes.get(cam):
                continue
            if other in suspects and list(dets).index(other) < list(dets).index(cam):
                continue  # the pair was listed from the other camera
            both = set(used[cam]) & set(used[other])
            out += [(_Slot(cam, i), _Slot(other, i)) for i in sorted(both)]
    return out


def _exchanged(
    dets: Mapping[str, Sequence[Detection]], a: _Slot, b: _Slot
) -> dict[str, list[Detection]]:
    out = {cam: list(d) for cam, d in dets.items()}
    out[a.camera][a.view], out[b.camera][b.view] = dets[b.camera][b.view], dets[a.camera][a.view]
    return out
