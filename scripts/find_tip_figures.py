"""``find-tip``'s figures on the simulator: a tool anywhere in the field, one outside it, none.

1. ``thesis-tip`` with a needle (``tip:needle:20:5``), the top camera: the search
   (:func:`microcal.procedures.find_tip.find_tip`, as ``microcal find-tip`` runs it) from
   joints drawn across the travel, the tip anywhere in the field.
2. A microscope camera (256 x 256 px, 0.65 µm per px) over a needle on a three-axis stage
   (skewed 4 degrees against the image): the tip 200 µm outside the field, on each side.
3. No tool (the ``thesis`` platform: a board that moves, no tool): refused, the manipulator
   put back.

Usage::

    python scripts/find_tip_figures.py --starts 6
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from microcal.procedures.find_tip import find_tip
from microcal.sim import platform
from microcal.sim.tools import (
    Background,
    Optics,
    Tool,
    ToolPlacement,
    ToolScene,
    microscope_camera,
    tool_axis,
    tool_image,
)
from microcal.vision.tip_target import parse_tip

NEEDLE = "tip:needle:20:5"


def _thesis(seed: int, start_um: np.ndarray, preset: str, spec: str) -> tuple[str, ...]:
    over = {"board": spec} if preset == "thesis-tip" else {}
    plat = platform(preset, seed=seed, overrides=over)
    m, cam, clock = plat.manipulator, plat.cameras["top"], plat.clock

    def move_to(d: np.ndarray) -> None:
        m.check_limits(d)
        m.move_to_um(d)
        m.wait_until_stopped(clock)

    move_to(start_um)
    before = np.asarray(m.position_um()).copy()
    t0 = time.perf_counter()
    s = find_tip(move_to, m.position_um, cam.grab, parse_tip(spec),
                 image_size_px=cam.model.image_size_px, field_um=1000.0, reach_um=2000.0,
                 jog_um=50.0)  # fmt: skip
    wall = time.perf_counter() - t0
    centre = (np.array(cam.model.image_size_px) - 1) / 2
    if not s.found:
        back = float(np.linalg.norm(np.asarray(m.position_um()) - before))
        return (
            "no",
            "",
            "",
            "",
            f"{s.moves}",
            f"{wall:.0f}",
            f"{s.reason} (back within {back:.2f} µm)",
        )
    tool = plat.scene.board_placement(clock.now_s())
    assert isinstance(tool, ToolPlacement)
    truth = cam.model.project(tool.tip_um[None])[0]
    return ("yes", f"{np.hypot(*(truth - centre)):.2f}", f"{np.hypot(*(s.apex_px - truth)):.2f}",
            f"{np.hypot(*(s.apex_px - centre)):.2f}", f"{s.moves}", f"{wall:.0f}", "")  # fmt: skip


class _Scope:
    """A needle on an ideal three-axis stage under a 256 x 256 microscope camera."""

    camera = microscope_camera(0.65)

    def __init__(self, tip_um: np.ndarray, seed: int) -> None:
        self.joints = np.zeros(3)
        self.tip0 = tip_um
        self.rng = np.random.default_rng(seed)
        a = np.radians(4.0)
        self.M = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    def tip_um(self) -> np.ndarray:
        out: np.ndarray = self.tip0 + self.M @ self.joints
        return out

    def move_to(self, d: np.ndarray) -> None:
        self.joints = np.asarray(d, dtype=np.float64).copy()

    def position(self) -> np.ndarray:
        return self.joints.copy()

    def grab(self) -> np.ndarray:
        tool = ToolPlacement(Tool("needle", taper_deg=12, tip_um=2.0), self.tip_um(),
                             tool_axis(10.0, 30.0))  # fmt: skip
        scene = ToolScene([tool], Optics(0.3, focus_depth_um=1000.0), Background("plain", seed=1))
        out: np.ndarray = tool_image(self.camera, scene, self.rng)[0]
        return out


def _outside(tip_um: np.ndarray, seed: int) -> tuple[str, ...]:
    rig = _Scope(tip_um, seed)
    t0 = time.perf_counter()
    s = find_tip(rig.move_to, rig.position, rig.grab, parse_tip("tip:needle"),
                 image_size_px=rig.camera.image_size_px, field_um=166.0)  # fmt: skip
    wall = time.perf_counter() - t0
    centre = (np.array(rig.camera.image_size_px) - 1) / 2
    if not s.found:
        return ("no", "", "", "", f"{s.moves}", f"{wall:.0f}", s.reason)
    truth = rig.camera.project(rig.tip_um()[None])[0]
    return ("yes", f"{np.hypot(*(truth - centre)):.2f}", f"{np.hypot(*(s.apex_px - truth)):.2f}",
            f"{np.hypot(*(s.apex_px - centre)):.2f}", f"{s.moves}", f"{wall:.1f}", "")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default="field,outside,none", help="which of field, outside, none")
    args = ap.parse_args()
    cases = args.cases.split(",")
    rng = np.random.default_rng(args.seed)
    print("| case | found | true tip from the centre at the end (px) | apex error (px) | "
          "apex from the centre (px) | moves | s | reason |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for i in range(args.starts if "field" in cases else 0):
        start = rng.uniform([1500.0, 1500.0, 2400.0], [8000.0, 8000.0, 3000.0])
        row = _thesis(args.seed + i, start, "thesis-tip", NEEDLE)
        print(f"| thesis-tip, needle, start {np.round(start).astype(int).tolist()} µm | "
              + " | ".join(row) + " |")  # fmt: skip
    outside = ([283.0, 0.0, 0.0], [0.0, -283.0, 0.0], [-283.0, 60.0, 0.0])
    for tip in outside if "outside" in cases else ():
        row = _outside(np.array(tip), args.seed)
        print(f"| microscope, tip 200 µm outside the field at {tip} µm | " + " | ".join(row) + " |")
    if "none" in cases:
        row = _thesis(args.seed, np.array([5000.0, 4800.0, 2700.0]), "thesis", NEEDLE)
        print("| thesis (a board, no tool) | " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
