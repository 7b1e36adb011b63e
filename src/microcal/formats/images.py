"""Reading and writing images: TIFF (tifffile, lossless), PNG, JPEG and BMP (OpenCV).

Any bit depth OpenCV or tifffile reads; colour stays colour (BGR), detection converts.
A TIFF with several pages holds several frames of one pose.

An image is read header first: its declared width, height, frames and sample size are
checked before any pixel is decoded, so a small file that declares a huge image (an
"image bomb": 11 KB of TIFF can declare 40000 x 40000 px) is refused in one line instead
of filling the memory. A file holds at most :data:`MAX_IMAGE_BYTES` of decoded pixels, and
when the camera is known no frame may be larger than the camera's image.
"""

from __future__ import annotations

import logging
import os
import struct
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np
import tifffile
from numpy.typing import NDArray

from .._validation import excerpt
from ..errors import FormatError
from .atomic import write_atomic
from .safe_open import opened_regular

__all__ = ["MAX_IMAGE_BYTES", "check_declared_size", "read_frames", "write_tiff"]

_TIFF = (".tif", ".tiff")
#: Most bytes of decoded pixels one image file may hold (all its frames): 256 MiB, five
#: frames of a 25-megapixel 16-bit camera.
MAX_IMAGE_BYTES = 2**28
#: Most bytes of a PNG, JPEG or BMP file (read whole before it is decoded).
MAX_FILE_BYTES = 2**28


def check_declared_size(
    where: str | os.PathLike[str],
    size_px: tuple[int, int],
    frames: int,
    bytes_per_pixel: int,
    max_size_px: tuple[int, int] | None = None,
) -> None:
    """Refuse an image whose declared size is more than microcal decodes.

    Parameters
    ----------
    where : path or str
        What declares it, for the message.
    size_px : (width, height) int
        One frame's declared size, px.
    frames : int
        Frames declared.
    bytes_per_pixel : int
        Bytes of one decoded pixel (samples x bytes per sample).
    max_size_px : (width, height) int, optional
        The camera's image size: no frame may be wider or higher.

    Raises
    ------
    FormatError
        ``WHERE: declares W x H px (x N frames), ...`` with the bound it passes.
    """
    w, h = (int(v) for v in size_px)
    pages = f" x {frames} frames" if frames != 1 else ""
    if max_size_px is not None and (w > max_size_px[0] or h > max_size_px[1]):
        raise FormatError(
            f"{where}: declares frames of {w} x {h} px, larger than the camera's "
            f"{max_size_px[0]} x {max_size_px[1]} px; it is not this camera's image"
        )
    total = w * h * max(frames, 1) * max(bytes_per_pixel, 1)
    if w < 0 or h < 0 or total > MAX_IMAGE_BYTES:
        raise FormatError(
            f"{where}: declares {w} x {h} px{pages} ({total / 2**20:.0f} MiB of pixels), more "
            f"than microcal decodes ({MAX_IMAGE_BYTES // 2**20} MiB); refused before decoding"
        )


def read_frames(
    path: str | os.PathLike[str],
    *,
    max_size_px: tuple[int, int] | None = None,
    link_ok: bool = False,
) -> list[NDArray[np.generic]]:
    """All frames of an image file (several for a multi-page TIFF).

    The header is read first: the declared size is checked (:func:`check_declared_size`)
    before the pixels are decoded.

    Parameters
    ----------
    path : path
        A regular file (never a FIFO or a device; a symbolic link only with ``link_ok``).
    max_size_px : (width, height) int, optional
        The camera's image size, when known: larger frames are refused.
    link_ok : bool
        The user named the file (a pattern of ``--images``): it may be a symbolic link.

    Raises
    ------
    FormatError
        No such file; a symbolic link (unless ``link_ok``), FIFO or device; a file that is
        not an image, truncated or damaged (a JPEG without its end, a PNG without IEND, a
        TIFF whose pages or data stop short); a declared size above the bounds; a layout
        that is not grey or colour frames; pixels that are NaN or infinite. The message
        names it.
    """
    p = Path(path)
    try:
        with opened_regular(p, link_ok=link_ok) as fh:
            data = _read_tiff(p, fh, max_size_px) if p.suffix.lower() in _TIFF else (
                _read_other(p, fh, max_size_px))  # fmt: skip
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        raise FormatError(f"{p}: no such image file") from None
    except FormatError:
        raise
    except Exception as exc:
        raise FormatError(
            f"{p}: cannot be read as an image ({type(exc).__name__}: {excerpt(str(exc), 80)})"
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


def _read_tiff(p: Path, fh: BinaryIO, max_size_px: tuple[int, int] | None) -> NDArray[np.generic]:
    """A TIFF's data, its declared shape checked first; what tifffile only logs (a page
    chain cut short) is an error here."""
    logger = logging.getLogger("tifffile")
    collect, propagate = _Collect(), logger.propagate
    logger.addHandler(collect)
    logger.propagate = False
    try:
        with tifffile.TiffFile(fh, name=p.name) as tif:
            series = tif.series[0]
            _check_tiff_shape(p, tuple(series.shape), np.dtype(series.dtype), max_size_px)
            data = tif.asarray()
            shaped = tif.shaped_metadata
    finally:
        logger.removeHandler(collect)
        logger.propagate = propagate
    if collect.messages:
        message = excerpt(collect.messages[0], 80)
        raise FormatError(f"{p}: damaged TIFF ({message}); it may be truncated")
    expected = shaped[0].get("shape") if shaped else None
    if isinstance(expected, list) and int(np.prod(expected)) != data.size:
        raise FormatError(
            f"{p}: damaged TIFF (holds {data.shape}, written as {excerpt(tuple(expected))}); it "
            f"may be truncated"
        )
    return np.asarray(data)


def _check_tiff_shape(
    p: Path, shape: tuple[int, ...], dtype: np.dtype, max_size_px: tuple[int, int] | None
) -> None:
    """The declared (pages..., H, W[, samples]) of a TIFF series, against the bounds."""
    colour = len(shape) >= 3 and shape[-1] in (3, 4)
    plane = shape[-3:-1] if colour else shape[-2:]
    if len(plane) < 2:
        return  # not frames: refused as such once read (it is small)
    samples = shape[-1] if colour else 1
    frames = int(np.prod(shape[: len(shape) - len(plane) - (1 if colour else 0)], dtype=np.int64))
    h, w = int(plane[0]), int(plane[1])
    check_declared_size(p, (w, h), frames, samples * dtype.itemsize, max_size_px)


def _read_other(p: Path, fh: BinaryIO, max_size_px: tuple[int, int] | None) -> NDArray[np.generic]:
    """A PNG, JPEG or BMP, its header's size checked first, refused when it stops short."""
    size = os.fstat(fh.fileno()).st_size
    if size > MAX_FILE_BYTES:
        raise FormatError(
            f"{p}: {size / 2**20:.0f} MiB, more than microcal reads of an image file "
            f"({MAX_FILE_BYTES // 2**20} MiB)"
        )
    raw = fh.read()
    declared = _declared_size(raw)
    if declared is None:
        raise FormatError(
            f"{p}: cannot be read as an image (unknown or corrupt format; microcal reads TIFF, "
            f"PNG, JPEG and BMP)"
        )
    check_declared_size(p, declared[:2], 1, declared[2], max_size_px)
    if raw.startswith(b"\x89PNG") and b"IEND" not in raw[-32:]:
        raise FormatError(f"{p}: truncated PNG (no IEND at its end)")
    if raw.startswith(b"\xff\xd8") and raw.rfind(b"\xff\xd9") < raw.rfind(b"\xff\xda"):
        raise FormatError(f"{p}: truncated JPEG (no end-of-image marker after its data)")
    image = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FormatError(f"{p}: cannot be read as an image (unknown or corrupt format)")
    return np.asarray(image)


#: Samples of a decoded PNG pixel by colour type (a palette decodes to BGR).
_PNG_SAMPLES = {0: 1, 2: 3, 3: 3, 4: 4, 6: 4}
#: JPEG start-of-frame markers (C4, C8 and CC are other segments).
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _declared_size(raw: bytes) -> tuple[int, int, int] | None:
    """(width, height, bytes per decoded pixel) a PNG, JPEG or BMP header declares; None
    when ``raw`` is none of them or its header is cut."""
    if raw.startswith(b"\x89PNG\r\n\x1a\n") and raw[12:16] == b"IHDR" and len(raw) >= 26:
        w, h = struct.unpack(">II", raw[16:24])
        depth, colour = raw[24], raw[25]
        return w, h, _PNG_SAMPLES.get(colour, 4) * (2 if depth == 16 else 1)
    if raw.startswith(b"\xff\xd8"):
        return _jpeg_size(raw)
    if raw.startswith(b"BM") and len(raw) >= 30:
        w, h = struct.unpack("<ii", raw[18:26])
        return abs(w), abs(h), 4
    return None


def _jpeg_size(raw: bytes) -> tuple[int, int, int] | None:
    """A JPEG's frame size from its start-of-frame segment (segments walked, not decoded)."""
    k = 2
    while k + 4 <= len(raw):
        if raw[k] != 0xFF:
            return None
        marker = raw[k + 1]
        if marker == 0xFF:  # fill byte
            k += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            k += 2
            continue
        (length,) = struct.unpack(">H", raw[k + 2 : k + 4])
        if marker in _JPEG_SOF:
            if k + 10 > len(raw):
                return None
            h, w = struct.unpack(">HH", raw[k + 5 : k + 9])
            return w, h, max(raw[k + 9], 1) * (2 if raw[k + 4] > 8 else 1)
        if marker == 0xDA or length < 2:
            return None
        k += 2 + length
    return None


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
