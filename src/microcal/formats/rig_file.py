"""Rig files (TOML): which devices a run uses. ``sim`` alone is the simulated thesis platform.

```toml
driver = "sim"        # the simulated platform
preset = "thesis"
seed = 0
[overrides.top.faults]   # any setting of microcal.sim.PlatformConfig
drop_rate = 0.1
```
Hardware drivers (SmarAct, GigE Vision, Micro-Manager) add their own tables later.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from ..errors import FormatError

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
    if driver != "sim":
        raise FormatError(
            f'{path}: driver {driver!r} is not available in this version; use driver = "sim"'
        )
    overrides: dict[str, Any] = {}
    _flatten("", data.get("overrides", {}), overrides)
    preset = str(data.get("preset", "thesis"))
    return {
        "driver": "sim",
        "preset": preset,
        "seed": int(data.get("seed", 0)),
        "overrides": overrides,
    }
