"""Rig files (TOML): which devices a run uses. ``sim`` alone is the simulated thesis platform.

:func:`load_rig` gives a typed spec (``microcal.devices.rig_spec``: :class:`SimRigSpec` or
:class:`HardwareRigSpec`, with every default filled in) that ``workflows.rigs.open_rig`` opens
and whose ``to_dict()`` is the rig's record in ``run.json``.

```toml
driver = "sim"        # the simulated platform
preset = "thesis"
seed = 0
[overrides.top.faults]   # any setting of microcal.sim.PlatformConfig
drop_rate = 0.1
```

Hardware rigs have ``driver = "hardware"``, a ``[manipulator]`` table (the device named
``m1``), one ``[manipulators.NAME]`` table per further device the cameras see (a second
manipulator ``m2``, the sample's positioner ``p1``) and one ``[cameras.NAME]`` table per
camera (``docs/hardware.md``, ``examples/rigs/``):

```toml
driver = "hardware"
board = "chessboard:4x3:400"           # the end-effector's board (or a tool's tip: "tip:needle")
[manipulator]
kind = "smaract-mcs2"                  # or "micromanager"
address = "192.168.1.200"
channels = { x = 0, y = 1, z = 2 }
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }
[cameras.top]
kind = "aravis"                        # or "micromanager"
address = "192.168.1.11"
exposure_ms = 10
```
"""

from __future__ import annotations

import copy
import dataclasses
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from .._validation import did_you_mean, excerpt, name_problem
from ..devices.rig_spec import (
    LEGACY_MM_CAMERA_RECORD,
    LEGACY_MM_STAGE_RECORD,
    AravisCameraSpec,
    CameraSpec,
    HardwareRigSpec,
    ManipulatorSpec,
    MCS2Spec,
    MicroManagerSpec,
    MMCameraSpec,
    MMStageSpec,
    RigSpec,
    SimRigSpec,
)
from ..errors import FormatError, InputError
from .json_file import validation_message
from .safe_open import read_regular_text

__all__ = ["load_rig", "rig_from_record"]


T = TypeVar("T")


def _flatten(prefix: str, node: Mapping[str, object], out: dict[str, object]) -> None:
    for key, value in node.items():
        name = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            _flatten(name, value, out)
        else:
            out[name] = value


def load_rig(spec: str) -> RigSpec:
    """The rig a ``--rig`` option names: ``"sim"`` (the simulated thesis platform) or a file.

    Parameters
    ----------
    spec : str
        ``"sim"``, or the path of a rig TOML file.

    Returns
    -------
    SimRigSpec or HardwareRigSpec
        Every setting filled in (the defaults are the specs').

    Raises
    ------
    FormatError
        No such file, not TOML, or a setting missing, unknown or out of range (one line
        naming the key).
    """
    if spec == "sim":
        return SimRigSpec()
    path = Path(spec)
    try:
        data = tomllib.loads(read_regular_text(path, link_ok=True))
    except FormatError:
        raise  # a link, a FIFO, a device: safe_open's own line
    except FileNotFoundError:
        raise FormatError(
            f"--rig {spec}: no such file (or use 'sim' for the simulated platform)"
        ) from None
    except IsADirectoryError:
        raise FormatError(f"--rig {spec}: is a directory; give a rig TOML file") from None
    except UnicodeDecodeError:
        raise FormatError(f"{path}: not a text file (expected a rig TOML file)") from None
    except tomllib.TOMLDecodeError as exc:
        raise FormatError(f"{path}: not valid TOML ({exc})") from None
    except (RecursionError, ValueError) as exc:  # nested too deep, an integer of 4300 digits
        raise FormatError(f"{path}: not a rig file microcal reads ({type(exc).__name__})") from None
    try:
        return _from_data(path, data, from_file=True)
    except RecursionError:
        raise FormatError(f"{path}: settings nested too deep for a rig file") from None


def rig_from_record(record: object, where: str) -> RigSpec:
    """The rig a run recorded (``run.json``'s ``rig``: a spec's ``to_dict()``), for a resume.

    Raises
    ------
    FormatError
        Not a rig's record (the message names ``where``).
    """
    if not isinstance(record, dict):
        raise FormatError(f"{where}: records no rig; give --rig")
    return _from_data(Path(where), _unflatten(record))


def _unflatten(record: Mapping[str, object]) -> dict[str, object]:
    """A recorded rig's ``overrides`` are dotted names; the file's are tables."""
    out = dict(copy.deepcopy(record))
    further = out.get("manipulators")
    stages = [out.get("manipulator"), out.get("target_stage")]
    stages += list(further.values()) if isinstance(further, dict) else []
    for stage in stages:
        _drop_legacy(stage, LEGACY_MM_STAGE_RECORD)
    scope = out.get("microscope")
    if isinstance(scope, dict):  # recorded as a Micro-Manager stage; the file's table has no kind
        _drop_legacy(scope, LEGACY_MM_STAGE_RECORD)
        scope.pop("kind", None)
    cameras = out.get("cameras")
    for camera in cameras.values() if isinstance(cameras, dict) else ():
        _drop_legacy(camera, LEGACY_MM_CAMERA_RECORD)
    flat = out.get("overrides")
    if isinstance(flat, dict):
        nested: dict[str, object] = {}
        for key, value in flat.items():
            node = nested
            *parents, leaf = str(key).split(".")
            for part in parents:
                child = node.setdefault(part, {})
                if not isinstance(child, dict):
                    raise FormatError(f"overrides: {key} is both a value and a table")
                node = child
            node[leaf] = value
        out["overrides"] = nested
    return out


def _drop_legacy(device: object, legacy: Mapping[str, object]) -> None:
    """A Micro-Manager device's record repeats settings it has not (see ``rig_spec``)."""
    if isinstance(device, dict) and device.get("kind") == "micromanager":
        for key, value in legacy.items():
            if device.get(key) == value:
                del device[key]


def _from_data(path: Path, data: Mapping[str, object], from_file: bool = False) -> RigSpec:
    """The spec of a rig's settings: a rig file's tables as parsed (``from_file``), or a
    recorded rig."""
    driver = data.get("driver")
    if driver == "hardware":
        return _hardware(path, data, from_file)
    if driver != "sim":
        raise FormatError(
            f'{path}: driver {excerpt(driver)} is unknown; use driver = "sim" or "hardware"'
        )
    return _sim(path, data)


# The file's syntax: types and known keys. No defaults here: a key the file leaves out is
# left out of the spec's arguments, and the spec supplies its default.
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class _Sim(_Strict):
    driver: str
    preset: str | None = None
    seed: int | None = None
    overrides: dict[str, object] | None = None


class _Manipulator(_Strict):
    kind: str
    limits_um: dict[str, tuple[float, float]]
    # smaract-mcs2
    address: str | None = None
    port: int | None = None
    channels: dict[str, int] | None = None
    timeout_s: float | None = None
    reconnects: int | None = None
    speed_um_s: float | None = None
    # micromanager
    xy_stage: str | None = None
    focus: str | None = None
    # a further device's own target ([manipulators.NAME] only)
    board: str | None = None

    @field_validator("kind")
    @classmethod
    def _kind(cls, value: str) -> str:
        if value not in _MANIPULATORS:
            raise ValueError(f"expected 'smaract-mcs2' or 'micromanager', got {value!r}")
        return value


class _Camera(_Strict):
    kind: str
    address: str | None = None  # aravis
    device: str | None = None  # micromanager
    exposure_ms: float | None = None
    pixel_format: str | None = None
    region_px: tuple[int, int, int, int] | None = None
    timeout_s: float | None = None
    pixel_size_um: float | None = None

    @field_validator("kind")
    @classmethod
    def _kind(cls, value: str) -> str:
        if value not in _CAMERAS:
            raise ValueError(f"expected 'aravis' or 'micromanager', got {value!r}")
        return value


class _MicroManager(_Strict):
    config: str | None = None
    python_devices: str | None = None
    options: dict[str, str | int | float] | None = None


class _Microscope(_Strict):
    """A one-camera microscope's X-Y stage and focus drive (Micro-Manager devices)."""

    xy_stage: str
    focus: str | None = None
    limits_um: dict[str, tuple[float, float]]


class _Hardware(_Strict):
    driver: str
    board: str | None = None
    manipulator: _Manipulator
    cameras: dict[str, _Camera]
    micromanager: _MicroManager | None = None
    target_stage: _Manipulator | None = None
    calibration_target: str | None = None
    manipulators: dict[str, _Manipulator] | None = None
    microscope: _Microscope | None = None


_MANIPULATORS: dict[str, type[ManipulatorSpec]] = {
    "smaract-mcs2": MCS2Spec,
    "micromanager": MMStageSpec,
}
_CAMERAS: dict[str, type[CameraSpec]] = {"aravis": AravisCameraSpec, "micromanager": MMCameraSpec}


def _given(model: BaseModel) -> dict[str, object]:
    """The keys the file sets (TOML has no null: unset and absent are the same), of the
    types the file's schema checked."""
    given: dict[str, object] = model.model_dump(exclude_unset=True)
    return given


def _spec(cls: Callable[..., T], given: Mapping[str, object]) -> T:
    """A spec from the settings a file gives (their types checked by the file's schema, their
    values by the spec itself); a setting it leaves out takes the spec's default."""
    return cls(**given)


def _build(path: Path, where: str, cls: type[Any], given: dict[str, object]) -> Any:
    """``cls(**given)`` for the table ``where`` (a kind's spec class and the keys the file
    sets), with one-line errors naming the table and the key."""
    kind = given.pop("kind", None)
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    unknown = [k for k in given if k not in names]
    if unknown:
        raise FormatError(
            f"{path}: {where}.{unknown[0]}: not a setting of kind {kind!r} "
            f"(its settings: {', '.join(names)})"
        )
    required = [
        f.name
        for f in fields
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [name for name in required if name not in given]
    if missing:
        needs = " and ".join(repr(name) for name in missing)
        raise FormatError(f"{path}: {where}: {kind} needs {needs}")
    try:
        return _spec(cls, given)
    except InputError as exc:
        raise FormatError(f"{path}: {where}.{exc}") from None


def _check_keys(path: Path, where: str, table: object, model: type[BaseModel]) -> None:
    """An unknown key is an error naming the nearest valid one (before the types' checks)."""
    if not isinstance(table, dict):
        return
    names = list(model.model_fields)
    for key in table:
        if key not in names:
            hint = did_you_mean(key, names)
            raise FormatError(
                f"{path}: {where}{key}: not a setting ({hint}settings: {', '.join(names)})"
            )


def _sim(path: Path, data: Mapping[str, object]) -> SimRigSpec:
    from ..sim.patch_devices import patch_config
    from ..sim.platforms import ONE_CAMERA_PRESET, PRESETS, check_overrides

    _check_keys(path, "", data, _Sim)
    try:
        rig = _Sim.model_validate(data)
    except ValidationError as exc:
        raise FormatError(f"{path}: {validation_message(exc)}") from None
    given = _given(rig)
    given.pop("driver")
    given.pop("overrides", None)
    overrides: dict[str, object] = {}
    _flatten("", rig.overrides or {}, overrides)
    preset = "thesis" if rig.preset is None else rig.preset
    presets = (*PRESETS, ONE_CAMERA_PRESET)
    if preset not in presets:
        near = did_you_mean(preset, presets).strip()
        hint = f" ({near})" if near else ""
        raise FormatError(
            f"{path}: preset: expected one of {list(presets)}, got {excerpt(preset)}{hint}"
        )
    if preset == ONE_CAMERA_PRESET:  # the one-camera microscope: its own settings
        try:
            patch_config(overrides)
            return _spec(SimRigSpec, {**given, "overrides": overrides})
        except InputError as exc:
            raise FormatError(f"{path}: {exc}") from None
    board = overrides.get("board")
    if isinstance(board, str):  # a board or a tool's tip, refused with the fix of a near miss
        _check_target(path, "overrides.board", board)
    try:
        check_overrides(overrides, preset)
        return _spec(SimRigSpec, {**given, "overrides": overrides})
    except InputError as exc:
        raise FormatError(f"{path}: {exc}") from None


def _check_target(path: Path, key: str, spec: str) -> None:
    """A board key takes a board or a tool's tip (``tip:needle:20:5``); the calibration
    target is a board."""
    from ..vision.effector_target import parse_effector_target
    from ..vision.targets import parse_target

    try:
        parse_target(spec) if key == "calibration_target" else parse_effector_target(spec)
    except InputError as exc:
        raise FormatError(f"{path}: {key}: {exc}") from None


def _check_names(path: Path, data: Mapping[str, object]) -> None:
    """The cameras' and the further devices' names become file names: plain words only."""
    for table in ("cameras", "manipulators"):
        named = data.get(table)
        for name in named if isinstance(named, dict) else ():
            problem = name_problem(name)
            if problem is not None:
                raise FormatError(f"{path}: {table}: {problem}")


def _config_beside(path: Path, config: str) -> str:
    """A rig file's Micro-Manager configuration: a file in the rig file's folder or below it
    (relative to the rig file, no ``..``, not absolute), as an absolute path."""
    relative = Path(config)
    folder = path.parent.resolve()
    resolved = (folder / relative).resolve()
    if (
        "\0" in config
        or relative.is_absolute()
        or ".." in relative.parts
        or (not resolved.is_relative_to(folder))
    ):
        raise FormatError(
            f"{path}: micromanager.config: {excerpt(config)} is not a file beside the rig "
            "file; give its path relative to the rig file, inside its folder (copy the "
            "configuration there)"
        )
    return str(resolved)


def _hardware(path: Path, data: Mapping[str, object], from_file: bool = False) -> HardwareRigSpec:
    _check_names(path, data)
    _check_keys(path, "", data, _Hardware)
    _check_keys(path, "manipulator.", data.get("manipulator"), _Manipulator)
    _check_keys(path, "micromanager.", data.get("micromanager"), _MicroManager)
    _check_keys(path, "target_stage.", data.get("target_stage"), _Manipulator)
    cameras = data.get("cameras")
    for name, camera in cameras.items() if isinstance(cameras, dict) else ():
        _check_keys(path, f"cameras.{name}.", camera, _Camera)
    _check_keys(path, "microscope.", data.get("microscope"), _Microscope)
    further = data.get("manipulators")
    for name, table in further.items() if isinstance(further, dict) else ():
        _check_keys(path, f"manipulators.{name}.", table, _Manipulator)
    try:
        rig = _Hardware.model_validate(data)
    except ValidationError as exc:
        raise FormatError(f"{path}: {validation_message(exc)}") from None
    own = (("manipulator", rig.manipulator, "board"),
           ("target_stage", rig.target_stage, "calibration_target"))  # fmt: skip
    for where, table, key in own:
        if table is not None and table.board is not None:
            raise FormatError(f"{path}: {where}.board: its target is the top-level {key!r}")
    m = rig.manipulator
    manipulator = _build(path, "manipulator", _MANIPULATORS[m.kind], _given(m))
    cameras = {
        name: _build(path, f"cameras.{name}", _CAMERAS[cam.kind], _given(cam))
        for name, cam in rig.cameras.items()
    }
    micromanager = None
    if rig.micromanager is not None:
        mm = _given(rig.micromanager)
        config = rig.micromanager.config
        if "\0" in (config or ""):
            raise FormatError(f"{path}: micromanager.config: a file name cannot hold a NUL")
        if config is not None and from_file:
            mm["config"] = _config_beside(path, config)
        elif config is not None and not Path(config).is_absolute():
            mm["config"] = str((path.parent / config).resolve())
        try:
            micromanager = _spec(MicroManagerSpec, mm)
        except InputError as exc:
            raise FormatError(f"{path}: {exc}") from None
    given: dict[str, object] = {}
    for key, target in (("board", rig.board), ("calibration_target", rig.calibration_target)):
        if target is not None:
            given[key] = target
            _check_target(path, key, target)
    if rig.target_stage is not None:
        stage = rig.target_stage
        given["target_stage"] = _build(
            path, "target_stage", _MANIPULATORS[stage.kind], _given(stage)
        )
    if rig.manipulators:
        others: dict[str, ManipulatorSpec] = {}
        boards: dict[str, str] = {}
        for name, m in rig.manipulators.items():
            keys = _given(m)
            if m.board is not None:
                keys.pop("board")
                boards[name] = m.board
                _check_target(path, f"manipulators.{name}.board", m.board)
            where = f"manipulators.{name}"
            others[name] = _build(path, where, _MANIPULATORS[m.kind], keys)
        given |= {"manipulators": others, "boards": boards}
    if rig.microscope is not None:
        scope = {"kind": "micromanager", **_given(rig.microscope)}
        given["microscope"] = _build(path, "microscope", MMStageSpec, scope)
    try:
        return _spec(HardwareRigSpec, {"manipulator": manipulator, "cameras": cameras,
                                       "micromanager": micromanager, **given})  # fmt: skip
    except InputError as exc:
        raise FormatError(f"{path}: {exc}") from None
