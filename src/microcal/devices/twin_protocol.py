"""The digital twin's frame protocol: its words, its answers' encoding, its limits.

The twin's frame server (:mod:`microcal.sim.frame_server`) writes this protocol and the
twin's cameras (:mod:`microcal.devices.twin_camera`) read it; both take every word, format
and limit from here.

A line protocol (ASCII, lines end in ``\\r\\n``; ``\\n`` is accepted), one request at a time
per connection, on ``frames_port`` (:data:`FRAMES_PORT` by default):

==========================  ===============================================================
``INFO``                    one JSON line: ``{"format": "microcal.twin/1", "preset",
                            "seed", "time_scale", "cameras": [{"name", "width",
                            "height", "bit_depth", "dtype", "pixel_size_um",
                            "exposure_ms"}, ...]}``
``GRAB <camera>``           ``OK <height> <width> <dtype> <nbytes>`` then ``nbytes`` bytes:
                            the frame in row-major order, ``uint8`` or little-endian
                            ``uint16``; or ``ERR <kind> <message>`` when there is no frame
``EXPOSURE <camera> <ms>``  ``OK``, or ``ERR input <message>``
``TRUTH``                   one JSON line ``{"t_s", "position_um", "target_stage_um",
                            "devices"}``: the end-effector's true position, the stage's
                            true joints and every device's true position by name, µm
                            (ground truth: for tests and comparisons, never a calibration)
==========================  ===============================================================

``<kind>`` is ``frame`` (a dropped frame, grab again), ``timeout`` (no frame in time, grab
again; also the answer to any request that took longer than the server's request timeout),
``device`` (any other device error), ``input`` (a request it does not take) or ``busy`` (the
first line of a connection beyond the server's clients at once, which it then closes).

Limits. Neither side trusts the other: the server (:mod:`microcal.sim.line_server`, whose
docstring gives its defaults) drops a request line longer than its limit, closes a connection
idle for its idle timeout, refuses connections beyond its clients at once and answers
``ERR timeout`` to a request that takes longer than its request timeout; a client reads an
answer line of at most :data:`MAX_HEADER_BYTES` and checks a frame's header before reading a
byte of the frame (:func:`parse_frame_header`): at most :data:`MAX_FRAME_BYTES`, and exactly
``height * width`` pixels of a known type.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DeviceError, DeviceTimeoutError, FrameError

__all__ = [
    "DTYPES",
    "EOL",
    "ERR",
    "EXPOSURE",
    "FRAMES_PORT",
    "GRAB",
    "INFO",
    "INFO_FORMAT",
    "KIND_BUSY",
    "KIND_DEVICE",
    "KIND_FRAME",
    "KIND_INPUT",
    "KIND_TIMEOUT",
    "MAX_FRAME_BYTES",
    "MAX_HEADER_BYTES",
    "OK",
    "TRUTH",
    "CameraInfo",
    "FrameHeader",
    "ascii_message",
    "decode_error",
    "decode_frame",
    "decode_info",
    "encode_error",
    "encode_frame",
    "encode_json",
    "encode_ok",
    "error_of_kind",
    "exposure_request",
    "frame_size_problem",
    "grab_request",
    "info_camera",
    "parse_frame_header",
]

#: The frame server's default port (``microcal twin --frames-port``).
FRAMES_PORT = 55561
#: The format id of the INFO answer.
INFO_FORMAT = "microcal.twin/1"
#: The end of every line the server writes.
EOL = b"\r\n"

# the requests
INFO = "INFO"
GRAB = "GRAB"
EXPOSURE = "EXPOSURE"
TRUTH = "TRUTH"
# the first word of an answer line
OK = "OK"
ERR = "ERR"
# the kinds of an ERR answer
KIND_FRAME = "frame"
KIND_TIMEOUT = "timeout"
KIND_DEVICE = "device"
KIND_INPUT = "input"
KIND_BUSY = "busy"

#: The pixel types of a frame, by their name in a GRAB header and in INFO.
DTYPES: dict[str, np.dtype[Any]] = {"uint8": np.dtype(np.uint8), "uint16": np.dtype("<u2")}
#: The longest answer line a client reads, bytes.
MAX_HEADER_BYTES = 1 << 16
#: The largest frame a client accepts, bytes (256 MiB: far above any sensor here).
MAX_FRAME_BYTES = 1 << 28


@dataclass(frozen=True)
class CameraInfo:
    """One camera of the INFO answer (its JSON object has these keys, in this order)."""

    name: str
    width: int
    height: int
    bit_depth: int
    dtype: str
    pixel_size_um: float
    exposure_ms: float

    def to_json(self) -> dict[str, Any]:
        """The camera's JSON object."""
        return dataclasses.asdict(self)


# --- requests (the client) -----------------------------------------------------------------
def grab_request(camera: str) -> str:
    """The request for one frame of ``camera``."""
    return f"{GRAB} {camera}"


def exposure_request(camera: str, exposure_ms: float) -> str:
    """The request setting ``camera``'s exposure, ms."""
    return f"{EXPOSURE} {camera} {exposure_ms!r}"


# --- answers (the server) ------------------------------------------------------------------
def ascii_message(text: str) -> str:
    """A message fit for one line of the twin's protocols (this one's and the MCS2 peer's,
    :mod:`microcal.sim.mcs2_peer`): ASCII, no quotes, separators or line ends."""
    clean = text.replace("µ", "u").replace('"', "'").replace(";", ",")
    clean = " ".join(clean.split())
    return clean.encode("ascii", errors="replace").decode("ascii")


def encode_ok() -> bytes:
    """The answer of a request that was done."""
    return OK.encode("ascii") + EOL


def encode_error(kind: str, message: str) -> bytes:
    """The answer ``ERR <kind> <message>`` (the message made fit for one line)."""
    return f"{ERR} {kind} {ascii_message(message)}".encode("ascii") + EOL


def encode_json(value: object) -> bytes:
    """A JSON answer line (INFO, TRUTH)."""
    return json.dumps(value).encode("ascii") + EOL


def encode_frame(frame: NDArray[Any]) -> bytes:
    """The answer to GRAB: the header line, then the frame's bytes.

    Parameters
    ----------
    frame : (height, width) uint8 or uint16
        Sent row-major, little-endian.
    """
    data = np.ascontiguousarray(frame, dtype=np.dtype(frame.dtype).newbyteorder("<"))
    h, w = data.shape
    header = f"{OK} {h} {w} {np.dtype(frame.dtype).name} {data.nbytes}"
    return header.encode("ascii") + EOL + data.tobytes()


# --- answers (the client) ------------------------------------------------------------------
@dataclass(frozen=True)
class FrameHeader:
    """A GRAB answer's header ``OK <height> <width> <dtype> <nbytes>``, checked
    (:func:`parse_frame_header`): ``nbytes == height * width * itemsize <= MAX_FRAME_BYTES``."""

    height: int
    width: int
    dtype: str
    nbytes: int


def frame_size_problem(height: int, width: int, dtype: str) -> str | None:
    """What makes a frame of this shape and pixel type one the protocol does not carry (a
    phrase), or None: a known pixel type, at least one pixel, at most :data:`MAX_FRAME_BYTES`."""
    if dtype not in DTYPES:
        return f"pixel type {dtype!r} (expected {' or '.join(DTYPES)})"
    if height < 1 or width < 1:
        return f"a frame of {height} x {width} pixels"
    nbytes = height * width * DTYPES[dtype].itemsize
    if nbytes > MAX_FRAME_BYTES:
        return f"frames of {nbytes} bytes, above the protocol's limit of {MAX_FRAME_BYTES} bytes"
    return None


def parse_frame_header(line: str) -> FrameHeader | None:
    """The header of a GRAB answer, checked before a byte of the frame is read (None: the
    line is not ``OK`` and four words, an ERR line say).

    Raises
    ------
    ValueError
        A header of a frame this protocol does not carry; the message is a phrase saying
        why (``declares 1000 bytes for a 2 x 2 uint8 frame of 4 bytes``, ``announces a frame
        of ... bytes, above the protocol's limit of ... bytes``).
    """
    words = line.split()
    if len(words) != 5 or words[0] != OK:
        return None
    try:
        height, width, nbytes = int(words[1]), int(words[2]), int(words[4])
    except ValueError:
        raise ValueError(
            f"has a height, width or size that are not integers ({line[:60]!r})"
        ) from None
    dtype = words[3]
    if nbytes > MAX_FRAME_BYTES:
        raise ValueError(
            f"announces a frame of {nbytes} bytes, above the protocol's limit of "
            f"{MAX_FRAME_BYTES} bytes"
        )
    if dtype not in DTYPES:
        raise ValueError(f"announces pixel type {dtype!r} (expected {' or '.join(DTYPES)})")
    if height < 1 or width < 1:
        raise ValueError(f"announces a frame of {height} x {width} pixels")
    expected = height * width * DTYPES[dtype].itemsize
    if nbytes != expected:
        raise ValueError(
            f"declares {nbytes} bytes for a {height} x {width} {dtype} frame of {expected} bytes"
        )
    return FrameHeader(height, width, dtype, nbytes)


def decode_frame(header: FrameHeader, data: bytes | bytearray) -> NDArray[np.unsignedinteger]:
    """The frame, (height, width), of a checked header and its ``header.nbytes`` bytes (a
    view of ``data``, which it keeps)."""
    frame = np.frombuffer(data, DTYPES[header.dtype], count=header.height * header.width)
    return frame.reshape(header.height, header.width)


def decode_error(line: str) -> tuple[str, str] | None:
    """``(kind, message)`` of an ``ERR <kind> <message>`` line; None for any other line."""
    if line.split()[:1] != [ERR]:
        return None
    kind, _, message = line.partition(" ")[2].partition(" ")
    return kind, message


def error_of_kind(kind: str) -> type[DeviceError]:
    """The error a driver raises for an ERR kind: :class:`FrameError` for ``frame``,
    :class:`DeviceTimeoutError` for ``timeout`` (both transient), else :class:`DeviceError`."""
    return {KIND_FRAME: FrameError, KIND_TIMEOUT: DeviceTimeoutError}.get(kind, DeviceError)


def decode_info(line: str) -> dict[str, Any]:
    """The INFO answer, its ``cameras`` a list.

    Raises
    ------
    ValueError, KeyError, TypeError
        Not an INFO answer.
    """
    info = json.loads(line)
    cameras = list(info["cameras"])
    return {**info, "cameras": cameras}


def info_camera(cam: Mapping[str, Any]) -> tuple[str, tuple[int, int], str, float]:
    """``(name, (height, width), dtype, exposure_ms)`` of one camera of the INFO answer.

    Raises
    ------
    KeyError, TypeError, ValueError
        Not a camera's description.
    """
    shape = (int(cam["height"]), int(cam["width"]))
    return str(cam["name"]), shape, str(cam["dtype"]), float(cam["exposure_ms"])
