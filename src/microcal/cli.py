"""The command line: ``microcal --help``.

Every user error ends with one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import typer
from rich.console import Console
from rich.table import Table
from typer.core import TyperGroup

from ._validation import FloatArray
from ._version import __version__
from .errors import FormatError, InputError, MicrocalError


class _Commands(TyperGroup):
    """The command group: user errors end in one line on stderr and exit code 2.

    Handled here rather than around the entry point, so that ``microcal`` from a shell and
    typer's ``CliRunner`` in the tests go through the same path.
    """

    def main(  # type: ignore[override]
        self, args: list[str] | None = None, prog_name: str | None = None, **extra: Any
    ) -> Any:
        argv = sys.argv[1:] if args is None else list(args)
        extra.pop("standalone_mode", None)
        try:
            code = super().main(
                args=argv or ["--help"],
                prog_name=prog_name or "microcal",
                standalone_mode=False,
                **extra,
            )
        except typer.TyperException as exc:  # usage errors: bad option, value or command
            ctx = getattr(exc, "ctx", None)
            hint = f" (see: {ctx.command_path} --help)" if ctx is not None else ""
            _fail(f"{exc.format_message()}{hint}")
        except (typer.Abort, KeyboardInterrupt):
            _fail("interrupted")
        except MicrocalError as exc:
            _fail(str(exc))
        sys.exit(code if isinstance(code, int) else 0)

    def list_commands(self, ctx: Any) -> list[str]:
        """In the order of a calibration, not alphabetically."""
        names = super().list_commands(ctx)
        return [n for n in WORKFLOW if n in names] + [n for n in names if n not in WORKFLOW]


WORKFLOW = ("demo", "stereo-calibrate", "acquire", "measure", "fit", "solve", "evaluate", "report")

app = typer.Typer(
    name="microcal",
    cls=_Commands,
    help="Vision-based automatic calibration of microrobotic systems.\n\n"
    "Example: microcal demo  (the whole calibration on the simulated platform; then open "
    "demo-out/report.html)",
    no_args_is_help=True,
    add_completion=False,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        print(f"microcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """Vision-based automatic calibration of microrobotic systems."""


def _staged(bar: Any) -> Any:
    """A progress callback (stage, done, total) with one bar per stage."""
    tasks: dict[str, Any] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=total)
        bar.update(tasks[stage], completed=done)

    return progress


QUICK_POSES, QUICK_FRAMES = 40, 2
DEMO_FILES = frozenset(
    {
        "run.json",
        "commands.csv",
        "journal.jsonl",
        "images",
        "measurements.csv",
        "cameras.json",
        "calibration.json",
        "results.json",
        "report.html",
    }
)


def _clear_demo_dir(out: Path) -> None:
    """Make ``out`` ready for a demo: new, empty, or holding only an earlier demo's files."""
    import json
    import shutil

    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory")
    if not out.exists() or not any(out.iterdir()):
        return
    entries = {p.name for p in out.iterdir()}
    try:
        manifest = json.loads((out / "run.json").read_text(encoding="utf-8"))
        is_demo = manifest.get("provenance", {}).get("command") == "demo"
    except (OSError, ValueError, AttributeError):
        is_demo = False
    if not is_demo or not entries <= DEMO_FILES:
        raise InputError(
            f"--out {out}: holds files that an earlier demo did not write; "
            f"choose a new or empty directory"
        )
    for name in entries:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()


@app.command(short_help="Run the whole calibration on the simulated platform.")
def demo(
    seed: Annotated[int, typer.Option(help="Seed of all random draws.")] = 0,
    poses: Annotated[
        int, typer.Option(min=20, help="Poses to acquire (the thesis used 170).")
    ] = 170,
    quick: Annotated[
        bool, typer.Option(help="A short run: 40 poses, 2 frames each, 1 ISO cycle.")
    ] = False,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Run directory to write (replaces an earlier demo).")
    ] = Path("demo-out"),
) -> None:
    """Run the whole calibration on the simulated thesis platform and write its report.

    Stereo calibration from rendered images, acquisition with vision settling, 3D
    measurement, matrix and polynomial identification, compensation, ISO 9283 and decoupling
    tests; writes the run directory, cameras.json, calibration.json, results.json and
    report.html, and compares the figures with the thesis's.

    Example: microcal demo --seed 3 --out demo-3
    """
    import time

    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from .formats.calibration_file import provenance
    from .formats.run_directory import RunWriter
    from .procedures.demo import CALIBRATION_TARGET, demo_design, run_demo
    from .sim import platform
    from .thesis.figures import (
        CLAIMED_ACCURACY_UM,
        REPROJECTION_ERROR_SIDE_PX,
        REPROJECTION_ERROR_TOP_PX,
        VALIDATION_UM,
    )

    wall0 = time.monotonic()
    console = Console()
    n_poses, frames = (QUICK_POSES, QUICK_FRAMES) if quick else (poses, 5)
    _clear_demo_dir(out)
    plat = platform("thesis", seed=seed)
    manifest = {
        "rig": {"driver": "sim", "preset": "thesis", "seed": seed, "overrides": {}},
        "target": plat.scene.board.spec,
        "cameras": list(plat.cameras),
        "design": {"kind": "random", "poses": n_poses, "seed": seed},
        "settle": "vision",
        "frames_per_pose": frames,
        "store": "roi",
        "provenance": provenance(command="demo", seed=seed),
    }
    writer = RunWriter.create(out, manifest, demo_design(seed, n_poses))
    console.print(
        f"[bold]microcal demo[/bold] on the simulated thesis platform, writing {out}/: stereo "
        f"calibration from rendered images, {n_poses} poses acquired with vision settling and "
        "measured in 3D, kinematic identification, compensation, and the ISO 9283 and "
        "decoupling tests."
    )
    with Progress(
        TextColumn("{task.description:<28}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        progress = _staged(bar)

        result = run_demo(
            seed=seed,
            poses=n_poses,
            frames_per_pose=frames,
            progress=progress,
            frames_per_view=4 if quick else 8,
            cycles=1 if quick else 3,
            decoupling_samples=5 if quick else 17,
            store=writer.store,
            plat=plat,
        )

    cal = result.calibration
    table = Table(
        title=f"1. Stereo calibration: {CALIBRATION_TARGET} at 5 known heights ({cal.method})"
    )
    for col in ("camera", "RMS px", "thesis px", "vs true camera px", "fx px", "fy px"):
        table.add_column(col, justify="right")
    thesis_rms = {"top": REPROJECTION_ERROR_TOP_PX, "side": REPROJECTION_ERROR_SIDE_PX}
    for name, c in cal.cameras.items():
        table.add_row(
            name,
            f"{c.rms_px:.3f}",
            f"{thesis_rms.get(name, float('nan')):.3f}",
            f"{result.calibration_truth_px[name]:.3f}",
            f"{c.model.K[0, 0]:.1f}",
            f"{c.model.K[1, 1]:.1f}",
        )
    console.print(table)
    ok = result.measured_ok
    stds = np.array([m.std_um for m, good in zip(result.measurements, ok, strict=True) if good])
    console.print(
        f"2. Measured {int(ok.sum())} of {len(ok)} poses ({frames} frames each, "
        f"{result.sim_time_s / 60:.0f} min of simulated time): 3D error vs ground truth "
        f"{result.measurement_rms_um:.2f} µm RMS "
        f"(the thesis claimed ±{CLAIMED_ACCURACY_UM:g} µm without measuring); reported std x/y/z "
        + "/".join(f"{v:.2f}" for v in np.median(stds, axis=0))
        + " µm."
    )
    n_fit = int(result.models["matrix"].validation["n_fit"])  # type: ignore[call-overload]
    table = Table(
        title=f"3. Identification: first {n_fit} poses fit, the rest validate (Eq 5.1, µm)"
    )
    for col in ("model", "mean", "std", "max", "thesis mean", "thesis std", "thesis max"):
        table.add_column(col, justify="right")
    for kind in ("matrix", "polynomial"):
        v = result.models[kind].validation
        ours = [float(v[f"{k}_um"]) for k in ("mean", "std", "max")]  # type: ignore[arg-type]
        theirs = [VALIDATION_UM[kind][k] for k in ("mean", "std", "max")]
        table.add_row(kind, *(f"{x:.2f}" for x in ours), *(f"{x:.2f}" for x in theirs))
    o = result.oracle
    table.add_row("oracle", f"{o['mean']:.2f}", f"{o['std']:.2f}", f"{o['max']:.2f}", "-", "-", "-")
    console.print(table)
    _print_evaluation(console, result.evaluation)
    _write_demo_files(out, result, wall_s=time.monotonic() - wall0)
    console.print(
        f"wrote {out}/: the run (run.json, commands.csv, journal.jsonl, images/), "
        f"measurements.csv, cameras.json, calibration.json, results.json and report.html "
        f"({time.monotonic() - wall0:.0f} s); open {out / 'report.html'} in a browser"
    )
    model = result.models["polynomial"].model
    console.print(
        "polynomial terms selected stepwise: "
        + "; ".join(
            f"{axis}: {', '.join(name for name, _, _ in model.axis_terms(i))}"
            for i, axis in enumerate("xyz")
        )
    )


def _print_evaluation(console: Console, evaluation: dict[str, Any]) -> None:
    from .thesis.figures import DECOUPLING_UM, POSE_ACCURACY_UM

    if not evaluation:
        return
    pa = evaluation["pose_accuracy"]
    table = Table(title="4. Pose accuracy at the Table 5-2 poses: mean / worst AP_P (µm)")
    for col in ("condition", "vision", "ground truth", "thesis"):
        table.add_column(col, justify="right")
    for name, (mean, worst) in POSE_ACCURACY_UM.items():
        cells = [f"{pa[src][name]['mean_ap_p_um']:.2f} / {pa[src][name]['max_ap_p_um']:.2f}"
                 for src in ("vision", "truth")]  # fmt: skip
        table.add_row(name, *cells, f"{mean:.2f} / {worst:.2f}")
    console.print(table)
    dc = evaluation["decoupling"]
    table = Table(title="5. Decoupling: undesired displacement \\[min, max] (µm), truth (thesis)")
    for col in ("condition", "x", "y", "z"):
        table.add_column(col, justify="right")
    for name, thesis in DECOUPLING_UM.items():
        cells = []
        for axis in "xyz":
            lo, hi = dc["truth"][name]["undesired_um"][axis]
            cells.append(f"[{lo:.1f}, {hi:.1f}] ({thesis[axis][0]:.1f}, {thesis[axis][1]:.1f})")
        table.add_row(name, *cells)
    console.print(table)


def _write_demo_files(out: Path, result: Any, wall_s: float) -> None:
    from .formats.calibration_file import (
        Calibration,
        ManipulatorCalibration,
        provenance,
        write_calibration,
    )
    from .formats.cameras_file import cameras_to_dict, write_cameras
    from .formats.measurements import write_measurements
    from .formats.results_file import update_results
    from .report import write_report

    out.mkdir(parents=True, exist_ok=True)
    ms = result.measurements
    write_measurements(
        out / "measurements.csv",
        result.d_um,
        np.array([m.p_um for m in ms]),
        std_um=np.array([m.std_um for m in ms]),
        status=[m.status for m in ms],
        reason=[m.reason for m in ms],
    )
    prov = provenance(command="demo", seed=result.seed)
    cameras = cameras_to_dict(result.calibration, prov)
    write_cameras(out / "cameras.json", cameras)
    poly, matrix = result.models["polynomial"], result.models["matrix"]
    extra = {"matrix_model": matrix.model.to_dict(), "matrix_validation": matrix.validation}
    entry = ManipulatorCalibration("m1", poly.model, poly.validation, extra)
    write_calibration(
        out / "calibration.json", Calibration({"m1": entry}, cameras["cameras"], prov)
    )
    results_path = out / "results.json"
    results_path.unlink(missing_ok=True)
    update_results(results_path, {
        "stereo": {n: {"rms_px": c.rms_px} for n, c in result.calibration.cameras.items()},
        "measurement": {"rms_error_um": result.measurement_rms_um},
        "models": {k: {"validation": v.validation} for k, v in result.models.items()},
        "oracle": {f"{k}_um": v for k, v in result.oracle.items()},
        "acquisition": {
            "poses": len(result.records),
            "stored": sum(r["status"] == "ok" for r in result.records),
            "mean_settle_s": float(np.mean([r["settle_s"] for r in result.records])),
            "failed": [{"pose": r["pose"], "reason": r.get("reason", "")}
                       for r in result.records if r["status"] != "ok"],
        },
        **result.evaluation,
        "timing": {"simulated_s": result.sim_time_s, "wall_s": wall_s},
        "provenance": prov,
    })  # fmt: skip
    write_report(out)


class ModelChoice(StrEnum):
    matrix = "matrix"
    polynomial = "polynomial"


class SelectChoice(StrEnum):
    stepwise = "stepwise"
    all = "all"


def _measurements_path(source: Path) -> Path:
    return source / "measurements.csv" if source.is_dir() else source


@app.command(short_help="Identify a kinematic model from measurements.")
def fit(
    source: Annotated[
        Path,
        typer.Argument(help="Run directory (with measurements.csv) or a measurements CSV file."),
    ],
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Calibration file to write or update.")
    ] = Path("calibration.json"),
    model: Annotated[
        ModelChoice, typer.Option(help="Kinematic model (thesis Eq 4.5 or 4.6).")
    ] = ModelChoice.polynomial,
    select: Annotated[
        SelectChoice, typer.Option(help="Polynomial terms: stepwise selection or all.")
    ] = SelectChoice.stepwise,
    penter: Annotated[float, typer.Option(help="Stepwise: p-value to enter.")] = 0.05,
    premove: Annotated[float, typer.Option(help="Stepwise: p-value to leave.")] = 0.10,
    train: Annotated[
        int | None,
        typer.Option(
            min=1, help="Fit on the first N poses, validate on the rest (default: 110/170 of them)."
        ),
    ] = None,
    folds: Annotated[
        int | None, typer.Option(min=2, help="Validate by K-fold cross-validation instead.")
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the cross-validation folds.")] = 0,
    temperature: Annotated[
        bool, typer.Option(help="Add temperature terms T, T² (needs temperature_c).")
    ] = False,
    manipulator: Annotated[
        str, typer.Option(help="Name of the manipulator in the calibration file.")
    ] = "m1",
    cameras: Annotated[
        Path | None, typer.Option(help="cameras.json to include (needed by 'microcal evaluate').")
    ] = None,
    mat: Annotated[
        Path | None, typer.Option(help="Also export the calibration as a MATLAB .mat file.")
    ] = None,
) -> None:
    """Identify a manipulator's kinematic model from measured positions.

    Example: microcal fit runs/a --model polynomial --train 110 --out calibration.json
    """
    from .formats.calibration_file import (
        Calibration,
        ManipulatorCalibration,
        export_mat,
        load_calibration,
        provenance,
        write_calibration,
    )
    from .formats.measurements import read_measurements
    from .procedures.identification import identify

    console = Console()
    path = _measurements_path(source)
    meas = read_measurements(path)
    if temperature and meas.temperature_c is None:
        raise InputError(f"--temperature: {path} has no 'temperature_c' column")
    existing = load_calibration(out) if out.exists() else None
    result = identify(
        meas.d_um,
        meas.p_um,
        model.value,
        select=select.value,
        penter=penter,
        premove=premove,
        train=train,
        folds=folds,
        seed=seed,
        temperature_c=meas.temperature_c if temperature else None,
    )
    joint_range = np.column_stack([meas.d_um.min(axis=0), meas.d_um.max(axis=0)])
    extra: dict[str, Any] = {"joint_range_um": joint_range.tolist()}
    if model == ModelChoice.polynomial:
        # The matrix model on the same poses, for the matrix compensator (Eq 4.16).
        matrix = identify(meas.d_um, meas.p_um, "matrix", train=train)
        extra["matrix_model"] = matrix.model.to_dict()
        extra["matrix_validation"] = matrix.validation
    entry = ManipulatorCalibration(manipulator, result.model, result.validation, extra)
    camera_data = existing.cameras if existing else {}
    if cameras is not None:
        camera_data = _camera_section(cameras)
    manipulators = dict(existing.manipulators) if existing else {}
    manipulators[manipulator] = entry
    calibration = Calibration(
        manipulators,
        cameras=camera_data,
        provenance=provenance({"measurements": path}, command="fit", model=model.value),
    )
    write_calibration(out, calibration)
    if mat is not None:
        export_mat(mat, calibration)
    m = result.model
    console.print(
        f"{model.value} model of {manipulator!r} from {len(meas.pose)} poses of {path}"
        + (f" ({meas.n_failed} failed poses skipped)" if meas.n_failed else "")
    )
    table = Table(title="Selected terms: coefficient ± standard error (µm per unit of the term)")
    table.add_column("term")
    for axis_name in "xyz":
        table.add_column(f"{axis_name} (µm)", justify="right")
    for a, t in enumerate(m.terms):
        if not m.selected[:, a].any():
            continue
        cells = []
        for axis in range(3):
            if m.selected[axis, a]:
                se = float(np.sqrt(m.covariance[axis, a, a]))
                cells.append(f"{m.coefficients[axis, a]:.6g} ± {se:.2g}")
            else:
                cells.append("-")
        table.add_row(t.name, *cells)
    console.print(table)
    v: dict[str, Any] = result.validation
    console.print(
        f"validation ({v['method']}): mean {v['mean_um']:.2f} µm, std {v['std_um']:.2f}, "
        f"max {v['max_um']:.2f}, RMS {v['rms_um']:.2f}, 95 % {v['p95_um']:.2f}; "
        "RMS per axis x/y/z " + "/".join(f"{r:.2f}" for r in v["rms_axis_um"].values()) + " µm"
    )
    if "cross_validation" in v:
        cv = v["cross_validation"]
        console.print(
            f"{cv['folds']}-fold cross-validation (selection repeated per fold): mean "
            f"{cv['mean_um']:.2f} µm, std {cv['std_um']:.2f}, max {cv['max_um']:.2f}"
        )
        unstable = [
            f"{axis}:{term} {share:.0%}"
            for axis, shares in cv["term_frequency"].items()
            for term, share in shares.items()
            if 0 < share < 1
        ]
        if unstable:
            console.print("terms not selected in every fold: " + ", ".join(unstable))
    console.print(f"wrote {out}" + (f" and {mat}" if mat else ""))


def _camera_section(path: Path) -> dict[str, Any]:
    """The ``cameras`` object of a cameras.json, validated."""
    from .formats.cameras_file import read_cameras

    return read_cameras(path)[0]


def _parse_limits(text: str) -> FloatArray:
    try:
        pairs = [tuple(float(v) for v in part.split(":")) for part in text.split(",")]
        arr = np.array(pairs, dtype=np.float64)
    except ValueError:
        arr = np.zeros(0)
    if arr.shape != (3, 2) or np.any(arr[:, 0] >= arr[:, 1]):
        raise InputError(
            f"--limits: expected LOW:HIGH for each joint, as 0:8000,0:8000,0:4800, got {text!r}"
        )
    return arr


@app.command(short_help="Print joint commands that reach given positions.")
def solve(
    calibration: Annotated[Path, typer.Argument(help="calibration.json")],
    position_um: Annotated[
        list[float],
        typer.Argument(help="Desired position X Y Z in {G}, µm (use -- before negative values)."),
    ],
    manipulator: Annotated[
        str | None, typer.Option(help="Manipulator name (optional if only one).")
    ] = None,
    temperature: Annotated[
        float | None, typer.Option(help="Ambient temperature, °C, for models with T terms.")
    ] = None,
    limits: Annotated[
        str | None, typer.Option(help="Soft limits per joint, LOW:HIGH,LOW:HIGH,LOW:HIGH in µm.")
    ] = None,
) -> None:
    """Print the joint commands that put the end-effector at a position (the compensator).

    Example: microcal solve calibration.json 2000 2000 300 --limits 0:8000,0:8000,0:4800
    """
    from .formats.calibration_file import load_calibration

    if len(position_um) != 3:
        raise InputError(f"position: expected 3 numbers X Y Z in µm, got {len(position_um)}")
    target = np.array(position_um, dtype=np.float64)
    if not np.all(np.isfinite(target)):
        raise InputError(f"position: expected finite numbers, got {position_um}")
    m = load_calibration(calibration).manipulator(manipulator)
    lim = _parse_limits(limits) if limits else None
    extra = None if temperature is None else np.array([[temperature]])
    d = m.joints_for(target, extra=extra, limits_um=lim)[0]
    u = d if extra is None else np.concatenate([d, extra[0]])
    reached = m.predict_um(u)[0]
    print("dx_um dy_um dz_um")
    print(" ".join(f"{v:.4f}" for v in d))
    rng = m.joint_range_um
    if rng is not None and np.any((d < rng[:, 0]) | (d > rng[:, 1])):
        print(
            "note: these joints lie outside the range the model was identified on "
            + ",".join(f"{lo:.0f}:{hi:.0f}" for lo, hi in rng)
            + " µm; the model extrapolates there",
            file=sys.stderr,
        )
    print(
        f"{m.model.kind} model of {m.name!r}: model(d) - target = "
        + ", ".join(f"{v:.2e}" for v in reached - target)
        + " µm",
        file=sys.stderr,
    )


def _parse_images(specs: list[str]) -> dict[str, list[Path]]:
    import glob

    out: dict[str, list[Path]] = {}
    for spec in specs:
        name, sep, pattern = spec.partition("=")
        if not sep or not name or not pattern:
            raise InputError(
                f"--images: expected CAMERA=GLOB such as top='cal/top_*.tiff', got {spec!r}"
            )
        files = sorted(Path(p) for p in glob.glob(pattern))
        if not files:
            raise InputError(f"--images {name}: no file matches {pattern!r}")
        out[name] = files
    if len(out) != 2:
        raise InputError(f"--images: expected two cameras, got {sorted(out)}")
    counts = {n: len(f) for n, f in out.items()}
    if len(set(counts.values())) != 1:
        raise InputError(f"--images: every camera needs one image per view, got {counts}")
    return out


def _read_displacements(path: Path, n_views: int) -> FloatArray:
    import csv

    try:
        rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    except FileNotFoundError:
        raise InputError(f"--known-displacements: {path}: no such file") from None
    try:
        disp = np.array([[float(r["dx_um"]), float(r["dy_um"]), float(r["dz_um"])] for r in rows])
    except (KeyError, TypeError, ValueError):
        raise InputError(
            f"--known-displacements: {path}: expected columns dx_um,dy_um,dz_um with numbers"
        ) from None
    if disp.shape != (n_views, 3):
        raise InputError(
            f"--known-displacements: {path} has {len(rows)} rows, expected one per view ({n_views})"
        )
    return disp


@app.command("stereo-calibrate", short_help="Calibrate two cameras from images of a target.")
def stereo_calibrate(
    target: Annotated[
        str, typer.Option(help="Target spec, e.g. dotgrid:40x30:250 or chessboard:9x6:25000.")
    ],
    images: Annotated[
        list[str], typer.Option(help="CAMERA=GLOB, once per camera; views pair up in sorted order.")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="cameras.json to write.")] = Path(
        "cameras.json"
    ),
    known_displacements: Annotated[
        Path | None,
        typer.Option(
            help="CSV dx_um,dy_um,dz_um per view: the target moved by known steps (method a)."
        ),
    ] = None,
    reference_view: Annotated[int, typer.Option(help="Method b: the view that defines {V}.")] = 0,
) -> None:
    """Calibrate two cameras from images of a target.

    With --known-displacements the thesis's method (target at known positions, DLT per
    camera, refined with distortion); without, unknown target poses (per-camera then stereo
    calibration). Multi-page TIFFs are averaged per view.

    Example: microcal stereo-calibrate --target dotgrid:40x30:250 --images top='cal/top_*.tiff'
    --images side='cal/side_*.tiff' --known-displacements cal/steps.csv --out cameras.json
    """
    from .formats.calibration_file import provenance
    from .formats.cameras_file import cameras_to_dict, write_cameras
    from .formats.images import read_frames
    from .procedures.stereo import calibrate_views
    from .vision.targets import parse_target

    tgt = parse_target(target)
    files = _parse_images(images)
    n_views = len(next(iter(files.values())))
    disp = _read_displacements(known_displacements, n_views) if known_displacements else None
    names = {cam: [f.name for f in fs] for cam, fs in files.items()}
    console = Console(stderr=True)
    with console.status("detecting the target ..."):
        cal = calibrate_views(
            names,
            lambda cam, i: read_frames(files[cam][i]),
            tgt,
            displacements_um=disp,
            reference_view=reference_view,
        )
    inputs = {f"{cam}/{f.name}": f for cam, fs in files.items() for f in fs}
    if known_displacements:
        inputs["displacements"] = known_displacements
    write_cameras(
        out, cameras_to_dict(cal, provenance(inputs, command="stereo-calibrate", target=tgt.spec))
    )
    table = Table(title=f"Stereo calibration ({cal.method})")
    for col in ("camera", "RMS px", "views used", "rejected", "fx px", "fy px"):
        table.add_column(col, justify="right")
    for name, c in cal.cameras.items():
        table.add_row(
            name,
            f"{c.rms_px:.4f}",
            str(c.views_used),
            str(len(c.views_rejected)),
            f"{c.model.K[0, 0]:.1f}",
            f"{c.model.K[1, 1]:.1f}",
        )
    Console().print(table)
    for name, c in cal.cameras.items():
        for r in c.views_rejected:
            print(f"rejected {name} {r['image']}: {r['reason']}")
    print(f"baseline {cal.baseline_um:.0f} µm; stereo RMS {cal.rms_px:.4f} px; wrote {out}")


@app.command(short_help="Measure the end-effector in 3D at every pose.")
def measure(
    run_dir: Annotated[Path, typer.Argument(help="Run directory (commands.csv and images/).")],
    cameras: Annotated[
        Path, typer.Option(help="cameras.json (or a calibration.json with cameras).")
    ],
    target: Annotated[
        str | None,
        typer.Option(help="End-effector board; default: run.json's, else chessboard:4x3:400."),
    ] = None,
) -> None:
    """Measure the end-effector in 3D at every pose of a run; writes measurements.csv.

    Example: microcal measure runs/a --cameras cameras.json
    """
    from .formats.cameras_file import load_cameras
    from .formats.images import read_frames
    from .formats.measurements import write_measurements
    from .formats.run_directory import find_image, read_commands, read_journal, read_manifest
    from .procedures.measurement import measure_poses
    from .vision.roi import frames_from_region
    from .vision.targets import parse_target

    if not run_dir.is_dir():
        raise InputError(f"{run_dir}: not a directory (expected a run directory)")
    models = load_cameras(cameras)
    poses, d = read_commands(run_dir)
    manifest = read_manifest(run_dir)
    spec = target or str(manifest.get("target", "chessboard:4x3:400"))
    board = parse_target(spec)

    journal = {int(r["pose"]): r for r in read_journal(run_dir)}

    def load(pose: int, cam: str) -> list[Any]:
        record = journal.get(pose, {})
        if record.get("status") == "failed":
            raise FormatError(f"acquisition failed: {record.get('reason', '')}")
        path = find_image(run_dir, cam, pose)
        if path is None:
            raise FormatError(f"no image images/{cam}_{pose:04d}.tiff")
        frames = read_frames(path)
        image = (record.get("images") or {}).get(cam, {})
        if "offset_px" in image:  # stored as a region: put it back in a frame of full size
            frames = frames_from_region(frames, image["offset_px"], image["full_size_px"])
        return frames

    from rich.progress import Progress

    with Progress(console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("measuring", total=len(poses))
        results = measure_poses(
            poses,
            d,
            load,
            models,
            board,
            progress=lambda done, _t: bar.update(task, completed=done),
        )
    ok = [r.status == "ok" for r in results]
    p = np.array([r.p_um for r in results])
    std = np.array([r.std_um for r in results])
    write_measurements(
        run_dir / "measurements.csv",
        d,
        p,
        std_um=std,
        status=[r.status for r in results],
        reason=[r.reason for r in results],
    )
    n_ok = sum(ok)
    print(f"measured {n_ok} of {len(results)} poses; wrote {run_dir / 'measurements.csv'}")
    if n_ok:
        med = np.median(std[np.array(ok)], axis=0)
        print("median standard deviation x/y/z: " + "/".join(f"{v:.2f}" for v in med) + " µm")
    for r in results:
        if r.status != "ok":
            print(f"pose {r.pose} failed: {r.reason}")


@app.command(short_help="Write a run's calibration report (one HTML file).")
def report(
    run_dir: Annotated[
        Path,
        typer.Argument(help="Run directory (any of run.json, measurements.csv, results.json...)."),
    ],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Where to write; default RUN_DIR/report.html."),
    ] = None,
) -> None:
    """Write the calibration report of a run: one self-contained HTML file with its figures.

    It shows what the run directory holds: the stereo calibration, the command design, the
    measurement uncertainty, the models and their validation errors, the pose-accuracy and
    decoupling tests, failed poses and provenance.

    Example: microcal report demo-out
    """
    from .report import write_report

    if out is not None and out.is_dir():
        raise InputError(f"--out {out}: is a directory; give a file name such as report.html")
    path = write_report(run_dir, out)
    print(f"wrote {path}")


class PoseChoice(StrEnum):
    table = "table-5-2"
    cube = "iso-cube"


class TestChoice(StrEnum):
    pose_accuracy = "pose-accuracy"
    decoupling = "decoupling"
    all = "all"


@app.command(short_help="Pose accuracy (ISO 9283) and decoupling tests.")
def evaluate(
    calibration: Annotated[
        Path, typer.Option(help="calibration.json (with cameras, see 'fit --cameras').")
    ],
    rig: Annotated[
        str, typer.Option(help="The rig: 'sim' (the simulated thesis platform).")
    ] = "sim",
    test: Annotated[TestChoice, typer.Option(help="Which test to run.")] = TestChoice.all,
    manipulator: Annotated[
        str | None, typer.Option(help="Manipulator name (optional if only one).")
    ] = None,
    cycles: Annotated[
        int, typer.Option(min=1, help="ISO 9283 cycles per pose (the standard asks 30).")
    ] = 3,
    poses: Annotated[
        PoseChoice,
        typer.Option(help="Test poses: the thesis's Table 5-2, or ISO 9283's cube P1-P5."),
    ] = PoseChoice.table,
    frames: Annotated[int, typer.Option(min=1, help="Frames measured per pose.")] = 5,
    settle_s: Annotated[
        float, typer.Option(min=0.0, help="Wait after the device reports it stopped, s.")
    ] = 5.0,
    seed: Annotated[int, typer.Option(help="Seed of the simulated rig.")] = 0,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="results.json to write or update.")
    ] = Path("results.json"),
) -> None:
    """Pose accuracy (ISO 9283) and decoupling tests without and with compensation.

    Each test runs uncalibrated, with the matrix compensator and with the optimal one, measured
    by the cameras (and on the simulator also by ground truth).

    Example: microcal evaluate --rig sim --calibration calibration.json --test pose-accuracy
    """
    from .control.feedforward import FeedForward
    from .formats.calibration_file import load_calibration
    from .formats.cameras_file import models_from_dict
    from .formats.results_file import update_results
    from .procedures.evaluation import (
        VisionProbe,
        iso_cube_poses,
        run_decoupling,
        run_pose_accuracy,
    )
    from .sim import platform
    from .thesis.experiment import TABLE_5_2_POSES_UM, WORKSPACE_MAX_UM, WORKSPACE_MIN_UM
    from .thesis.figures import POSE_ACCURACY_UM

    if rig != "sim":
        raise InputError(
            f"--rig: {rig!r} is not available; this version drives the simulated rig 'sim' only"
        )
    cal = load_calibration(calibration)
    m = cal.manipulator(manipulator)
    if not cal.cameras:
        raise InputError(
            f"{calibration}: holds no cameras; run 'microcal fit ... --cameras cameras.json'"
        )
    models = models_from_dict(
        {"format": "microcal.cameras/1", "cameras": cal.cameras}, str(calibration)
    )
    plat = platform("thesis", seed=seed)
    missing = sorted(set(plat.cameras) - set(models))
    if missing:
        raise InputError(f"{calibration}: no calibration for the rig's camera(s) {missing}")
    if m.model.extra_inputs:
        raise InputError(
            "evaluate: models with extra inputs (temperature) need a rig with a sensor"
        )
    conditions: dict[str, FeedForward | None] = {"uncalibrated": None}
    matrix = m.matrix_model
    conditions["matrix"] = FeedForward(plat.manipulator, matrix or m.model, "matrix")
    if m.model.kind == "polynomial":
        conditions["optimal"] = FeedForward(plat.manipulator, m.model, "optimal")
    probe = VisionProbe(
        {n: plat.cameras[n] for n in models}, models, plat.scene.board, frames=frames
    )
    console = Console()
    parts: dict[str, Any] = {}
    from rich.progress import Progress

    with Progress(console=Console(stderr=True), transient=True) as bar:
        progress = _staged(bar)

        kwargs = {"settle_s": settle_s, "truth": plat.truth_position_um, "progress": progress}
        if test in (TestChoice.pose_accuracy, TestChoice.all):
            test_poses = (
                TABLE_5_2_POSES_UM
                if poses == PoseChoice.table
                else iso_cube_poses(WORKSPACE_MIN_UM, WORKSPACE_MAX_UM)
            )
            parts["pose_accuracy"] = run_pose_accuracy(
                plat.manipulator,
                plat.clock,
                probe,
                conditions,
                poses_um=test_poses,
                cycles=cycles,
                **kwargs,
            )
        if test in (TestChoice.decoupling, TestChoice.all):
            parts["decoupling"] = run_decoupling(
                plat.manipulator,
                plat.clock,
                probe,
                conditions,
                **kwargs,
            )
    update_results(out, parts)
    if "pose_accuracy" in parts:
        table = Table(title=f"Pose accuracy AP_P (µm): mean / worst over the {poses.value} poses")
        for col in ("condition", "vision", "ground truth", "thesis"):
            table.add_column(col, justify="right")
        thesis = {
            name: f"{mean:.2f} / {worst:.2f}" if poses == PoseChoice.table else "-"
            for name, (mean, worst) in POSE_ACCURACY_UM.items()
        }
        pa = parts["pose_accuracy"]
        for name in conditions:
            cells = [f"{pa[src][name]['mean_ap_p_um']:.2f} / {pa[src][name]['max_ap_p_um']:.2f}"
                     for src in ("vision", "truth")]  # fmt: skip
            table.add_row(name, *cells, thesis[name])
        console.print(table)
    if "decoupling" in parts:
        table = Table(title="Decoupling: undesired displacement \\[min, max] (µm), vision | truth")
        for col in ("condition", "x", "y", "z"):
            table.add_column(col, justify="right")
        dc = parts["decoupling"]
        for name in conditions:
            cells = []
            for axis in "xyz":
                v, t = (
                    dc["vision"][name]["undesired_um"][axis],
                    dc["truth"][name]["undesired_um"][axis],
                )
                cells.append(f"[{v[0]:.1f}, {v[1]:.1f}] | [{t[0]:.1f}, {t[1]:.1f}]")
            table.add_row(name, *cells)
        console.print(table)
    print(f"wrote {out}")


def _read_command_file(path: Path) -> FloatArray:
    import csv

    try:
        rows = list(csv.DictReader(path.read_text(encoding="utf-8").splitlines()))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"--design {path}: cannot be read ({exc})") from None
    try:
        d = np.array([[float(r["dx_um"]), float(r["dy_um"]), float(r["dz_um"])] for r in rows])
    except (KeyError, TypeError, ValueError):
        raise InputError(
            f"--design {path}: expected a CSV with columns dx_um,dy_um,dz_um of numbers"
        ) from None
    if d.ndim != 2 or len(d) < 2 or not np.all(np.isfinite(d)):
        raise InputError(f"--design {path}: expected at least 2 rows of finite numbers")
    return d


def _evaluation_trajectories() -> dict[str, FloatArray]:
    from .procedures.evaluation import decoupling_path, iso_cube_poses
    from .thesis.experiment import TABLE_5_2_POSES_UM, WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

    return {
        "table-5-2": TABLE_5_2_POSES_UM,
        "decoupling": decoupling_path()[0],
        "iso-cube": iso_cube_poses(WORKSPACE_MIN_UM, WORKSPACE_MAX_UM),
    }


def _parse_settle(text: str) -> tuple[str, float]:
    if text == "vision":
        return "vision", 0.0
    kind, _, value = text.partition(":")
    try:
        seconds = float(value)
    except ValueError:
        seconds = -1.0
    if kind != "fixed" or seconds < 0:
        raise InputError(
            f"--settle: expected 'vision' or 'fixed:SECONDS' such as fixed:30, got {text!r}"
        )
    return "fixed", seconds


@app.command(short_help="Move through a design, settle and store images.")
def acquire(
    out: Annotated[Path, typer.Option("--out", "-o", help="Run directory to create (or resume).")],
    rig: Annotated[str, typer.Option(help="'sim' or a rig TOML file.")] = "sim",
    design: Annotated[
        str,
        typer.Option(
            help="random, sobol, lhs, grid; table-5-2, decoupling, iso-cube (evaluation "
            "trajectories); or a CSV of dx_um,dy_um,dz_um."
        ),
    ] = "random",
    poses: Annotated[
        int, typer.Option(min=2, help="Poses of a generated design (the thesis: 170).")
    ] = 170,
    seed: Annotated[int, typer.Option(help="Seed of the design.")] = 0,
    resume: Annotated[bool, typer.Option(help="Continue a run that stopped.")] = False,
    settle: Annotated[
        str, typer.Option(help="'vision' or 'fixed:SECONDS' (the thesis: fixed:30).")
    ] = "vision",
    frames: Annotated[int, typer.Option(min=1, help="Frames stored per camera and pose.")] = 5,
    store: Annotated[
        str, typer.Option(help="'full' frames, or 'roi': only the region around the board.")
    ] = "full",
    dry_run: Annotated[
        bool,
        typer.Option(
            "--dry-run",
            help="Check the connections, one frame per camera and the design against the "
            "limits; move nothing and write nothing.",
        ),
    ] = False,
) -> None:
    """Drive the manipulator through a design and store images of every pose.

    Example: microcal acquire --rig sim --design random --poses 170 --out runs/a
    (first: microcal acquire --rig myrig.toml --out runs/a --dry-run)
    """
    from .devices.rig import open_rig
    from .formats.rig_file import load_rig

    if (
        not resume
        and not dry_run
        and ((out / "run.json").exists() or (out / "journal.jsonl").exists())
    ):
        raise InputError(
            f"{out}: already holds a run; use --resume to continue it or choose another --out"
        )
    rig_spec = load_rig(rig)
    settle_mode, fixed_s = _parse_settle(settle)
    if store not in ("full", "roi"):
        raise InputError(f"--store: expected 'full' or 'roi', got {store!r}")
    if resume and not (out / "run.json").exists():
        raise InputError(f"{out}: no run to resume (no run.json); start it without --resume")
    if resume and dry_run:
        raise InputError("--dry-run and --resume: choose one")
    with open_rig(rig_spec) as opened:
        _acquire_on(opened, rig, rig_spec, out, design, poses, seed, resume, settle, settle_mode,
                    fixed_s, frames, store, dry_run)  # fmt: skip


def _dry_run(opened: Any, d: FloatArray, design: str) -> None:
    from .procedures.acquisition import grab_retrying
    from .vision.detect import detect

    for what, text in opened.description.items():
        print(f"{what}: {text}")
    m = opened.manipulator
    p = m.position_um()
    print(
        f"manipulator at {', '.join(f'{a} {v:.3f}' for a, v in zip(m.axes, p, strict=True))} µm, "
        f"{'moving' if m.is_moving() else 'still'}; limits "
        + ", ".join(
            f"{a} [{lo:g}, {hi:g}]" for a, (lo, hi) in zip(m.axes, m.limits_um, strict=True)
        )
        + " µm"
    )
    for name, cam in opened.cameras.items():
        frame = grab_retrying(cam, retries=2)
        h, w = frame.shape[:2]
        if (w, h) != tuple(cam.sensor_size_px):
            raise InputError(
                f"camera {name}: frame is {w} x {h} px but the camera reports "
                f"{cam.sensor_size_px[0]} x {cam.sensor_size_px[1]}"
            )
        found = detect(frame, opened.board)
        board = "board found" if found.found else f"board not found ({found.reason})"
        print(
            f"camera {name}: {w} x {h} px, {frame.dtype}, mean {float(frame.mean()):.1f}; {board}"
        )
    print(f"design {design}: {len(d)} poses, all within the soft limits")
    print("dry run: nothing moved, nothing written")


def _acquire_on(
    opened: Any,
    rig: str,
    rig_spec: dict[str, Any],
    out: Path,
    design: str,
    poses: int,
    seed: int,
    resume: bool,
    settle: str,
    settle_mode: str,
    fixed_s: float,
    frames: int,
    store: str,
    dry_run: bool,
) -> None:
    import signal
    import sys as _sys

    from .formats.calibration_file import provenance
    from .formats.run_directory import RunWriter, read_commands
    from .kinematics.compensators import check_limits
    from .kinematics.designs import DESIGNS, check_design, make_design
    from .procedures.acquisition import AcquisitionConfig, RunStoppedError
    from .procedures.acquisition import acquire as run_acquisition
    from .thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

    board = opened.board
    manipulator = opened.manipulator
    if resume:
        writer = RunWriter.resume(out, rig_spec)
        pose_ids, d = read_commands(out)
    else:
        trajectories = _evaluation_trajectories()
        if design in DESIGNS:
            d = make_design(design, poses, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, seed)
        elif design in trajectories:
            d = trajectories[design]
        else:
            d = _read_command_file(Path(design))
        if design in trajectories:  # for evaluation: only the limits matter
            check_limits(d, manipulator.limits_um)
        else:
            check_design(d, manipulator.limits_um)
        if dry_run:
            _dry_run(opened, d, design)
            return
        manifest = {
            "rig": rig_spec,
            "target": board.spec,
            "cameras": list(opened.cameras),
            "design": {
                "kind": design if design in DESIGNS or design in trajectories else "file",
                "poses": len(d),
                "seed": seed,
            },
            "settle": settle,
            "frames_per_pose": frames,
            "provenance": provenance(command="acquire"),
        }
        writer = RunWriter.create(out, manifest, d)
        pose_ids = list(range(1, len(d) + 1))
    todo = writer.remaining(pose_ids)
    config = AcquisitionConfig(
        settle=settle_mode, fixed_s=fixed_s, frames_per_pose=frames, store_roi=store == "roi"
    )
    stop = {"requested": False}

    def request_stop(signum: int, _frame: object) -> None:
        stop["requested"] = True

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    failed: list[tuple[int, str]] = []
    settle_times: list[float] = []
    tty = _sys.stdout.isatty()
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    bar = Progress(
        TextColumn("acquiring"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeRemainingColumn(),
        disable=not tty,
    )
    task = bar.add_task("acquire", total=len(todo))

    def progress(done: int, total: int, record: dict[str, Any]) -> None:
        settle_times.append(float(record["settle_s"]))
        if record["status"] != "ok":
            failed.append((int(record["pose"]), str(record.get("reason", ""))))
        bar.update(task, completed=done)
        if not tty and (done % 10 == 0 or done == total):
            print(f"acquired {done}/{total} poses", flush=True)

    print(
        f"{'resuming' if resume else 'starting'} {out}: {len(todo)} of {len(pose_ids)} poses to do"
    )
    try:
        with bar:
            run_acquisition(
                manipulator,
                opened.cameras,
                opened.clock,
                d,
                todo,
                board,
                writer.store,
                config=config,
                should_stop=lambda: stop["requested"],
                temperature=opened.temperature,
                progress=progress,
            )
    except RunStoppedError as exc:
        raise InputError(
            f"run stopped ({exc}); {len(writer.done)} of {len(pose_ids)} poses stored; "
            f"resume with: microcal acquire --rig {rig} --out {out} --resume"
        ) from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    size_mb = writer.size_bytes() / 1e6
    mean_settle = float(np.mean(settle_times)) if settle_times else 0.0
    print(
        f"stored {len(writer.done)} of {len(pose_ids)} poses in {out} ({size_mb:.1f} MB); "
        f"mean settle {mean_settle:.2f} s ({settle})"
    )
    for pose, reason in failed:
        print(f"pose {pose} failed: {reason}")


def _fail(message: str) -> NoReturn:
    print(f"microcal: error: {message}", file=sys.stderr)
    sys.exit(2)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``microcal`` command: user errors end in one line and exit code 2."""
    app(args=argv)
