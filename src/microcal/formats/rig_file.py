"""Rig files (TOML): which devices a run uses. ``sim`` alone is the simulated thesis platform.

```toml
driver = "sim"        # the simulated platform
preset = "thesis"
seed = 0
[overrides.top.faults]   # any setting of microcal.sim.PlatformConfig
drop_rate = 0.1
```

Hardware rigs have ``driver = "hardware"``, a ``[manipulator]`` table and one
``[cameras.NAME]`` table per camera (``docs/hardware.md``, ``examples/rigs/``):

```toml
driver = "hardware"
board = "chessboard:4x3:400"           # the end-effector's board
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

import tomllib
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import FormatError
from .json_file import validation_message

__all__ = ["load_rig"]


def _flatten(prefix: str, node: dict[str, Any], out: dict[str, Any]) -> None:
    for key, value in node.items():
        name = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            _flatten(name, value, out)
        else:
            out[name] = value


def load_rig(spec: str) -> dict[str, Any]:
    """``{"driver": "sim", "preset": ..., "seed": ..., "overrides": {dotted: value}}``."""
    if spec == "sim":
        return {"driver": "sim", "preset": "thesis", "seed": 0, "overrides": {}}
    path = Path(spec)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FormatError(
            f"--rig {spec}: no such file (or use 'sim' for the simulated platform)"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise FormatError(f"{path}: not valid TOML ({exc})") from None
    driver = data.get("driver")
    if driver == "hardware":
        return _hardware(path, data)
    if driver != "sim":
        raise FormatError(f'{path}: driver {driver!r} is unknown; use driver = "sim" or "hardware"')
    overrides: dict[str, Any] = {}
    _flatten("", data.get("overrides", {}), overrides)
    preset = str(data.get("preset", "thesis"))
    return {
        "driver": "sim",
        "preset": preset,
        "seed": int(data.get("seed", 0)),
        "overrides": overrides,
    }


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class _Manipulator(_Strict):
    kind: str
    limits_um: dict[str, tuple[float, float]]
    # smaract-mcs2
    address: str | None = None
    port: int = 55551
    channels: dict[str, int] | None = None
    timeout_s: float = Field(default=2.0, gt=0)
    reconnects: int = Field(default=2, ge=0)
    speed_um_s: float | None = Field(default=None, gt=0)
    # micromanager
    xy_stage: str | None = None
    focus: str | None = None

    @field_validator("kind")
    @classmethod
    def _kind(cls, value: str) -> str:
        if value not in ("smaract-mcs2", "micromanager"):
            raise ValueError(f"expected 'smaract-mcs2' or 'micromanager', got {value!r}")
        return value


class _Camera(_Strict):
    kind: str
    address: str | None = None  # aravis
    device: str | None = None  # micromanager
    exposure_ms: float | None = Field(default=None, gt=0)
    pixel_format: str = "Mono8"
    region_px: tuple[int, int, int, int] | None = None
    timeout_s: float = Field(default=2.0, gt=0)
    pixel_size_um: float = Field(default=3.45, gt=0)

    @field_validator("kind")
    @classmethod
    def _kind(cls, value: str) -> str:
        if value not in ("aravis", "micromanager"):
            raise ValueError(f"expected 'aravis' or 'micromanager', got {value!r}")
        return value


class _MicroManager(_Strict):
    config: str | None = None
    python_devices: str | None = None


class _Hardware(_Strict):
    driver: str
    board: str = "chessboard:4x3:400"
    manipulator: _Manipulator
    cameras: dict[str, _Camera]
    micromanager: _MicroManager | None = None


def _hardware(path: Path, data: dict[str, Any]) -> dict[str, Any]:
    try:
        rig = _Hardware.model_validate(data)
    except ValidationError as exc:
        raise FormatError(f"{path}: {validation_message(exc)}") from None
    m = rig.manipulator
    if m.kind == "smaract-mcs2" and (m.address is None or m.channels is None):
        raise FormatError(f"{path}: manipulator: smaract-mcs2 needs 'address' and 'channels'")
    if m.kind == "micromanager" and (m.xy_stage is None or m.focus is None):
        raise FormatError(f"{path}: manipulator: micromanager needs 'xy_stage' and 'focus'")
    axes = list(m.channels) if m.channels is not None else ["x", "y", "z"]
    if sorted(m.limits_um) != sorted(axes):
        raise FormatError(
            f"{path}: manipulator.limits_um: expected a [low, high] for each of {axes}, "
            f"got {sorted(m.limits_um)}"
        )
    for name, cam in rig.cameras.items():
        if cam.kind == "aravis" and cam.address is None:
            raise FormatError(f"{path}: cameras.{name}: aravis needs 'address'")
        if cam.kind == "micromanager" and cam.device is None:
            raise FormatError(f"{path}: cameras.{name}: micromanager needs 'device'")
    if len(rig.cameras) != 2:
        raise FormatError(
            f"{path}: cameras: expected two cameras (e.g. [cameras.top], [cameras.side]), "
            f"got {len(rig.cameras)}"
        )
    uses_mm = m.kind == "micromanager" or any(
        c.kind == "micromanager" for c in rig.cameras.values()
    )
    if uses_mm:
        mm = rig.micromanager
        if mm is None or (mm.config is None) == (mm.python_devices is None):
            raise FormatError(
                f"{path}: micromanager: give exactly one of 'config' (a .cfg file) or "
                f"'python_devices' (module:function)"
            )
        if mm.config is not None and not Path(mm.config).is_absolute():
            mm.config = str((path.parent / mm.config).resolve())
    out = rig.model_dump(exclude_none=True)
    out["manipulator"]["limits_um"] = {k: list(v) for k, v in m.limits_um.items()}
    return out
