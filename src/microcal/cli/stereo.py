"""``microcal stereo-calibrate``: calibrate the cameras from images of a target."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from rich.console import Console
from typer import Option

from ..report.console import output_console, print_parts, staged_progress
from ._app import app, fail

_Target = Annotated[
    str | None,
    Option(
        help="Target spec, e.g. dotgrid:40x30:250; a slide larger than the field: "
        "dotgrid:...:markers=C,R/C,R/C,R (--rig: its own)."
    ),
]
_Images = Annotated[list[str] | None, Option(help="CAMERA=GLOB, once per camera; sorted views.")]
_Rig = Annotated[
    str | None, Option(help="Instead of images: 'sim' or a rig file with a target stage.")
]
_Views = Annotated[Path | None, Option(help="--rig: folder for the frames (OUT-views).")]
_Frames = Annotated[int, Option(min=1, max=100, help="--rig: frames per view and camera.")]
_Out = Annotated[Path, Option("--out", "-o", help="cameras.json to write.")]
_Steps = Annotated[Path | None, Option(help="CSV dx_um,dy_um,dz_um: steps per view (method a).")]
_Reference = Annotated[int, Option(help="Method b: the view that defines {V}.")]
_Lens = Annotated[str, Option(help="Method b: auto (by held-out error) or radial1 ... tilted.")]
_Model = Annotated[str, Option(help="Method a: pinhole, affine (telecentric) or auto.")]


@app.command("calibrate-cameras", short_help="Calibrate one or more cameras from target images.")
@app.command("stereo-calibrate", short_help="The same as calibrate-cameras.")
def stereo_calibrate(
    target: _Target = None, images: _Images = None, out: _Out = Path("cameras.json"),
    known_displacements: _Steps = None, reference_view: _Reference = 0, lens_model: _Lens = "auto",
    camera_model: _Model = "auto", rig: _Rig = None, views: _Views = None,
    frames_per_view: _Frames = 8,
    seed: Annotated[int | None, Option(min=0, help="Seed of the simulated rig.")] = None,
) -> None:  # fmt: skip
    """Calibrate one or more cameras from images of a target, all in one frame.

    One --images per camera; one camera alone gets its intrinsics, lens model and diagnostics
    as each camera of a pair does. stereo-calibrate is the same command. With
    --known-displacements the thesis's method (DLT per camera, refined; pinhole or
    affine); without, unknown target poses (lens model chosen by held-out error). Multi-page
    TIFFs are averaged per view. With --rig the rig's target stage moves the target by the
    steps (default 0-4 mm along z) and the cameras grab each view (kept in --views).

    Example: microcal stereo-calibrate --target dotgrid:40x30:250 --images top='cal/top_*.tiff'
    --images side='cal/side_*.tiff' --known-displacements cal/steps.csv --out cameras.json

    Example: microcal calibrate-cameras --target chessboard:9x6:25000 --images cam='cal/*.png'
    --out cameras.json

    Example: microcal stereo-calibrate --rig sim --out runs/a/cameras.json
    """
    if rig is not None:
        return _on_rig(rig, out, views, known_displacements, target, seed, frames_per_view,
                       camera_model)  # fmt: skip
    if target is None or not images:
        fail("give --target and --images (image files), or --rig (a rig with a target stage)")
    _from_images(target, images, out, known_displacements, reference_view, lens_model,
                 camera_model)  # fmt: skip


def _from_images(target: str, images: list[str], out: Path, known_displacements: Path | None,
                 reference_view: int, lens_model: str, camera_model: str) -> None:  # fmt: skip
    from ..report.text_tables import stereo_lines
    from ..workflows.stereo import stereo_calibrate_images

    with Console(stderr=True).status("detecting the target and calibrating ..."):
        cal = stereo_calibrate_images(target, images, out, known_displacements=known_displacements,
                                      reference_view=reference_view, lens_model=lens_model,
                                      camera_model=camera_model)  # fmt: skip
    print_parts(output_console(), stereo_lines(cal, out))


def _on_rig(rig: str, out: Path, views: Path | None, steps: Path | None, target: str | None,
            seed: int | None, frames: int, camera_model: str) -> None:  # fmt: skip
    from ..report.text_tables import stereo_lines
    from ..workflows.options import check_camera_model
    from ..workflows.stereo import RigViewsConfig, stereo_calibrate_rig

    cfg = RigViewsConfig(frames_per_view=frames, camera_model=check_camera_model(camera_model))
    with staged_progress() as progress:
        tick = lambda done, total: progress("views grabbed", done, total)  # noqa: E731
        cal, path, folder = stereo_calibrate_rig(rig, out, views=views, steps=steps, target=target,
                                                 seed=seed, config=cfg, progress=tick)  # fmt: skip
    print_parts(output_console(), [*stereo_lines(cal, path), f"views: {folder}"])
