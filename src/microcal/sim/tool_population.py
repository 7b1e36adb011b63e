"""A population of rendered tool images with known tips, for the tip detection's figures.

Each image is drawn from one seed: a tool of one kind (pipette, needle, jaw) with its taper
(5-15 degrees) and tip (a pipette's opening 0.5-2 µm, a needle's or jaw's rounded end 1-3 µm),
held 0-25 degrees off the image plane in any direction, its tip anywhere in the middle of the
field, focused ``focus_dof`` depths of field off (either side), against a plain, tissue or
debris background under uneven light, through a 10x objective (NA 0.3, 0.65 µm pixels, a
256 x 256 region) with shot and read noise on 8 bits. Images without a tool, with two tools
or with the tip outside the field are drawn alike, for the detector's refusals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ..geometry.affine_camera import AffineCamera
from .tools import (
    TOOL_KINDS,
    Background,
    Optics,
    Tool,
    ToolPlacement,
    ToolScene,
    ToolTruth,
    microscope_camera,
    tool_axis,
    tool_image,
)

__all__ = ["Case", "PopulationImage", "draw_tool_image", "population_camera"]

Case = Literal["tool", "none", "two", "outside"]
#: The population's objective: numerical aperture and pixel in the object.
NUMERICAL_APERTURE = 0.3
UM_PER_PX = 0.65


@dataclass
class PopulationImage:
    """One image of the population and what it shows."""

    image: NDArray[np.unsignedinteger]
    truths: list[ToolTruth]
    kind: str
    case: Case
    focus_dof: float
    spec: str  # the tip spec a user would give for this tool
    background: str
    scene: ToolScene  # what was rendered, to render it again (moved, refocused)


def population_camera() -> AffineCamera:
    """The population's camera: 0.65 µm pixels, 256 x 256, looking down."""
    return microscope_camera(UM_PER_PX, (256, 256))


def _tool(rng: np.random.Generator, kind: str) -> Tool:
    taper = float(rng.uniform(5.0, 15.0))
    tip = float(rng.uniform(0.5, 2.0) if kind == "pipette" else rng.uniform(1.0, 3.0))
    return Tool(kind, taper_deg=taper, tip_um=tip)  # type: ignore[arg-type]


def _background(rng: np.random.Generator) -> Background:
    texture = ("plain", "tissue", "debris")[int(rng.integers(3))]
    contrast = float(rng.uniform(0.03, 0.08)) if texture == "tissue" else 0.1
    gradient = (float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.3, 0.3)))
    return Background(texture, contrast, gradient, float(rng.uniform(0.5, 0.8)),  # type: ignore[arg-type]
                      int(rng.integers(2**31)))  # fmt: skip


def draw_tool_image(
    seed: int, kind: str = "needle", focus_dof: float = 0.0, case: Case = "tool"
) -> PopulationImage:
    """One image of the population (see the module docstring), from ``seed``."""
    rng = np.random.default_rng(seed)
    camera = population_camera()
    optics0 = Optics(NUMERICAL_APERTURE)
    dof = optics0.depth_of_field_um(UM_PER_PX)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    focus = 1000.0 + sign * focus_dof * dof  # the tips are at 1 mm depth
    optics = Optics(NUMERICAL_APERTURE, focus_depth_um=focus)
    background = _background(rng)
    placements: list[ToolPlacement] = []
    kinds = [kind] if case in ("tool", "outside") else []
    if case == "two":
        kinds = [kind, TOOL_KINDS[int(rng.integers(3))]]
    for i, k in enumerate(kinds):
        azimuth = float(rng.uniform(0.0, 360.0)) if i == 0 else 0.0
        if i == 1:  # the second tool comes from the other side
            azimuth = float(np.degrees(np.arctan2(placements[0].axis[1], placements[0].axis[0])))
            azimuth += 180.0 + float(rng.uniform(-40.0, 40.0))
        axis = tool_axis(float(rng.uniform(0.0, 25.0)), azimuth)
        tip = np.append(rng.uniform(-26.0, 26.0, 2), 0.0)  # ±40 px around the middle
        if i == 1:
            tip = placements[0].tip_um[:2] - placements[0].axis[:2] * 30.0
            tip = np.append(tip + rng.uniform(-8, 8, 2), 0.0)
        if case == "outside":  # the tip 20-60 µm beyond the field's edge, the tool across it
            side = float(rng.uniform(0, 2 * np.pi))
            out = np.array([np.cos(side), np.sin(side)])
            reach = (83.0 + float(rng.uniform(20.0, 60.0))) / float(np.max(np.abs(out)))
            tip = np.append(out * reach, 0.0)
            axis = tool_axis(float(rng.uniform(0.0, 10.0)), float(np.degrees(side)) + 180.0)
        placements.append(ToolPlacement(_tool(rng, k), tip, axis))
    scene = ToolScene(placements, optics, background)
    image, truths = tool_image(camera, scene, rng)
    spec = f"tip:{kind}" if not placements else (
        f"tip:{kind}:{placements[0].tool.taper_deg:.1f}")  # fmt: skip
    return PopulationImage(image, truths, kind, case, focus_dof, spec, background.texture, scene)
