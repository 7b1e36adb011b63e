"""Do the cameras' views of a tool's tip show one point? Two tools in view, told apart by
none of the cameras, can each give a tip: one camera the first tool's, another the second's.

A board cannot be mixed up so (each camera sees all of its corners), but a tool's tip is one
point per camera: two tools whose outlines merge in one camera's image (their shanks meet
before the image's edge) are one outline there, whose apex is either tool's. Triangulated,
such views give a point that is neither tool's, far from where each camera saw its tip.
:func:`refuse_disagreeing` fails every such pose with the reason (the pose is measured
again from what each camera saw once the cause is gone).

The test is the distance, in each camera's ideal pixels, from the apex it saw to the
triangulated point's image: a tool's tip is fixed to within a pixel or two along its axis
(less across it), while another tool's tip lies tens of pixels away or more.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Protocol

import numpy as np

from .._validation import FloatArray
from ..geometry import AnyCamera

__all__ = ["DISAGREE_PX", "Measured", "disagreement", "refuse_disagreeing"]

#: Views further than this from their triangulation (px) do not show one tip.
DISAGREE_PX = 8.0


def disagreement(
    p_um: np.ndarray, apexes_px: Mapping[str, np.ndarray], cameras: Mapping[str, AnyCamera]
) -> str | None:
    """Why the cameras' apexes are not the image of one point ``p_um`` (3,), or None.

    Parameters
    ----------
    p_um : (3,) float
        The triangulated tip, µm in {G}.
    apexes_px : mapping of camera name to (k, 2) float
        Each camera's apexes (ideal pixels), one per frame.
    cameras : mapping of camera name to camera model
    """
    if not np.all(np.isfinite(p_um)):
        return None
    far: list[tuple[float, str]] = []
    for name, apexes in apexes_px.items():
        seen = np.asarray(apexes, dtype=np.float64).reshape(-1, 2).mean(axis=0)
        model = cameras[name]
        image = np.asarray(model.undistort_px(model.project(p_um)), dtype=np.float64).reshape(2)
        far.append((float(np.linalg.norm(image - seen)), name))
    worst, name = max(far)
    if not worst > DISAGREE_PX:  # NaN (a point a camera cannot see) is left to the caller
        return None
    return (
        f"the cameras' tips are not one point ({name}'s is {worst:.0f} px from where the "
        f"cameras put it): two tools in view, or something else taken for the tool"
    )


class Measured(Protocol):
    """A pose's measurement (:class:`~microcal.vision.measurement.PoseMeasurement`)."""

    status: str
    reason: str
    p_um: FloatArray
    cov_um2: FloatArray
    vp_px: dict[str, FloatArray]


def refuse_disagreeing(results: Iterable[Measured], cameras: Mapping[str, AnyCamera]) -> None:
    """Fail every measured pose whose views do not show one tip (:func:`disagreement`),
    with the reason; in place."""
    for m in results:
        why = disagreement(m.p_um, m.vp_px, cameras) if m.status == "ok" else None
        if why is None:
            continue
        m.status, m.reason = "failed", why
        m.p_um, m.cov_um2 = np.full(3, np.nan), np.full((3, 3), np.nan)
