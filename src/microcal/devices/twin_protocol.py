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
                            "exposure_ms", "regions"}, ...]}`` (``regions``: the camera's
                            frames are to be read by region, SNAP and REGION; absent: false)
``GRAB <camera>``           ``OK <height> <width> <dtype> <nbytes>`` then ``nbytes`` bytes:
                            the frame in row-major order, ``uint8`` or little-endian
                            ``uint16``; or ``ERR <kind> <message>`` when there is no frame
``EXPOSURE <camera> <ms>``  ``OK``, or ``ERR input <message>``
``TRUTH``                   one JSON line ``{"t_s", "position_um", "target_stage_um",
                            "devices"}``: the end-effector's true position, the stage's
                            true joints and every device's true position by name, µm
                            (ground truth: for tests and comparisons, never a calibration)
``SNAP <camera>``           ``OK <id> <height> <width> <dtype>``: one frame exposed and kept
                            by the server, read by region afterwards; it keeps the last
                            :data:`KEPT_FRAMES` frames (older ids are told ``ERR input``)
``REGION <id> <x0> <y0>     the pixels of a kept frame over [x0, x1) x [y0, y1), inside the
<x1> <y1>``                 frame: answered as GRAB (``OK <h> <w> <dtype> <nbytes>`` and the
                            bytes), or ``ERR input <message>``
``MOVE <stage> <um>...``    move a stage (one value for a focus drive, two for an X-Y stage)
                            to the given position, µm: ``OK``, or ``ERR limit <message>`` for
                            a position outside its travel (nothing moved)
``POS <stage>``             ``OK <um>...``: the stage's readout, µm
``BUSY <stage>``            ``OK 1`` while the stage moves, else ``OK 0``
``STOP <stage>``            ``OK``: the stage stopped where it is
==========================  ===============================================================

The stages (the ``patch`` preset's focus drive and X-Y stage) are listed in INFO's
``"stages": [{"name", "kind", "limits_um"}, ...]`` (``kind`` ``"xy"`` or ``"focus"``,
``limits_um`` one ``[low, high]`` per axis); a twin of a platform has none.

``<kind>`` is ``frame`` (a dropped frame, grab again), ``timeout`` (no frame in time, grab
again; also the answer to any request that took longer than the server's request timeout),
``device`` (any other device error), ``limit`` (a stage position outside its travel; nothing
moved), ``input`` (a request it does not take) or ``busy`` (the first line of a connection
beyond the server's clients at once, which it then closes).

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
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DeviceError, DeviceTimeoutError, FrameError

__all__ = [
    "BUSY",
    "DTYPES",
    "EOL",
    "ERR",
    "EXPOSURE",
    "FRAMES_PORT",
    "GRAB",
    "INFO",
    "INFO_FORMAT",
    "KEPT_FRAMES",
    "KIND_BUSY",
    "KIND_DEVICE",
    "KIND_FRAME",
    "KIND_INPUT",
    "KIND_LIMIT",
    "KIND_TIMEOUT",
    "MAX_FRAME_BYTES",
    "MAX_HEADER_BYTES",
    "MAX_STAGE_AXES",
    "MOVE",
    "OK",
    "POS",
    "REGION",
    "SNAP",
    "STAGE_KINDS",
    "STOP",
    "TRUTH",
    "CameraInfo",
    "FrameHeader",
    "SnapHeader",
    "StageInfo",
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
    "info_regions",
    "info_stage",
    "parse_frame_header",
    "parse_numbers",
    "parse_snap_header",
    "region_request",
    "snap_request",
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
SNAP = "SNAP"
REGION = "REGION"
MOVE = "MOVE"
POS = "POS"
BUSY = "BUSY"
STOP = "STOP"
# the first word of an answer line
OK = "OK"
ERR = "ERR"
# the kinds of an ERR answer
KIND_FRAME = "frame"
KIND_TIMEOUT = "timeout"
KIND_DEVICE = "device"
KIND_INPUT = "input"
KIND_LIMIT = "limit"
KIND_BUSY = "busy"

#: The pixel types of a frame, by their name in a GRAB header and in INFO.
DTYPES: dict[str, np.dtype[Any]] = {"uint8": np.dtype(np.uint8), "uint16": np.dtype("<u2")}
#: The longest answer line a client reads, bytes.
MAX_HEADER_BYTES = 1 << 16
#: The largest frame a client accepts, bytes (256 MiB: far above any sensor here).
MAX_FRAME_BYTES = 1 << 28
#: The frames of SNAP the server keeps for REGION requests (the oldest is dropped beyond).
KEPT_FRAMES = 16
#: The kinds of stage and their number of axes.
STAGE_KINDS = {"xy": 2, "focus": 1}
#: The most values a stage request carries.
MAX_STAGE_AXES = 2


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
    regions: bool = False

    def to_json(self) -> dict[str, Any]:
        """The camera's JSON object."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class StageInfo:
    """One stage of the INFO answer: its name, kind (``xy`` or ``focus``) and travel per
    axis, ``((low, high), ...)`` µm."""

    name: str
    kind: str
    limits_um: tuple[tuple[float, float], ...]

    def to_json(self) -> dict[str, Any]:
        """The stage's JSON object."""
        return {"name": self.name, "kind": self.kind,
                "limits_um": [list(pair) for pair in self.limits_um]}  # fmt: skip


@dataclass(frozen=True)
class SnapHeader:
    """A SNAP answer ``OK <id> <height> <width> <dtype>``, checked (:func:`parse_snap_header`)."""

    frame_id: int
    height: int
    width: int
    dtype: str


# --- requests (the client) -----------------------------------------------------------------
def grab_request(camera: str) -> str:
    """The request for one frame of ``camera``."""
    return f"{GRAB} {camera}"


def snap_request(camera: str) -> str:
    """The request for one frame of ``camera``, kept by the server to be read by region."""
    return f"{SNAP} {camera}"


def region_request(frame_id: int, box: tuple[int, int, int, int]) -> str:
    """The request for the pixels of kept frame ``frame_id`` over ``box`` (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = (int(v) for v in box)
    return f"{REGION} {int(frame_id)} {x0} {y0} {x1} {y1}"


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


def parse_snap_header(line: str) -> SnapHeader | None:
    """The answer to SNAP, checked (None: not ``OK`` and four words, an ERR line say).

    Raises
    ------
    ValueError
        Words that are not integers, a pixel type the protocol does not carry, or a frame of
        no pixels or above :data:`MAX_FRAME_BYTES` (the message says which).
    """
    words = line.split()
    if len(words) != 5 or words[0] != OK:
        return None
    try:
        frame_id, height, width = int(words[1]), int(words[2]), int(words[3])
    except ValueError:
        raise ValueError(f"has an id or a size that are not integers ({line[:60]!r})") from None
    problem = frame_size_problem(height, width, words[4])
    if problem is not None:
        raise ValueError(f"announces {problem}")
    return SnapHeader(frame_id, height, width, words[4])


def parse_numbers(line: str, count: int) -> tuple[float, ...] | None:
    """The ``count`` finite numbers of an answer ``OK <v> ...`` (POS, BUSY), or None for any
    other line (an ERR line, a line of other words)."""
    words = line.split()
    if len(words) != count + 1 or words[0] != OK:
        return None
    try:
        values = tuple(float(w) for w in words[1:])
    except ValueError:
        return None
    return values if all(math.isfinite(v) for v in values) else None


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
    """The INFO answer, its ``cameras`` and ``stages`` lists (no stages: an empty list).

    Raises
    ------
    ValueError, KeyError, TypeError
        Not an INFO answer.
    """
    info = json.loads(line)
    cameras = list(info["cameras"])
    stages = list(info.get("stages", []))
    return {**info, "cameras": cameras, "stages": stages}


def info_stage(stage: Mapping[str, Any]) -> StageInfo:
    """One stage of the INFO answer, checked.

    Raises
    ------
    KeyError, TypeError, ValueError
        Not a stage's description (an unknown kind, limits not one finite ``[low, high]``
        with low <= high per axis of its kind).
    """
    kind = str(stage["kind"])
    if kind not in STAGE_KINDS:
        raise ValueError(f"stage kind {kind!r}")
    limits = tuple((float(lo), float(hi)) for lo, hi in stage["limits_um"])
    if len(limits) != STAGE_KINDS[kind] or not all(
        math.isfinite(lo) and math.isfinite(hi) and lo <= hi for lo, hi in limits
    ):
        raise ValueError(f"stage limits {stage['limits_um']!r}")
    return StageInfo(str(stage["name"]), kind, limits)


def info_regions(cam: Mapping[str, Any]) -> bool:
    """Whether a camera of the INFO answer is to be read by region (``regions``; absent:
    false)."""
    return cam.get("regions", False) is True


def info_camera(cam: Mapping[str, Any]) -> tuple[str, tuple[int, int], str, float]:
    """``(name, (height, width), dtype, exposure_ms)`` of one camera of the INFO answer.

    Raises
    ------
    KeyError, TypeError, ValueError
        Not a camera's description.
    """
    shape = (int(cam["height"]), int(cam["width"]))
    return str(cam["name"]), shape, str(cam["dtype"]), float(cam["exposure_ms"])
