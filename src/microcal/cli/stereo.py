"""``microcal stereo-calibrate``: calibrate the cameras from images of a target."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from rich.console import Console
from typer import Option

from ..report.console import print_parts
from ._app import app

_Target = Annotated[str, Option(help="Target spec, e.g. dotgrid:40x30:250, chessboard:9x6:25000.")]
_Images = Annotated[list[str], Option(help="CAMERA=GLOB, once per camera; views in sorted order.")]
_Out = Annotated[Path, Option("--out", "-o", help="cameras.json to write.")]
_Steps = Annotated[Path | None, Option(help="CSV dx_um,dy_um,dz_um: steps per view (method a).")]
_Reference = Annotated[int, Option(help="Method b: the view that defines {V}.")]
_Lens = Annotated[str, Option(help="Method b: auto (by held-out error) or radial1 ... tilted.")]
_Model = Annotated[str, Option(help="Method a: pinhole, affine (telecentric) or auto.")]


@app.command("stereo-calibrate", short_help="Calibrate two or more cameras from target images.")
def stereo_calibrate(
    target: _Target, images: _Images, out: _Out = Path("cameras.json"),
    known_displacements: _Steps = None, reference_view: _Reference = 0, lens_model: _Lens = "auto",
    camera_model: _Model = "auto",
) -> None:  # fmt: skip
    """Calibrate two or more cameras from images of a target, all in one frame.

    With --known-displacements the thesis's method (DLT per camera, refined; pinhole or
    affine); without, unknown target poses (lens model chosen by held-out error). Multi-page
    TIFFs are averaged per view.

    Example: microcal stereo-calibrate --target dotgrid:40x30:250 --images top='cal/top_*.tiff'
    --images side='cal/side_*.tiff' --known-displacements cal/steps.csv --out cameras.json
    """
    from ..formats.cameras_file import CAMERAS_FORMAT, save_stereo_calibration
    from ..formats.commands_csv import read_joint_csv
    from ..formats.images import read_frames
    from ..formats.json_file import check_json_output
    from ..formats.options import check_camera_model, parse_images
    from ..procedures.stereo import calibrate_views
    from ..report.text_tables import stereo_lines
    from ..vision.targets import parse_target

    tgt = parse_target(target)
    check_json_output(out, CAMERAS_FORMAT, "cameras.json")
    files = parse_images(images)
    n_views = len(next(iter(files.values())))
    disp = None
    if known_displacements is not None:
        disp = read_joint_csv(known_displacements, what="--known-displacements", rows=n_views)[1]
    with Console(stderr=True).status("detecting the target and calibrating ..."):
        cal = calibrate_views({cam: [f.name for f in fs] for cam, fs in files.items()},
                              lambda cam, i: read_frames(files[cam][i]), tgt, displacements_um=disp,
                              reference_view=reference_view, lens_model=lens_model,
                              camera_model=check_camera_model(camera_model))  # fmt: skip
    save_stereo_calibration(out, cal, files, known_displacements, tgt.spec)
    print_parts(Console(), stereo_lines(cal, out))
