"""Fuzzing of every reader of a user file: bad input raises MicrocalError, never anything else.

Each reader is given files made by mutating a valid file of its kind (written by microcal's
own writers, or one of ``examples/rigs``): JSON values replaced by values of other types, keys
deleted or added, CSV cells, rows and columns changed, TOML settings changed, then bytes
flipped, deleted or inserted, lines duplicated or dropped, a byte-order mark or other line
endings. Every reader must return normally or raise :class:`~microcal.errors.MicrocalError`,
within :data:`HANG_SECONDS`; any other exception fails the test with its own traceback, so
Hypothesis reports (and shrinks) each distinct bug separately.

The generators live here; ``scripts/fuzz_readers.py`` runs them for many more inputs per
reader and prints a summary.
"""

from __future__ import annotations

import copy
import csv
import ctypes
import functools
import io
import json
import math
import re
import sys
import tempfile
import threading
import time
import tomllib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from microcal.errors import FormatError, InputError, MicrocalError
from microcal.formats.calibration_file import (
    Calibration,
    ManipulatorCalibration,
    load_calibration,
    write_calibration,
)
from microcal.formats.cameras_file import cameras_to_dict, load_cameras, write_cameras
from microcal.formats.commands_csv import read_joint_csv
from microcal.formats.measurements import read_measurements, write_measurements
from microcal.formats.rig_file import load_rig
from microcal.formats.run_directory import RunDirectory
from microcal.journal_record import JournalRecord, PoseStatus

__all__ = [
    "EXAMPLES",
    "HANG_SECONDS",
    "READERS",
    "FuzzCase",
    "HangError",
    "Outcome",
    "Reader",
    "call_with_time_limit",
    "compact_repr",
    "run_case",
    "seed_files",
]

#: A reader still running after this long has hung.
HANG_SECONDS = 5.0
#: The recursion limit a reader runs under: Python's default.
READER_RECURSION_LIMIT = 1000
#: Inputs per reader in the test suite (the script runs more).
EXAMPLES = 200

REPO = Path(__file__).resolve().parents[2]
RIG_EXAMPLES = REPO / "examples" / "rigs"


# --- what a fuzzed reader is given -------------------------------------------------------------
_REPEATS = re.compile(rb"(.{1,8}?)\1{7,}", re.DOTALL)


def compact_repr(data: bytes, limit: int | None = None) -> str:
    """``data`` as a Python expression, a run of one short piece written ``b'[' * 1000``.

    ``limit`` cuts the middle of a longer result (for summaries; the full form evaluates back
    to ``data``).
    """
    parts: list[str] = []
    pos = 0
    for m in _REPEATS.finditer(data):
        if m.start() > pos:
            parts.append(repr(data[pos : m.start()]))
        unit = m.group(1)
        parts.append(f"{unit!r} * {len(m.group(0)) // len(unit)}")
        pos = m.end()
    if pos < len(data) or not parts:
        parts.append(repr(data[pos:]))
    text = " + ".join(parts)
    if limit is not None and len(text) > limit:
        half = max(limit // 2 - 10, 10)
        text = f"{text[:half]} ... {text[-half:]} ({len(data)} bytes)"
    return text


def _option_repr(value: object) -> str:
    return value.__name__ if isinstance(value, type) else repr(value)


@dataclass(frozen=True)
class FuzzCase:
    """One generated input: the file's bytes and the reader's keyword arguments."""

    data: bytes
    options: Mapping[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        if not self.options:
            return f"FuzzCase({compact_repr(self.data)})"
        options = ", ".join(f"{k!r}: {_option_repr(v)}" for k, v in self.options.items())
        return f"FuzzCase({compact_repr(self.data)}, options={{{options}}})"

    def _repr_pretty_(self, p: Any, cycle: bool) -> None:
        p.text(repr(self))

    def short(self, limit: int = 160) -> str:
        """A one-line summary of at most about ``limit`` characters."""
        options = ", ".join(f"{k}={_option_repr(v)}" for k, v in self.options.items())
        return compact_repr(self.data, limit) + (f" [{options}]" if options else "")


# --- valid files to start from -----------------------------------------------------------------
@dataclass(frozen=True)
class SeedFiles:
    """Valid files of every kind a reader reads, as bytes."""

    journal: bytes
    manifest: bytes
    commands: bytes
    design: bytes
    measurements: bytes
    cameras: bytes
    calibration: bytes
    rigs: tuple[bytes, ...]


_D_UM = np.array(
    [[100.0, 200.0, 300.0], [1100.0, 1200.0, 1300.0], [2100.0, 2200.0, 2300.0], [50.5, 7.25, 9.0]]
)


def _stereo_calibration() -> Any:
    from microcal.thesis.cameras import thesis_cameras
    from microcal.vision.stereo_calibration import CameraCalibration, StereoCalibration

    cams = {
        c.name: CameraCalibration(c, 0.05, {"v1": 0.05}, 1, residuals_px={"v1": np.zeros((2, 4))})
        for c in thesis_cameras(np.array([0.5, 0.0, 1e-3, -1e-3, 0.0]))
    }
    return StereoCalibration("known-displacements", cams, 0.06, 123456.0)


def build_seed_files(directory: Path) -> SeedFiles:
    """Write a valid file of every kind into ``directory`` with microcal's writers; read them."""
    from microcal.formats.provenance import provenance
    from microcal.procedures.identification import identify
    from microcal.sim.synthetic_run import synthetic_run

    run = directory / "run"
    manifest = {
        "rig": {"driver": "sim", "preset": "thesis", "seed": 0, "overrides": {}},
        "target": "chessboard:4x3:400",
        "cameras": ["top", "side"],
        "design": {"kind": "random", "poses": len(_D_UM), "seed": 7, "low_um": [0, 0, 0]},
        "settle": "vision",
        "frames_per_pose": 2,
        "store": "roi",
        "provenance": {"command": "acquire", "software": "microcal"},
    }
    writer = RunDirectory.create(run, manifest, _D_UM)
    rng = np.random.default_rng(0)

    def frames(shape: tuple[int, int]) -> list[Any]:
        return [rng.integers(0, 4096, shape, dtype=np.uint16) for _ in range(2)]

    def record(pose: int, status: PoseStatus = "ok", reason: str | None = None,
               **extra: Any) -> JournalRecord:  # fmt: skip
        return JournalRecord(pose=pose, commanded_um=_D_UM[pose - 1].tolist(), approach={},
                             status=status, wall_time_s=1700000000.5 + pose, sim_time_s=0.0,
                             move_s=0.0, settle_s=1.5 * pose, residual_px=None,
                             reported_um=_D_UM[pose - 1].tolist() if status == "ok" else None,
                             reason=reason, **extra)  # fmt: skip

    writer.store(
        1,
        {"top": frames((8, 12)), "side": frames((4, 6))},
        record(1, readings={"temperature_c": 21.5}, roi_px={"side": (3, 2, 12, 8)}),
    )
    writer.store(2, {}, record(2, "failed", reason="move timed out"))
    writer.store(3, {"top": frames((8, 12)), "side": frames((8, 12))}, record(3))

    measurements = write_measurements(
        directory / "measurements.csv",
        _D_UM,
        _D_UM * 1.01 + 3.0,
        std_um=np.full((len(_D_UM), 3), 0.25),
        status=["ok", "failed", "ok", "ok"],
        reason=["", "no board in side", "", ""],
        extra={"temperature": np.array([21.5, np.nan, 21.75, 22.0])},
        pose=[1, 2, 3, 5],
    )

    stereo = _stereo_calibration()
    camera_data = cameras_to_dict(stereo, {"software": "microcal", "command": "stereo-calibrate"})
    cameras = write_cameras(directory / "cameras.json", camera_data)

    sim = synthetic_run(40, seed=11)
    manipulators = {
        name: ManipulatorCalibration(name, ident.model, ident.validation)
        for name, ident in (
            ("m1", identify(sim.d_um, sim.measured_um, "polynomial")),
            ("m2", identify(sim.d_um, sim.measured_um, "matrix")),
        )
    }
    calibration = write_calibration(
        directory / "calibration.json",
        Calibration(manipulators, camera_data["cameras"], provenance(command="fit")),
    )

    design = (
        "\ufeffdx_um,dy_um,dz_um,note\r\n100,200,300,first\r\n1100.5,1200,1300,\r\n"
        "2100,2200,2300.25,last\r\n"
    ).encode()
    rigs = [p.read_bytes() for p in sorted(RIG_EXAMPLES.glob("*.toml"))]
    rigs.append(b'driver = "sim"\n')
    return SeedFiles(
        journal=(run / "journal.jsonl").read_bytes(),
        manifest=(run / "run.json").read_bytes(),
        commands=(run / "commands.csv").read_bytes(),
        design=design,
        measurements=measurements.read_bytes(),
        cameras=cameras.read_bytes(),
        calibration=calibration.read_bytes(),
        rigs=tuple(rigs),
    )


@functools.cache
def seed_files() -> SeedFiles:
    """The valid files every generator starts from (built once per process)."""
    with tempfile.TemporaryDirectory(prefix="microcal-fuzz-seeds-") as tmp:
        return build_seed_files(Path(tmp))


# --- strange values ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Raw:
    """Text written into a document as it is: what a serializer refuses or normalises
    (``NaN``, a 5000-digit number, arrays nested 3000 deep, TOML dates)."""

    text: str


def _nested(n: int, open_: str, inner: str, close: str) -> Raw:
    return Raw(open_ * n + inner + close * n)


# Numbers about the largest float (309 digits) and about Python's limit of 4300 digits for
# int(); nesting about Python's recursion limit.
_DIGIT_COUNTS = st.one_of(st.integers(300, 330), st.integers(4250, 4400))
_DIGITS = _DIGIT_COUNTS.map(lambda n: Raw("9" * n))
_DEPTH = st.integers(500, 5000)

_JSON_RAW = st.one_of(
    st.sampled_from(["NaN", "Infinity", "-Infinity", "1e999", "-1e999", "-0", "1E400", "5e-400",
                     "01", "+1", ".5", "0x10", "nul", '"\\ud800"', '"\\u0000"', "[1,]", "{}"]),
    _DIGITS,
    _DEPTH.map(lambda n: _nested(n, "[", "", "]")),
    _DEPTH.map(lambda n: _nested(n, '{"a": ', "1", "}")),
).map(lambda v: v if isinstance(v, Raw) else Raw(v))  # fmt: skip

_TOML_RAW = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "+inf", "-0", "1979-05-27T07:32:00Z", "07:32:00",
                     "1979-05-27", "1979-05-27T07:32:00", "0x7fffffffffffffff", "0o777", "0b101",
                     "1_000", "1e999", "'literal'", '"""two\nlines"""', "'''x'''", "true", "[]",
                     "{}", '"\\u0000"', '"\\ud800"', "9223372036854775808"]),
    _DIGITS,
    _DEPTH.map(lambda n: _nested(n, "[", "1", "]")),
    _DEPTH.map(lambda n: _nested(n, "{ a = ", "1", " }")),
).map(lambda v: v if isinstance(v, Raw) else Raw(v))  # fmt: skip

#: Strings that mean something to some reader, or to a parser.
WORDS = ("", " ", "ok", "failed", "pinhole", "fisheye", "matrix", "polynomial",
         "microcal.run/1", "microcal.run/2", "microcal.calibration/1", "microcal.calibration/9",
         "microcal.cameras/1", "microcal.results/1", "microcal.run", "/1", "dx", "dy", "dz", "T",
         "dx^2", "dx*dy", "T^2", "1", "dx^0", "dx^-1", "dx^", "^2", "*", "dx**2", "x", "y", "z",
         "nan", "inf", "-1", "0", "1e999", "images/top_0001.tiff", "../../etc/passwd", "/", "\\",
         "a\x00b", "\ufeff", "é", "µm", "\ud800", "\n", "sim", "hardware", "thesis", "aravis",
         "micromanager", "smaract-mcs2", "Mono8", "Mono32", "chessboard:4x3:400", "chessboard",
         "top", "side", "vision", "fixed:1.5", "roi", "full", "mydevices:load", "MMConfig.cfg")  # fmt: skip

#: Keys an edited file might add (some known to some schema, some not).
KEYS = st.one_of(
    st.sampled_from(["format", "pose", "status", "reason", "images", "file", "sha256", "roi",
                     "offset_px", "full_size_px", "frames", "cameras", "manipulators", "model",
                     "validation", "kind", "terms", "selection", "matrix_model", "K", "dist",
                     "image_size_px", "rig", "design", "driver", "preset", "seed", "overrides",
                     "manipulator", "micromanager", "config", "python_devices", "limits_um",
                     "channels", "region_px", "", " ", "é", "a.b", "a\nb", "__class__"]),
    st.text(max_size=8),
)  # fmt: skip


def strange_values(raw: st.SearchStrategy[Raw]) -> st.SearchStrategy[Any]:
    """JSON-like values of every type, the edge ones often, and ``raw`` tokens."""
    scalars = st.one_of(
        st.none(),
        st.booleans(),
        st.sampled_from([0, 1, -1, 2, 3, 2**31 - 1, 2**31, 2**63, -(2**63), 10**20, 10**400]),
        st.integers(),
        st.sampled_from([0.5, -0.0, 1e308, -1e308, 5e-324, math.nan, math.inf, -math.inf]),
        st.floats(),
        st.sampled_from(WORDS),
        st.text(max_size=16),
    )
    containers = st.one_of(
        st.builds(list),
        st.builds(dict),
        st.lists(scalars, max_size=4),
        st.lists(st.lists(scalars, max_size=4), max_size=4),
        st.dictionaries(KEYS, scalars, max_size=3),
    )
    return st.one_of(scalars, scalars, containers, containers, raw)


JSON_VALUES = strange_values(_JSON_RAW)
TOML_VALUES = strange_values(_TOML_RAW)


# --- mutating a parsed document ----------------------------------------------------------------
NodePath = list[Any]  # keys and indices from the root to a node


def _get(tree: Any, path: NodePath) -> Any:
    for key in path:
        tree = tree[key]
    return tree


def _set(tree: Any, path: NodePath, value: Any) -> Any:
    if not path:
        return value
    _get(tree, path[:-1])[path[-1]] = value
    return tree


def _leaves(tree: Any, path: NodePath) -> Iterator[NodePath]:
    if isinstance(tree, dict | list) and tree:
        for key in list(tree) if isinstance(tree, dict) else range(len(tree)):
            yield from _leaves(tree[key], [*path, key])
    else:
        yield path


def _draw_path(draw: st.DrawFn, tree: Any) -> NodePath:
    """A node of the tree: found by walking down from the root (each level is as likely), or
    one of its leaves (each leaf is as likely)."""
    if draw(st.booleans()):
        return draw(st.sampled_from(list(_leaves(tree, []))))
    path: NodePath = []
    node = tree
    while isinstance(node, dict | list) and node and draw(st.integers(0, 4)) > 0:
        key = draw(st.sampled_from(list(node) if isinstance(node, dict) else range(len(node))))
        path.append(key)
        node = node[key]
    return path


# A number written with too many digits: beyond the largest float, beyond int()'s limit.
_TOO_LONG = (lambda v: Raw("9" * 310), lambda v: Raw("9" * 4301))

#: Edits of a value that keep something of it, by its type.
_TWEAKS: dict[type, tuple[Callable[[Any], Any], ...]] = {
    bool: (lambda v: not v, int, lambda v: str(v).lower(), lambda v: [v]),
    int: (lambda v: -v, lambda v: v + 1, lambda v: 0, lambda v: v * 2**64, float, str,
          lambda v: v * 10**300, lambda v: v - 0.5, lambda v: [v, v], *_TOO_LONG),
    float: (lambda v: -v, lambda v: v * 1e300, lambda v: int(v) if math.isfinite(v) else v, str,
            lambda v: v + 0.5, lambda v: 0.0, lambda v: math.nan, lambda v: [v], *_TOO_LONG),
    str: (lambda v: "", lambda v: v * 2, str.upper, lambda v: v + "\x00", lambda v: "\x00" + v,
          lambda v: v[:-1], lambda v: f" {v} ", lambda v: v + "/2", lambda v: "9" + v,
          lambda v: [v], lambda v: v + "\n", lambda v: "\ufeff" + v,
          lambda v: v * 3000 if len(v) < 40 else v),  # long, not huge
    list: (lambda v: v[:-1], lambda v: v + v, lambda v: v[::-1], lambda v: [v], lambda v: v[:1]),
    dict: (lambda v: dict(list(v.items())[1:]), lambda v: dict.fromkeys(v),
           lambda v: dict(reversed(v.items())), lambda v: list(v), lambda v: list(v.values())),
}  # fmt: skip


def _mutate_tree(draw: st.DrawFn, tree: Any, values: st.SearchStrategy[Any]) -> Any:  # the new tree
    """One edit at a node: replace, delete, add a key, copy another node there, wrap, tweak."""
    path = _draw_path(draw, tree)
    node = _get(tree, path)
    ops = ["replace", "delete", "add", "copy", "wrap", "duplicate", "tweak", "tweak"]
    op = draw(st.sampled_from(ops))
    if op == "delete" and path:
        del _get(tree, path[:-1])[path[-1]]
        return tree
    if op == "add" and isinstance(node, dict):
        node[draw(KEYS)] = draw(values)
        return tree
    if op == "duplicate" and isinstance(node, list) and node:
        i = draw(st.integers(0, len(node) - 1))
        node.insert(i, copy.deepcopy(node[i]))
        return tree
    if op == "copy":
        new = copy.deepcopy(_get(tree, _draw_path(draw, tree)))
    elif op == "wrap":
        new = [node] if draw(st.booleans()) else {"value": node}
    elif op == "tweak" and type(node) in _TWEAKS:
        tweak = draw(st.sampled_from(_TWEAKS[type(node)]))
        try:
            new = tweak(copy.deepcopy(node))
        except (OverflowError, ValueError):  # an int too large for a float, say
            new = draw(values)
    else:
        new = draw(values)
    return _set(tree, path, new)


def _mutate_trees(draw: st.DrawFn, tree: Any, values: st.SearchStrategy[Any]) -> Any:
    tree = copy.deepcopy(tree)
    for _ in range(draw(st.integers(0, 3))):
        tree = _mutate_tree(draw, tree, values)
    return tree


# --- writing a document back -------------------------------------------------------------------
def dump_json(value: Any, indent: int | None = None, level: int = 0) -> str:
    """JSON text of ``value``, :class:`Raw` tokens as they are; NaN and infinity as Python
    writes them."""
    if isinstance(value, Raw):
        return value.text
    if isinstance(value, dict):
        items = [f"{json.dumps(k)}: {dump_json(v, indent, level + 1)}" for k, v in value.items()]
        brackets = "{}"
    elif isinstance(value, list):
        items = [dump_json(v, indent, level + 1) for v in value]
        brackets = "[]"
    else:
        return json.dumps(value)
    if not items:
        return brackets
    if indent is None:
        return brackets[0] + ", ".join(items) + brackets[1]
    pad = "\n" + " " * (indent * (level + 1))
    return brackets[0] + pad + ("," + pad).join(items) + "\n" + " " * (indent * level) + brackets[1]


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.fullmatch(key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, Raw):
        return value.text
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value if v is not None) + "]"
    if isinstance(value, dict):
        items = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items() if v is not None]
        return "{ " + ", ".join(items) + " }" if items else "{}"
    return json.dumps(str(value))


def dump_toml(doc: Any) -> str:
    """TOML text of a document (tables inline; TOML has no null, so None drops the key)."""
    if not isinstance(doc, dict):
        doc = {"driver": doc}
    return "".join(f"{_toml_key(k)} = {_toml_value(v)}\n" for k, v in doc.items() if v is not None)


def dump_csv(draw: st.DrawFn, rows: list[list[str]]) -> str:
    """CSV text of the rows: quoted as Python's csv module does, all quoted, or not at all."""
    style = draw(st.sampled_from(["minimal", "all", "none"]))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    if style == "none":
        return "".join(",".join(row) + end for row in rows)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator=end, quoting=csv.QUOTE_MINIMAL)
    if style == "all":
        writer = csv.writer(out, lineterminator=end, quoting=csv.QUOTE_ALL)
    writer.writerows(rows)
    return out.getvalue()


# --- mutating bytes ----------------------------------------------------------------------------
_TOKENS = (b'"', b"{", b"}", b"[", b"]", b",", b":", b"=", b"#", b"'", b'"""', b"\\", b"\\u",
           b"\x00", b"\xff", b"\xc3", b"\xed\xa0\x80", b"\xef\xbb\xbf", b"\r", b"\n", b"\r\n",
           b"\t", b" ", b"-", b".", b"e", b"9" * 20, b"null", b"NaN", b"nan")  # fmt: skip


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def _mutate_bytes_once(draw: st.DrawFn, data: bytes) -> bytes:
    """One byte-level or line-level edit."""
    op = draw(st.sampled_from(["flip", "delete", "insert", "truncate", "duplicate_line",
                               "delete_line", "swap_lines", "bom", "crlf", "cr", "utf16"]))  # fmt: skip
    if op == "bom":
        return b"\xef\xbb\xbf" + data
    if op == "crlf":
        return data.replace(b"\n", b"\r\n")
    if op == "cr":
        return data.replace(b"\n", b"\r")
    if op == "utf16":
        return data.decode("utf-8", "replace").encode(
            draw(st.sampled_from(["utf-16", "utf-16-le"]))
        )
    if op in ("duplicate_line", "delete_line", "swap_lines"):
        lines = _lines(data)
        i = draw(st.integers(0, len(lines) - 1))
        if op == "duplicate_line":
            lines.insert(i, lines[i])
        elif op == "delete_line":
            del lines[i]
        else:
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        return b"\n".join(lines)
    i = draw(st.integers(0, len(data)))
    if op == "truncate":
        return data[:i]
    if op == "delete":
        return data[:i] + data[i + draw(st.integers(1, 16)) :]
    if op == "insert":
        insert = draw(st.one_of(st.sampled_from(_TOKENS), st.binary(min_size=1, max_size=8)))
        return data[:i] + insert + data[i:]
    if i == len(data):
        return data
    return data[:i] + bytes([data[i] ^ draw(st.integers(1, 255))]) + data[i + 1 :]


def _mutate_bytes(draw: st.DrawFn, data: bytes) -> bytes:
    for _ in range(draw(st.integers(0, 3))):
        data = _mutate_bytes_once(draw, data)
    return data


# --- the generators of each kind of file -------------------------------------------------------
@st.composite
def json_files(draw: st.DrawFn, seeds: Sequence[bytes]) -> bytes:
    """A mutated indented JSON file (calibration.json, cameras.json, run.json)."""
    tree = json.loads(draw(st.sampled_from(seeds)))
    tree = _mutate_trees(draw, tree, JSON_VALUES)
    return _mutate_bytes(draw, dump_json(tree, indent=1).encode())


@st.composite
def jsonl_files(draw: st.DrawFn, seed: bytes) -> bytes:
    """A mutated JSON-lines file (journal.jsonl): lines edited as JSON, then as bytes."""
    lines = [json.loads(line) for line in seed.splitlines() if line.strip()]
    lines = _mutate_trees(draw, lines, JSON_VALUES)
    if not isinstance(lines, list):
        lines = [lines]
    text = "\n".join(dump_json(line) for line in lines) + draw(st.sampled_from(["\n", "", "\n\n"]))
    return _mutate_bytes(draw, text.encode())


_CELLS = st.one_of(
    st.sampled_from(["", " ", "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e999", "-1e999",
                     "abc", "ok", "failed", "0", "-1", "1.5", "1_000", "0x10", "\uff11\uff12",
                     "1e-400", "  7  ", '"', '""', 'a"b', "a,b", "a\nb", "\r", "\x00", "None",
                     "True", "\ufeff1", "1,5", "1.0.0", "pose", "dx_um", "+3", "\u0661"]),
    st.text(max_size=10),
    st.integers().map(str),
    st.floats().map(repr),
)  # fmt: skip
_RARE_CELLS = st.one_of(
    _DIGIT_COUNTS.map(lambda n: "9" * n),  # beyond a float, beyond int()'s 4300 digits
    st.integers(100_000, 200_000).map(lambda n: "x" * n),  # beyond csv's field size limit
)
CELLS = st.one_of(*[_CELLS] * 7, _RARE_CELLS)  # a rare cell in about one of eight
COLUMN_NAMES = st.one_of(
    st.sampled_from(["pose", "status", "reason", "dx_um", "dy_um", "dz_um", "x_um", "y_um",
                     "z_um", "sx_um", "temperature_c", "note", "", " dx_um ", "DX_UM", "pose\x00"]),
    st.text(max_size=6),
)  # fmt: skip


def _mutate_table(draw: st.DrawFn, rows: list[list[str]]) -> list[list[str]]:
    """One edit of a CSV table (row 0 is the header)."""
    op = draw(st.sampled_from(["cell", "delete_row", "duplicate_row", "insert_row", "blank_row",
                               "delete_column", "add_column", "drop_cell", "extra_cell",
                               "swap_columns", "rename"]))  # fmt: skip
    r = draw(st.integers(0, max(len(rows) - 1, 0)))
    if not rows:
        return [draw(st.lists(CELLS, max_size=8))]
    row = rows[r]
    width = max(len(row), 1)
    c = draw(st.integers(0, width - 1))
    if op in ("cell", "rename"):
        value = draw(COLUMN_NAMES if op == "rename" or r == 0 else CELLS)
        rows[r] = [*row[:c], value, *row[c + 1 :]]
    elif op == "delete_row":
        del rows[r]
    elif op == "duplicate_row":
        rows.insert(r, list(row))
    elif op == "insert_row":
        rows.insert(r, draw(st.lists(CELLS, max_size=width + 2)))
    elif op == "blank_row":
        rows.insert(r, draw(st.sampled_from([[], [""], [" "], ["", "", ""]])))
    elif op == "delete_column":
        rows = [[*x[:c], *x[c + 1 :]] for x in rows]
    elif op == "add_column":
        name = draw(COLUMN_NAMES)
        cells = draw(st.lists(CELLS, min_size=len(rows) - 1, max_size=len(rows) - 1))
        rows = [[*x[:c], v, *x[c:]] for x, v in zip(rows, [name, *cells], strict=True)]
    elif op == "drop_cell":
        rows[r] = [*row[:c], *row[c + 1 :]]
    elif op == "extra_cell":
        rows[r] = [*row, draw(CELLS)]
    else:
        d = draw(st.integers(0, width - 1))
        for x in rows:
            if c < len(x) and d < len(x):
                x[c], x[d] = x[d], x[c]
    return rows


@st.composite
def csv_files(draw: st.DrawFn, seeds: Sequence[bytes]) -> bytes:
    """A mutated CSV file: cells, rows and columns edited, written back, then bytes edited."""
    text = draw(st.sampled_from(seeds)).decode("utf-8")
    rows = [list(r) for r in csv.reader(io.StringIO(text, newline=""))]
    for _ in range(draw(st.integers(0, 4))):
        rows = _mutate_table(draw, rows)
    return _mutate_bytes(draw, dump_csv(draw, rows).encode("utf-8", "surrogatepass"))


@st.composite
def toml_files(draw: st.DrawFn, seeds: Sequence[bytes]) -> bytes:
    """A mutated rig file: as written (comments and tables) or its settings edited and written
    back inline, then bytes edited."""
    text = draw(st.sampled_from(seeds))
    if draw(st.booleans()):
        tree = _mutate_trees(draw, tomllib.loads(text.decode("utf-8")), TOML_VALUES)
        text = dump_toml(tree).encode("utf-8", "surrogatepass")
    if draw(st.integers(0, 4)) == 0:  # a table nested deep by a dotted name
        table = draw(st.sampled_from(["overrides", "overrides.top", "manipulator", "cameras.top"]))
        name = table + ".a" * draw(_DEPTH)
        text += draw(st.sampled_from([f"\n[{name}]\nb = 1\n", f"\n{name} = 1\n"])).encode()
    return _mutate_bytes(draw, text)


def _cases(
    files: st.SearchStrategy[bytes], options: st.SearchStrategy[dict[str, Any]] | None = None
) -> st.SearchStrategy[FuzzCase]:
    if options is None:
        return files.map(FuzzCase)
    return st.builds(FuzzCase, files, options)


#: The calls the commands reader serves: a --design file, --known-displacements of N views,
#: a run's commands.csv.
JOINT_CSV_OPTIONS = st.one_of(
    st.just({"what": "--design"}),
    st.builds(lambda n: {"what": "--known-displacements", "rows": n}, st.integers(1, 6)),
    st.just({"pose_column": True, "error": FormatError}),
    st.just({"pose_column": False, "min_rows": 2, "error": InputError}),
)


# --- the readers -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Reader:
    """A reader of one kind of user file, and the generator of its inputs."""

    name: str
    file_name: str  # what the input is called in its directory
    read: Callable[[Path, Mapping[str, Any]], object]
    make_inputs: Callable[[SeedFiles], st.SearchStrategy[FuzzCase]]

    @functools.cached_property
    def inputs(self) -> st.SearchStrategy[FuzzCase]:
        """The generator (the valid files it starts from are built on first use)."""
        return st.deferred(lambda: self.make_inputs(seed_files()))


def _read_journal(path: Path, options: Mapping[str, Any]) -> object:
    return RunDirectory(path.parent).journal()


def _read_manifest(path: Path, options: Mapping[str, Any]) -> object:
    return RunDirectory(path.parent).manifest


def _read_commands(path: Path, options: Mapping[str, Any]) -> object:
    return RunDirectory(path.parent).commands()


_READERS = (
    Reader("journal", "journal.jsonl", _read_journal, lambda s: _cases(jsonl_files(s.journal))),
    Reader("measurements", "measurements.csv", lambda p, o: read_measurements(p),
           lambda s: _cases(csv_files([s.measurements]))),
    Reader("calibration", "calibration.json", lambda p, o: load_calibration(p),
           lambda s: _cases(json_files([s.calibration]))),
    Reader("cameras", "cameras.json", lambda p, o: load_cameras(p),
           lambda s: _cases(json_files([s.cameras, s.calibration]))),
    Reader("rig", "rig.toml", lambda p, o: load_rig(str(p)), lambda s: _cases(toml_files(s.rigs))),
    Reader("joint_csv", "design.csv", lambda p, o: read_joint_csv(p, **o),
           lambda s: _cases(csv_files([s.commands, s.design]), JOINT_CSV_OPTIONS)),
    Reader("commands", "commands.csv", _read_commands,
           lambda s: _cases(csv_files([s.commands, s.design]))),
    Reader("manifest", "run.json", _read_manifest, lambda s: _cases(json_files([s.manifest]))),
)  # fmt: skip
#: Every fuzzed reader by name.
READERS: dict[str, Reader] = {r.name: r for r in _READERS}


# --- running one input -------------------------------------------------------------------------
class HangError(BaseException):
    """A reader ran longer than :data:`HANG_SECONDS` (a BaseException, so that no
    ``except Exception`` in a reader swallows it when it is raised into the reader)."""


def call_with_time_limit(call: Callable[[], object], seconds: float) -> None:
    """Run ``call()`` in a thread of its own; raise what it raised, or HangError after
    ``seconds``.

    A thread of its own starts every call at the same stack depth, and it runs under
    Python's default recursion limit (as under the ``microcal`` command, not the limit
    Hypothesis raises while it runs a test), so a RecursionError is raised at the same line
    each time an input is replayed. A call still running at the limit has HangError raised
    into it (which stops Python code, not a loop inside C code; such a thread is left behind
    as a daemon).
    """
    raised: list[BaseException] = []

    def target() -> None:
        try:
            call()
        except BaseException as exc:  # handed to the caller's thread
            raised.append(exc)

    thread = threading.Thread(target=target, name="fuzzed reader", daemon=True)
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(READER_RECURSION_LIMIT)
    try:
        thread.start()
        thread.join(seconds)
    finally:
        sys.setrecursionlimit(limit)
    if thread.is_alive():
        ident = ctypes.c_ulong(thread.ident or 0)
        ctypes.pythonapi.PyThreadState_SetAsyncExc(ident, ctypes.py_object(HangError))
        thread.join(1.0)
        raise HangError(f"no answer within {seconds} s")
    if raised:
        raise raised[0]


@dataclass(frozen=True)
class Outcome:
    """What a reader did with one input."""

    kind: str  # "returned", "refused" (MicrocalError), "other" (another exception) or "hang"
    seconds: float
    error: BaseException | None = None


def write_case(directory: Path, reader: Reader, case: FuzzCase) -> Path:
    """Write the input where the reader looks for it; its path."""
    path = directory / reader.file_name
    path.write_bytes(case.data)
    return path


def run_case(reader: Reader, case: FuzzCase, directory: Path) -> Outcome:
    """Write ``case`` into ``directory`` and read it, classifying what happened."""
    path = write_case(directory, reader, case)
    start = time.perf_counter()
    try:
        call_with_time_limit(lambda: reader.read(path, case.options), HANG_SECONDS)
    except HangError as exc:
        return Outcome("hang", time.perf_counter() - start, exc)
    except MicrocalError as exc:
        kind = "refused"
        error: BaseException | None = exc
    except Exception as exc:
        return Outcome("other", time.perf_counter() - start, exc)
    else:
        kind, error = "returned", None
    seconds = time.perf_counter() - start
    return Outcome("hang" if seconds > HANG_SECONDS else kind, seconds, error)


# --- the tests ---------------------------------------------------------------------------------
FUZZ = settings(
    max_examples=EXAMPLES,
    derandomize=True,
    database=None,
    deadline=None,
    print_blob=False,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


@pytest.fixture(scope="session")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory per test run; each reader writes its inputs into a folder of its own."""
    return tmp_path_factory.mktemp("fuzz")


def check_reader(name: str, case: FuzzCase, fuzz_dir: Path) -> None:
    """The reader returns or raises MicrocalError within HANG_SECONDS.

    Any other exception propagates with its traceback (Hypothesis tells distinct bugs apart by
    where they are raised); a hang is an AssertionError.
    """
    reader = READERS[name]
    directory = fuzz_dir / name
    directory.mkdir(exist_ok=True)
    path = write_case(directory, reader, case)
    start = time.perf_counter()
    try:
        call_with_time_limit(lambda: reader.read(path, case.options), HANG_SECONDS)
    except MicrocalError:
        pass  # the documented refusal of a bad file
    except HangError:
        raise AssertionError(f"{name}: no answer within {HANG_SECONDS} s") from None
    elapsed = time.perf_counter() - start
    assert elapsed < HANG_SECONDS, f"{name}: took {elapsed:.1f} s"


@settings(FUZZ, max_examples=300)  # its inputs are quick to read: a few more of them
@given(case=READERS["journal"].inputs)
def test_journal_reader_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``RunDirectory.journal()`` on an edited journal.jsonl (lines changed as JSON and as bytes,
    duplicated, dropped, cut) returns the lines or raises MicrocalError, in bounded time."""
    check_reader("journal", case, fuzz_dir)


@FUZZ
@given(case=READERS["measurements"].inputs)
def test_measurements_reader_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``read_measurements`` on an edited measurements.csv (cells turned into text, empty,
    ``nan``, ``inf``, huge numbers; columns and rows added, dropped, duplicated) returns or
    raises MicrocalError, in bounded time."""
    check_reader("measurements", case, fuzz_dir)


@FUZZ
@given(case=READERS["calibration"].inputs)
def test_calibration_loader_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``load_calibration`` on an edited calibration.json (values of other types, keys deleted
    or added, NaN, huge numbers, deep nesting, bytes changed) returns or raises MicrocalError,
    in bounded time."""
    check_reader("calibration", case, fuzz_dir)


@FUZZ
@given(case=READERS["cameras"].inputs)
def test_cameras_loader_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``load_cameras`` on an edited cameras.json or calibration.json (camera matrices of the
    wrong shape or type, unknown models, keys deleted, bytes changed) returns or raises
    MicrocalError, in bounded time."""
    check_reader("cameras", case, fuzz_dir)


@FUZZ
@given(case=READERS["rig"].inputs)
def test_rig_loader_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``load_rig`` on an edited rig file (the example rigs with settings of other types,
    unknown or missing tables, TOML dates, deep nesting, bytes changed, not UTF-8) returns or
    raises MicrocalError, in bounded time."""
    check_reader("rig", case, fuzz_dir)


@FUZZ
@given(case=READERS["joint_csv"].inputs)
def test_joint_csv_reader_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``read_joint_csv``, called as ``--design``, ``--known-displacements`` and a run's
    commands are, on edited command tables returns or raises MicrocalError (the caller's
    class), in bounded time."""
    check_reader("joint_csv", case, fuzz_dir)


@FUZZ
@given(case=READERS["commands"].inputs)
def test_run_commands_raise_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``RunDirectory.commands()`` on an edited commands.csv (poses repeated, zero, negative or
    not whole; cells not finite; columns missing) returns or raises MicrocalError, in bounded
    time."""
    check_reader("commands", case, fuzz_dir)


@FUZZ
@given(case=READERS["manifest"].inputs)
def test_run_manifest_raises_only_microcal_errors(case: FuzzCase, fuzz_dir: Path) -> None:
    """``RunDirectory.manifest`` on an edited run.json (values of other types, keys deleted or
    added, another format version, bytes changed) returns or raises MicrocalError, in bounded
    time."""
    check_reader("manifest", case, fuzz_dir)


def test_every_reader_is_fuzzed_and_its_seed_files_are_valid(fuzz_dir: Path) -> None:
    """The valid files the generators start from are read without error by their readers, so a
    refusal of a mutated file is about the mutation."""
    seeds = seed_files()
    valid = {"journal": seeds.journal, "measurements": seeds.measurements,
             "calibration": seeds.calibration, "cameras": seeds.cameras, "rig": seeds.rigs[0],
             "joint_csv": seeds.design, "commands": seeds.commands, "manifest": seeds.manifest}  # fmt: skip
    assert set(valid) == set(READERS)
    for name, data in valid.items():
        directory = fuzz_dir / f"valid-{name}"
        directory.mkdir(exist_ok=True)
        outcome = run_case(READERS[name], FuzzCase(data), directory)
        assert outcome.kind == "returned", (name, outcome.error)
    for rig in seeds.rigs:
        outcome = run_case(READERS["rig"], FuzzCase(rig), fuzz_dir / "valid-rig")
        assert outcome.kind == "returned", outcome.error
