"""The lines ``scope-calibrate`` and ``scope-show`` print: one objective's calibration."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["scope_lines"]


def _pm(value: float, sd: float, unit: str = "") -> str:
    """``value ± sd`` with two significant digits of the standard deviation."""
    digits = max(0, 1 - math.floor(math.log10(sd))) if sd > 0 else 4
    return f"{value:.{digits}f} ± {sd:.{digits}f}{unit}"


def scope_lines(objective: str, record: Mapping[str, Any]) -> list[str]:
    """One objective's set (a scope file's, or ``ScopeCalibration.to_json()``) as lines."""
    r = record
    affine = ", ".join(f"{v:.6g}" for v in r["pixel_size_affine"])
    dist, focus = r["distortion"], r["focus"]
    scale = r.get("scale_um", [math.nan, math.nan])
    scale_sd = r.get("scale_sd_um", [0.0, 0.0])
    lines = [
        f"objective {objective}: pixel size {_pm(r['pixel_size_um'], r['pixel_size_sd_um'], ' µm')}"
        f" (x {_pm(scale[0], scale_sd[0])}, y {_pm(scale[1], scale_sd[1])})",
        f"  image x axis at {_pm(r['rotation_deg'], r['rotation_sd_deg'], '°')} in the stage's "
        f"frame, skew {_pm(r['skew_deg'], r['skew_sd_deg'], '°')}"
        + (", mirrored (image y down)" if r.get("mirrored") else ""),
        f"  Micro-Manager pixel-size affine: {affine}",
        f"  distortion k1, k2 = {dist['k'][0]:.3g}, {dist['k'][1]:.3g} (half diagonals); at the "
        f"corner {_pm(dist['corner_px'], dist['corner_sd_px'], ' px')}",
        f"  focus axis {_pm(focus['angle_deg'], focus['angle_sd_deg'], '°')} from the optical "
        f"axis; dxdz {focus['dxdz']:.4f}, dydz {focus['dydz']:.4f}",
        f"  {r['views']} views, {r['features']} features, RMS {r['rms_px']:.3f} px",
    ]
    curv = r.get("field_curvature")
    if isinstance(curv, Mapping):
        sag = _pm(curv["corner_um"], curv["corner_sd_um"], " µm")
        lines.insert(-1, f"  field curvature: the corner in focus {sag} from the centre")
    return lines
