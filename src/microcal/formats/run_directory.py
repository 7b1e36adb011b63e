"""The run directory of an acquisition: commands, images, journal, and what is derived from them.

```
RUN_DIR/run.json              manifest (target spec, cameras, rig, design, software, created)
RUN_DIR/commands.csv          pose, dx_um, dy_um, dz_um
RUN_DIR/journal.jsonl         one line per pose acquired (append-only)
RUN_DIR/images/top_0001.tiff  one file per camera and pose (several pages = several frames)
RUN_DIR/measurements.csv      written by `microcal measure`
RUN_DIR/cameras.json          the cameras (the demo; --out of stereo-calibrate)
RUN_DIR/calibration.json      the models (the demo; --out of fit)
RUN_DIR/results.json          the test figures (the demo; --out of evaluate)
RUN_DIR/report.html           written by `microcal report` (and the demo)
```

:class:`RunDirectory` reads a run (:meth:`RunDirectory.open`); :class:`RunWriter` writes one
so that a crash loses at most the pose in progress (:meth:`RunDirectory.create`,
:meth:`RunDirectory.resume`).
"""

from __future__ import annotations

import json
import os
import re
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .._validation import FloatArray, excerpt, name_problem
from ..errors import FormatError, InputError
from .atomic import write_text_atomic
from .commands_csv import read_joint_csv, write_joint_csv
from .hashing import sha256_file
from .json_file import parse_schema, read_versioned_json
from .records import (
    MAX_FRAME_PIXELS,
    MAX_FRAME_SIDE_PX,
    MAX_FRAMES_PER_POSE,
    RUN_FORMAT,
    RUN_FORMATS,
    ImageRecord,
    JournalLine,
    RoiRecord,
    RunManifest,
)
from .safe_open import open_regular, read_regular_bytes

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from numpy.typing import NDArray

    from ..journal_record import JournalRecord
    from ..vision.measurement import PoseMeasurement

__all__ = [
    "HOLDS_A_RUN",
    "RUN_FILE_NAMES",
    "RUN_FORMAT",
    "RunDirectory",
    "RunWriter",
    "holds_run",
    "read_commands",
    "write_commands",
]

MANIFEST = "run.json"
COMMANDS = "commands.csv"
JOURNAL = "journal.jsonl"
IMAGES = "images"
MEASUREMENTS = "measurements.csv"
#: What a run directory may hold, in the order a run produces it ("images" is a folder).
RUN_FILE_NAMES = (
    MANIFEST,
    COMMANDS,
    JOURNAL,
    IMAGES,
    MEASUREMENTS,
    "cameras.json",
    "calibration.json",
    "results.json",
    "report.html",
)
IMAGE_SUFFIXES = (".tiff", ".tif", ".png", ".jpg", ".jpeg")
#: Where a resume keeps the images of poses it acquires again (``images/_set_aside/TIME/``).
SET_ASIDE = "_set_aside"


class RunDirectory:
    """The files of one run directory, read on demand (each may be missing).

    ``RunDirectory(path)`` takes a directory as it is (the report reads whatever it holds);
    :meth:`open` requires a run (a directory with ``commands.csv``).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._manifest: RunManifest | None = None
        self._manifest_read = False
        self._journal: dict[int, JournalLine] | None = None
        self._damage: list[DamagedLine] = []
        self._verified: set[str] = set()

    def __repr__(self) -> str:
        return f"RunDirectory({str(self.path)!r})"

    # --- opening, creating, resuming -----------------------------------------------------
    @classmethod
    def open(cls, path: str | os.PathLike[str], *, require_commands: bool = True) -> RunDirectory:
        """An existing run.

        ``require_commands=False`` defers the check for ``commands.csv`` to
        :meth:`commands` (same message), for a caller that checks its other inputs first.

        Raises
        ------
        InputError
            ``path`` is not a directory.
        FormatError
            It holds no ``commands.csv``.
        """
        p = Path(path)
        if not p.is_dir():
            raise InputError(f"{p}: not a directory (expected a run directory)")
        if require_commands and not (p / COMMANDS).is_file():
            raise FormatError(f"{p / COMMANDS}: no such file (is {p} a run directory?)")
        return cls(p)

    @classmethod
    def create(
        cls,
        path: str | os.PathLike[str],
        manifest: RunManifest | Mapping[str, object],
        d_um: FloatArray,
    ) -> RunWriter:
        """Start a new run: writes commands.csv and run.json (see :meth:`RunWriter.create`)."""
        return RunWriter.create(path, manifest, d_um)

    @classmethod
    def resume(cls, path: str | os.PathLike[str], rig: Mapping[str, object]) -> RunWriter:
        """Continue a run made with ``rig`` (see :meth:`RunWriter.resume`)."""
        return RunWriter.resume(path, rig)

    # --- what it holds ---------------------------------------------------------------------
    @property
    def manifest(self) -> RunManifest | None:
        """``run.json``, or None when the run has none."""
        if not self._manifest_read:
            path = self.path / MANIFEST
            if path.exists():
                raw = read_versioned_json(path, RUN_FORMATS)
                self._manifest = parse_schema(RunManifest, raw, path)
            self._manifest_read = True
        return self._manifest

    @property
    def target_spec(self) -> str | None:
        """The end-effector board's spec that run.json records (``chessboard:4x3:400``)."""
        manifest = self.manifest
        return manifest.target if manifest is not None else None

    @property
    def measurements_path(self) -> Path:
        """Where ``measurements.csv`` is (or goes)."""
        return self.path / MEASUREMENTS

    def commands(self) -> tuple[list[int], FloatArray]:
        """Pose numbers and joint commands (N, 3) µm from ``commands.csv``.

        Raises
        ------
        FormatError
            No such file, a malformed one (the message names the line), or one that differs
            from the commands the run began with (run.json records their SHA-256).
        """
        path = self.path / COMMANDS
        if not path.is_file():
            raise FormatError(f"{path}: no such file (is {self.path} a run directory?)")
        recorded = self.manifest.commands_sha256 if self.manifest is not None else None
        if recorded is not None and sha256_file(path) != recorded:
            raise FormatError(
                f"{path}: edited since the run began (its SHA-256 is not the one "
                f"{MANIFEST} records); restore the original commands"
            )
        poses, d = read_joint_csv(path, pose_column=True, error=FormatError, link_ok=False)
        assert poses is not None
        return poses, d

    def journal(self) -> dict[int, JournalLine]:
        """The journal's intact lines by pose, in the order acquired ({} without a journal).

        A damaged line (not JSON, not a journal line, a pose again) is left out and listed by
        :meth:`journal_damage`; the lines after it are kept.
        """
        if self._journal is None:
            read = _read_journal(self.path / JOURNAL)
            self._journal, self._damage = read.lines, read.damaged
        return self._journal

    def journal_damage(self) -> list[DamagedLine]:
        """The journal's damaged lines, in file order ([] when it has none)."""
        self.journal()
        return list(self._damage)

    def damage_note(self) -> str | None:
        """One line naming the damaged journal lines and their poses, or None."""
        damaged = self.journal_damage()
        if not damaged:
            return None
        described = "; ".join(d.describe() for d in damaged[:3])
        more = f" (and {len(damaged) - 3} more)" if len(damaged) > 3 else ""
        return f"{self.path / JOURNAL}: {described}{more}"

    def image_path(self, camera: str, pose: int) -> Path | None:
        """The image file of a camera at a pose (``images/CAMERA_0001.tiff``), if present.

        Raises
        ------
        FormatError
            ``camera`` is not a name (a path, ``..``): the file stays inside ``images/``.
        """
        problem = name_problem(camera)
        if problem is not None:
            raise FormatError(f"camera {problem}")
        stem = self.path / IMAGES / f"{camera}_{pose:04d}"
        for suffix in IMAGE_SUFFIXES:
            candidate = stem.with_suffix(suffix)
            if candidate.is_file():
                return candidate
        return None

    def frames(
        self, pose: int, camera: str, size_px: tuple[int, int] | None = None
    ) -> list[NDArray[np.generic]]:
        """The frames of one camera at one pose, each of the camera's full size.

        A stored region is pasted back into a full frame (filled with the region's median
        grey level) where the journal records one. ``size_px``: the camera's image size
        (width, height), when known; a file's frames and the full frame the journal records
        may not be larger, and both are bounded before anything is decoded or made
        (:func:`~microcal.formats.images.check_declared_size`).

        Raises
        ------
        FormatError
            ``acquisition failed: REASON`` for a pose whose acquisition failed, ``no image
            images/CAMERA_NNNN.tiff`` when the file is missing, an unreadable file; and in
            a run with a journal, a pose the journal does not hold, an image whose SHA-256
            or frame count is not the journal's.
        """
        from ..vision.roi import frames_from_region
        from .images import check_declared_size, read_frames

        journal = self.journal()
        line = journal.get(pose)
        if line is not None and line.failed:
            raise FormatError(f"acquisition failed: {line.reason or ''}")
        path = self.image_path(camera, pose)
        if path is None:
            raise FormatError(f"no image {IMAGES}/{camera}_{pose:04d}.tiff")
        image = line.images.get(camera) if line is not None else None
        if (self.path / JOURNAL).exists():
            self._verify(pose, camera, path, line, image)
        frames = read_frames(path, max_size_px=size_px)
        if image is not None and image.frames is not None and len(frames) != image.frames:
            raise FormatError(f"{path}: {len(frames)} frames, the journal records {image.frames}")
        if image is not None and image.roi is not None:
            (x0, y0), (w, h) = image.roi.offset_px, image.roi.full_size_px
            if any(x0 + f.shape[1] > w or y0 + f.shape[0] > h for f in frames):
                raise FormatError(
                    f"{path}: its region at ({x0}, {y0}) does not fit in the {w} x {h} frame "
                    f"the journal records (images.{camera}.full_size_px)"
                )
            where = f"{self.path / JOURNAL}: pose {pose}, camera {camera}"
            check_declared_size(where, image.roi.full_size_px, len(frames),
                                frames[0].dtype.itemsize, size_px)  # fmt: skip
            frames = frames_from_region(frames, image.roi.offset_px, image.roi.full_size_px)
        return frames

    def _verify(
        self,
        pose: int,
        camera: str,
        path: Path,
        line: JournalLine | None,
        image: ImageRecord | None,
    ) -> None:
        """An image is measured only as the journal recorded it (file and SHA-256)."""
        if line is None:
            damage = " (the journal has damaged lines: run acquire --resume to repair)"
            raise FormatError(
                "not in the journal, so its images cannot be verified"
                + (damage if self.journal_damage() else "")
            )
        if image is None:
            raise FormatError(f"the journal records no image of camera {camera!r}")
        if self.path / image.file != path:
            raise FormatError(f"{path}: the journal records {image.file} instead")
        if image.file not in self._verified:
            if sha256_file(path) != image.sha256:
                raise FormatError(
                    f"{path}: changed since it was recorded (its SHA-256 is not the "
                    f"journal's); restore the original file"
                )
            self._verified.add(image.file)

    def journaled(self, key: str, poses: Sequence[int]) -> FloatArray | None:
        """A number each pose's journal line records under ``key``, (N,); NaN where a pose has
        none, None when no pose has one.

        Raises
        ------
        FormatError
            A value that is not a number.
        """
        journal = self.journal()
        out = np.full(len(poses), np.nan)
        for k, pose in enumerate(poses):
            line = journal.get(pose)
            value = line.get(key) if line is not None else None
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise FormatError(
                    f"{self.path / JOURNAL}: pose {pose}: {key} = {value!r} is not a number"
                )
            out[k] = float(value)
        return out if np.isfinite(out).any() else None

    def temperature_c(self, poses: Sequence[int]) -> FloatArray | None:
        """The journaled ambient temperature of each pose, °C, (N,): NaN where a pose has
        none, None when no pose has one."""
        return self.journaled("temperature_c", poses)

    def extra_inputs(self, poses: Sequence[int]) -> dict[str, FloatArray]:
        """Every extra input of the registry (:mod:`microcal.kinematics.extra_inputs`) that
        the journal records at some pose, by registry name, (N,) each, NaN where not recorded.
        """
        from ..kinematics.extra_inputs import EXTRA_INPUTS

        out = {}
        for name, entry in EXTRA_INPUTS.items():
            values = self.journaled(entry.column, poses)
            if values is not None:
                out[name] = values
        return out

    def write_measurements(
        self, poses: Sequence[int], d_um: FloatArray, results: Sequence[PoseMeasurement]
    ) -> Path:
        """Write ``measurements.csv`` from measured poses, with the journaled extra inputs
        (the temperature, when the rig recorded it); returns its path."""
        from .measurements import write_measurements

        return write_measurements(
            self.measurements_path,
            np.asarray(d_um, dtype=np.float64),
            np.array([r.p_um for r in results]).reshape(len(results), 3),
            std_um=np.array([r.std_um for r in results]).reshape(len(results), 3),
            status=[r.status for r in results],
            reason=[r.reason for r in results],
            extra=self.extra_inputs(poses),
            pose=list(poses),
        )

    def files(self) -> list[Path]:
        """The run's known files that exist, in the order a run produces them (images sorted)."""
        out: list[Path] = []
        for name in RUN_FILE_NAMES:
            path = self.path / name
            if name == IMAGES:
                if path.is_dir():
                    out += sorted(f for f in path.iterdir() if f.is_file())
            elif path.is_file():
                out.append(path)
        return out


#: Why a new run cannot go where a run already is (the same words before and after devices open).
HOLDS_A_RUN = "already holds a run; use --resume to continue it or choose another --out"


def holds_run(run_dir: str | os.PathLike[str]) -> bool:
    """True if the directory holds a run (its manifest or journal) that a new run would replace."""
    path = Path(run_dir)
    return (path / MANIFEST).exists() or (path / JOURNAL).exists()


def read_commands(run_dir: str | os.PathLike[str]) -> tuple[list[int], FloatArray]:
    """Pose numbers and joint commands (N, 3) µm of a run: ``RunDirectory(run_dir).commands()``."""
    return RunDirectory(run_dir).commands()


def write_commands(run_dir: str | os.PathLike[str], d_um: FloatArray) -> Path:
    """Write ``commands.csv`` (poses numbered from 1) atomically."""
    return write_joint_csv(Path(run_dir) / COMMANDS, d_um)


@dataclass(frozen=True)
class DamagedLine:
    """A journal line that cannot be used: its line number, why, and its pose if legible."""

    number: int
    reason: str
    pose: int | None = None

    def describe(self) -> str:
        """``line 7 (pose 7): not JSON``."""
        pose = f" (pose {self.pose})" if self.pose is not None else ""
        return f"line {self.number}{pose}: {self.reason}"


@dataclass
class _JournalRead:
    lines: dict[int, JournalLine] = field(default_factory=dict)
    good: list[bytes] = field(default_factory=list)  # the intact lines' bytes, in order
    damaged: list[DamagedLine] = field(default_factory=list)


_POSE_BYTES = re.compile(rb'"pose"\s*:\s*(\d{1,9})')
#: An image file's name in ``images/``: camera, pose (4 digits or more), suffix.
_IMAGE_NAME = re.compile(r"(.+)_(\d{4,9})(\.[A-Za-z]+)")


def _read_journal(path: Path) -> _JournalRead:
    """The journal's intact lines by pose and their bytes, and its damaged lines.

    A damaged line never hides the lines after it: each line stands alone.
    """
    out = _JournalRead()
    if not path.exists():
        return out
    try:
        data = read_regular_bytes(path)
    except OSError as exc:
        raise FormatError(f"{path}: cannot be read ({exc.strerror})") from None
    raws = data.split(b"\n")
    for number, raw in enumerate(raws, start=1):
        if not raw.strip():
            continue
        legible = _POSE_BYTES.search(raw)
        pose = int(legible.group(1)) if legible else None
        cut = number == len(raws)  # no line end: the write was cut by a stop
        try:
            record = json.loads(raw)
            line = parse_schema(JournalLine, record, f"{path}, line {number}")
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, ValueError):
            reason = "cut short by a stop" if cut else "not JSON (damaged)"
            out.damaged.append(DamagedLine(number, reason, pose))
            continue
        except FormatError as exc:
            reason = str(exc).rpartition(f"line {number}: ")[2]
            out.damaged.append(DamagedLine(number, reason, pose))
            continue
        check_journal_line(line, f"{path}, line {number}")
        if line.pose in out.lines:
            out.damaged.append(DamagedLine(number, f"pose {line.pose} again", line.pose))
            continue
        out.lines[line.pose] = line
        out.good.append(raw)
    return out


def check_journal_line(line: JournalLine, where: str) -> None:
    """Refuse a journal line that reaches outside its run or declares sizes beyond reason.

    Each camera is a name, its image is this pose's file in ``images/`` (nothing else is
    opened from a journal: no other folder, no ``..``, no absolute path), and a stored
    region's full frame and frame count are bounded before anything is allocated from them.

    Raises
    ------
    FormatError
        ``WHERE: images.CAMERA.KEY: problem``, with the fix.
    """
    fix = "restore the journal, or delete the line and resume to acquire the pose again"
    for cam, image in line.images.items():
        problem = name_problem(cam)
        if problem is not None:
            raise FormatError(f"{where}: images: camera {problem}; {fix}")
        key = f"{where}: images.{cam}"
        stem = f"{IMAGES}/{cam}_{line.pose:04d}"
        if not (image.file.startswith(stem) and image.file[len(stem) :] in IMAGE_SUFFIXES):
            raise FormatError(
                f"{key}.file: {excerpt(image.file)} is not this pose's image ({stem}.tiff); a "
                f"run's files stay inside it: {fix}"
            )
        if image.frames is not None and not 1 <= image.frames <= MAX_FRAMES_PER_POSE:
            raise FormatError(
                f"{key}.frames: {image.frames} (expected 1 to {MAX_FRAMES_PER_POSE}); {fix}"
            )
        if image.roi is not None:
            _check_region(image.roi, key, fix)


def _check_region(roi: RoiRecord, key: str, fix: str) -> None:
    """A stored region's offset and full frame: bounded before a frame is made of them."""
    (x0, y0), (w, h) = roi.offset_px, roi.full_size_px
    sides = 8 <= w <= MAX_FRAME_SIDE_PX and 8 <= h <= MAX_FRAME_SIDE_PX
    if not (sides and w * h <= MAX_FRAME_PIXELS):
        raise FormatError(
            f"{key}.full_size_px: {w} x {h} is not a camera's frame (each side 8 to "
            f"{MAX_FRAME_SIDE_PX} px, at most {MAX_FRAME_PIXELS} px in all); {fix}"
        )
    if not (0 <= x0 < w and 0 <= y0 < h):
        raise FormatError(f"{key}.offset_px: ({x0}, {y0}) is not inside the {w} x {h} frame; {fix}")


class RunWriter:
    """Writes a run directory so that a crash at any instant loses at most the pose in progress.

    Images are written to a temporary name and renamed; the journal line of a pose is
    appended, flushed and synced only after its images. On resume, every recorded image is
    checked against its SHA-256, a damaged journal line (one cut by a stop, or changed) is
    dropped and its pose acquired again (the intact lines after it are kept, the journal as
    it was is kept aside), temporary files a stop left are removed, and images without a
    journal line are moved aside (``images/_set_aside/TIME/``), never written over; each
    repair is listed in :attr:`repairs`.
    """

    def __init__(self, run_dir: str | os.PathLike[str], manifest: RunManifest) -> None:
        self.run_dir = Path(run_dir)
        self.manifest = manifest
        self.done: dict[int, JournalLine] = {}
        #: What resuming mended: damaged journal lines dropped, temporary files removed,
        #: images of poses acquired again kept aside.
        self.repairs: list[str] = []
        self._aside: Path | None = None

    # --- creating and resuming ---------------------------------------------------------
    @classmethod
    def create(
        cls,
        run_dir: str | os.PathLike[str],
        manifest: RunManifest | Mapping[str, object],
        d_um: FloatArray,
    ) -> RunWriter:
        """A new run: writes commands.csv, then run.json with the commands' SHA-256.

        ``manifest`` is run.json's object (without ``format`` and ``commands_sha256``, which
        the writer adds), validated before anything is written.

        Raises
        ------
        FormatError
            The directory already holds a run, or the manifest is malformed.
        """
        path = Path(run_dir)
        if holds_run(path):
            raise FormatError(f"{path}: {HOLDS_A_RUN}")
        body: dict[str, object] = dict(
            manifest.to_json() if isinstance(manifest, RunManifest) else manifest
        )
        body.pop("format", None)
        body.pop("commands_sha256", None)
        parse_schema(RunManifest, {"format": RUN_FORMAT, **body}, f"{path / MANIFEST} (manifest)")
        (path / IMAGES).mkdir(parents=True, exist_ok=True)
        write_commands(path, d_um)
        full = {"format": RUN_FORMAT, **body, "commands_sha256": sha256_file(path / COMMANDS)}
        write_text_atomic(path / MANIFEST, json.dumps(full, indent=1) + "\n")
        return cls(path, RunManifest.model_validate(full))

    @classmethod
    def resume(cls, run_dir: str | os.PathLike[str], rig: Mapping[str, object]) -> RunWriter:
        """Continue a run: it must come from the same rig (``rig``: its record, a spec's
        ``to_dict()``) and be unedited.

        Raises
        ------
        FormatError
            No run, another rig, commands.csv edited, or a recorded image missing or changed.
        """
        path = Path(run_dir)
        manifest = RunDirectory(path).manifest
        if manifest is None:
            raise FormatError(f"{path}: not a run directory of microcal (no {MANIFEST})")
        if manifest.rig != rig:
            raise FormatError(
                f"{path}: this run was made with another rig (its {MANIFEST} records other "
                "settings); resume it with that rig"
            )
        commands = path / COMMANDS
        if not commands.is_file():
            raise FormatError(f"{commands}: missing; restore it to resume this run")
        if sha256_file(commands) != manifest.commands_sha256:
            raise FormatError(f"{commands} was edited since the run began; refusing to resume")
        writer = cls(path, manifest)
        writer._read_journal()
        return writer

    def _read_journal(self) -> None:
        """Check the journal and its images, then mend what a stop left (see the class)."""
        path = self.run_dir / JOURNAL
        read = _read_journal(path)
        for pose, line in read.lines.items():
            for cam, image in line.images.items():
                file = self.run_dir / image.file  # inside images/: check_journal_line
                if not file.is_file() or sha256_file(file) != image.sha256:
                    raise FormatError(
                        f"{file}: missing or changed since it was recorded (camera {cam}, "
                        f"pose {pose}); restore it before resuming"
                    )
        self._remove_temporary_files()
        self.done = read.lines
        self._set_aside_unrecorded()
        for damaged in read.damaged:
            again = "" if damaged.pose in read.lines else "; its pose is acquired again"
            self.repairs.append(f"{path}: dropped {damaged.describe()}{again}")
        if read.damaged:
            kept = self._set_aside_folder() / JOURNAL
            kept.write_bytes(path.read_bytes())
            self.repairs.append(f"kept the journal as it was in {kept}")
            # Rewrite the journal with its intact lines only, so appends stay well-formed.
            write_text_atomic(path, "".join(g.decode() + "\n" for g in read.good))

    def _remove_temporary_files(self) -> None:
        """Files a stop left while being written (``.NAME.XXXX.tmp``: see ``atomic.py``)."""
        for folder in (self.run_dir, self.run_dir / IMAGES):
            if not folder.is_dir():
                continue
            for tmp in folder.glob(".*.tmp"):
                if tmp.is_file() and not tmp.is_symlink():
                    tmp.unlink()
                    self.repairs.append(f"removed {tmp}, left by a stop while it was written")

    def _set_aside_unrecorded(self) -> None:
        """Move the image files of poses the journal does not hold (a damaged line, a stop
        between a pose's images and its line) aside: acquiring the pose again never writes
        over a file."""
        folder = self.run_dir / IMAGES
        if not folder.is_dir():
            return
        loose: dict[Path, int] = {}
        for file in sorted(folder.iterdir()):
            named = _IMAGE_NAME.fullmatch(file.name)
            if named is None or named.group(3).lower() not in IMAGE_SUFFIXES:
                continue
            pose = int(named.group(2))
            if pose not in self.done and not stat.S_ISDIR(file.lstat().st_mode):
                loose[file] = pose
        if loose:
            self._move_aside(list(loose), sorted(set(loose.values())))

    def _set_aside_folder(self) -> Path:
        """This writer's folder of files kept aside (``images/_set_aside/TIME``), made once."""
        if self._aside is None:
            stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
            base = self.run_dir / IMAGES / SET_ASIDE
            base.mkdir(parents=True, exist_ok=True)
            for n in range(1, 1000):
                folder = base / (stamp if n == 1 else f"{stamp}-{n}")
                try:
                    folder.mkdir()
                except FileExistsError:
                    continue
                self._aside = folder
                break
            else:
                raise FormatError(f"{base}: cannot make a folder to keep images aside in")
        return self._aside

    def _move_aside(self, files: list[Path], poses: list[int]) -> None:
        """Move ``files`` (the images of ``poses``) into the set-aside folder, and say so."""
        folder = self._set_aside_folder()
        for file in files:
            os.rename(file, folder / file.name)
        shown = ", ".join(map(str, poses[:5])) + (", ..." if len(poses) > 5 else "")
        self.repairs.append(
            f"kept {len(files)} image file(s) of pose(s) {shown}, which the journal does not "
            f"record, aside in {folder}; the pose(s) are acquired again"
        )

    # --- writing -------------------------------------------------------------------------
    def store(
        self, pose: int, frames: Mapping[str, Sequence[NDArray[np.generic]]], record: JournalRecord
    ) -> None:
        """Write a pose's images, then append its journal line (synced).

        The line is ``record``'s (:meth:`~microcal.journal_record.JournalRecord.to_json`) with
        its images; the region each camera's frames hold (``record.roi_px``: the region's
        offset and the full frame's size) is recorded with that camera's image.
        """
        from .images import write_tiff

        images: dict[str, ImageRecord] = {}
        for cam, cam_frames in frames.items():
            problem = name_problem(cam)
            if problem is not None:
                raise FormatError(f"camera {problem}")
            rel = f"{IMAGES}/{cam}_{pose:04d}.tiff"
            if os.path.lexists(self.run_dir / rel):  # never written over: kept, and said so
                self._move_aside([self.run_dir / rel], [pose])
            write_tiff(self.run_dir / rel, list(cam_frames))
            roi = record.roi_px.get(cam)
            images[cam] = ImageRecord(
                file=rel,
                sha256=sha256_file(self.run_dir / rel),
                frames=len(cam_frames),
                roi=None if roi is None else RoiRecord.from_roi_px(roi),
            )
        data = record.to_json() | {
            "images": {cam: image.to_json() for cam, image in images.items()}
        }
        line = json.dumps(data, allow_nan=False)
        journal_line = parse_schema(JournalLine, data, f"journal line of pose {pose}")
        append = os.O_WRONLY | os.O_APPEND | os.O_CREAT
        with os.fdopen(open_regular(self.run_dir / JOURNAL, append), "a", encoding="utf-8") as fh:
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        self.done[pose] = journal_line

    def remaining(self, poses: list[int]) -> list[int]:
        """The poses not yet in the journal, in order."""
        return [p for p in poses if p not in self.done]

    def size_bytes(self) -> int:
        """Bytes the run's files take."""
        return sum(f.stat().st_size for f in self.run_dir.rglob("*") if f.is_file())
