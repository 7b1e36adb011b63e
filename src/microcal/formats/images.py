"""Reading and writing images: TIFF (tifffile, lossless), PNG and JPEG (OpenCV).

Any bit depth OpenCV or tifffile reads; colour stays colour (BGR), detection converts.
A TIFF with several pages holds several frames of one pose.
"""

from __future__ import annotations

import logging
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
    """All frames of an image file (several for a multi-page TIFF).

    Raises
    ------
    FormatError
        No such file; a file that is not an image, truncated or damaged (a JPEG without
        its end, a PNG without IEND, a TIFF whose pages or data stop short); a layout that is
        not grey or colour frames; pixels that are NaN or infinite. The message names it.
    """
    p = Path(path)
    if not p.is_file():
        raise FormatError(f"{p}: no such image file")
    try:
        data = _read_tiff(p) if p.suffix.lower() in _TIFF else _read_other(p)
    except FormatError:
        raise
    except Exception as exc:
        raise FormatError(
            f"{p}: cannot be read as an image ({type(exc).__name__}: {exc})"
        ) from None
    frames = _frames_of(data, p)
    for frame in frames:
        if frame.dtype.kind == "f" and not np.all(np.isfinite(frame)):
            bad = int(np.count_nonzero(~np.isfinite(frame)))
            raise FormatError(f"{p}: {bad} pixels are NaN or infinite; it is not a camera image")
    return frames


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def _read_tiff(p: Path) -> NDArray[np.generic]:
    """A TIFF's data; what tifffile only logs (a page chain cut short) is an error here."""
    logger = logging.getLogger("tifffile")
    collect, propagate = _Collect(), logger.propagate
    logger.addHandler(collect)
    logger.propagate = False
    try:
        with tifffile.TiffFile(p) as tif:
            data = tif.asarray()
            shaped = tif.shaped_metadata
    finally:
        logger.removeHandler(collect)
        logger.propagate = propagate
    if collect.messages:
        raise FormatError(f"{p}: damaged TIFF ({collect.messages[0]}); it may be truncated")
    expected = shaped[0].get("shape") if shaped else None
    if isinstance(expected, list) and int(np.prod(expected)) != data.size:
        raise FormatError(
            f"{p}: damaged TIFF (holds {data.shape}, written as {tuple(expected)}); it may be "
            f"truncated"
        )
    return np.asarray(data)


def _read_other(p: Path) -> NDArray[np.generic]:
    """A PNG or JPEG (anything else OpenCV decodes), refused when it stops short."""
    raw = p.read_bytes()
    if raw.startswith(b"\x89PNG") and b"IEND" not in raw[-32:]:
        raise FormatError(f"{p}: truncated PNG (no IEND at its end)")
    if raw.startswith(b"\xff\xd8") and raw.rfind(b"\xff\xd9") < raw.rfind(b"\xff\xda"):
        raise FormatError(f"{p}: truncated JPEG (no end-of-image marker after its data)")
    image = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FormatError(f"{p}: cannot be read as an image (unknown or corrupt format)")
    return np.asarray(image)


def _frames_of(data: NDArray[np.generic], p: Path) -> list[NDArray[np.generic]]:
    """Frames of (H, W) grey or (H, W, 3|4) colour, from one image or a stack of pages."""
    colour = data.ndim >= 3 and data.shape[-1] in (3, 4)
    if data.ndim == 2 or (data.ndim == 3 and colour):
        frames = [data]
    elif data.ndim == 3 or (data.ndim == 4 and colour):
        frames = [np.asarray(f) for f in data]
    else:
        raise FormatError(
            f"{p}: image data of shape {data.shape} is not grey or colour frames (expected "
            f"H x W, H x W x 3 or pages of them)"
        )
    if min(frames[0].shape[:2]) < 8 or data.dtype.kind not in "uif":
        raise FormatError(f"{p}: {data.shape} {data.dtype} is not a camera image")
    return frames


def write_tiff(
    path: str | os.PathLike[str], frames: list[NDArray[np.generic]] | NDArray[np.generic]
) -> Path:
    """Write one frame or several (as pages) losslessly compressed, atomically.

    zlib at level 1: noisy camera frames shrink to about 70 % at any level, and level 1 takes
    less than half the time of the default (6).
    """
    stack = np.asarray(frames)

    def write(tmp: Path) -> None:
        tifffile.imwrite(
            tmp, stack, compression="zlib", compressionargs={"level": 1}, photometric="minisblack"
        )

    return write_atomic(path, write)
