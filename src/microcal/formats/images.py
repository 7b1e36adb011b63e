"""Reading and writing images: TIFF (tifffile, lossless), PNG and JPEG (OpenCV).

Any bit depth OpenCV or tifffile reads; colour stays colour (BGR), detection converts.
A TIFF with several pages holds several frames of one pose.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import tifffile
from numpy.typing import NDArray

from ..errors import FormatError
from .atomic import write_atomic

__all__ = ["read_frames", "write_tiff"]

_TIFF = (".tif", ".tiff")


def read_frames(path: str | os.PathLike[str]) -> list[NDArray[np.generic]]:
    """All frames of an image file (several for a multi-page TIFF)."""
    p = Path(path)
    if not p.is_file():
        raise FormatError(f"{p}: no such image file")
    try:
        if p.suffix.lower() in _TIFF:
            data = tifffile.imread(p)
            if data.ndim == 3 and data.shape[2] not in (3, 4):
                return [np.asarray(f) for f in data]
            return [np.asarray(data)]
        image = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    except Exception as exc:
        raise FormatError(
            f"{p}: cannot be read as an image ({type(exc).__name__}: {exc})"
        ) from None
    if image is None:
        raise FormatError(f"{p}: cannot be read as an image (unknown or corrupt format)")
    return [np.asarray(image)]


def write_tiff(
    path: str | os.PathLike[str], frames: list[NDArray[np.generic]] | NDArray[np.generic]
) -> Path:
    """Write one frame or several (as pages) losslessly compressed, atomically."""
    stack = np.asarray(frames)

    def write(tmp: Path) -> None:
        tifffile.imwrite(tmp, stack, compression="zlib", photometric="minisblack")

    return write_atomic(path, write)
