"""A simulated rig of the thesis's cameras whose manipulator carries a needle instead of
the board (for tests of the commands with a tool's tip)."""

from __future__ import annotations

from pathlib import Path

#: the tool: a needle of 20 degrees' taper and a 5 µm end
NEEDLE = "tip:needle:20:5"


def write_needle_rig(directory: Path) -> Path:
    """``directory``/needle.toml: the thesis-tip preset, seed 0, carrying :data:`NEEDLE`."""
    path = directory / "needle.toml"
    path.write_text(f'driver = "sim"\npreset = "thesis-tip"\nseed = 0\n'
                    f'[overrides]\nboard = "{NEEDLE}"\n')  # fmt: skip
    return path
