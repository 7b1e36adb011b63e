"""The run directory of an acquisition: commands, images, and what is derived from them.

```
RUN_DIR/run.json              manifest (target spec, cameras, rig, software, created)
RUN_DIR/commands.csv          pose, dx_um, dy_um, dz_um
RUN_DIR/images/top_0001.tiff  one file per camera and pose (several pages = several frames)
RUN_DIR/measurements.csv      written by `microcal measure`
```
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError
from .atomic import write_text_atomic

__all__ = [
    "RunWriter",
    "find_image",
    "read_commands",
    "read_journal",
    "read_manifest",
    "write_commands",
]

IMAGE_SUFFIXES = (".tiff", ".tif", ".png", ".jpg", ".jpeg")


def read_commands(run_dir: str | os.PathLike[str]) -> tuple[list[int], FloatArray]:
    """Pose numbers and joint commands (N, 3) µm from ``commands.csv``."""
    path = Path(run_dir) / "commands.csv"
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file (is {run_dir} a run directory?)") from None
    reader = csv.DictReader(io.StringIO(text))
    need = ["pose", "dx_um", "dy_um", "dz_um"]
    missing = [c for c in need if c not in (reader.fieldnames or [])]
    if missing:
        raise FormatError(f"{path}: missing column(s) {missing}; expected {need}")
    poses, rows = [], []
    for line, row in enumerate(reader, start=2):
        try:
            poses.append(int(row["pose"]))
            rows.append([float(row[c]) for c in need[1:]])
        except (TypeError, ValueError):
            raise FormatError(
                f"{path}, line {line}: expected a pose number and three numbers"
            ) from None
    if not rows:
        raise FormatError(f"{path}: no commands")
    if len(set(poses)) != len(poses):
        raise FormatError(f"{path}: a pose number appears twice")
    d = np.array(rows)
    if not np.all(np.isfinite(d)):
        raise FormatError(f"{path}: non-finite command")
    return poses, d


def write_commands(run_dir: str | os.PathLike[str], d_um: FloatArray) -> Path:
    """Write ``commands.csv`` (poses numbered from 1) atomically."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["pose", "dx_um", "dy_um", "dz_um"])
    for i, row in enumerate(np.asarray(d_um, dtype=np.float64), start=1):
        w.writerow([i, *(f"{v:.4f}" for v in row)])
    return write_text_atomic(Path(run_dir) / "commands.csv", out.getvalue())


def find_image(run_dir: str | os.PathLike[str], camera: str, pose: int) -> Path | None:
    """The image file of a camera at a pose (``images/CAMERA_0001.tiff``), if present."""
    stem = Path(run_dir) / "images" / f"{camera}_{pose:04d}"
    for suffix in IMAGE_SUFFIXES:
        candidate = stem.with_suffix(suffix)
        if candidate.is_file():
            return candidate
    return None


def read_manifest(run_dir: str | os.PathLike[str]) -> dict[str, object]:
    """``run.json`` as a dict, or {} when the run has none."""
    path = Path(run_dir) / "run.json"
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise FormatError(f"{path}: not a JSON file ({exc})") from None
    if not isinstance(data, dict):
        raise FormatError(f"{path}: expected a JSON object")
    return data


JOURNAL = "journal.jsonl"
MANIFEST = "run.json"
RUN_FORMAT = "microcal.run/1"


def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class RunWriter:
    """Writes a run directory so that a crash at any instant loses at most the pose in progress.

    Images are written to a temporary name and renamed; the journal line of a pose is
    appended, flushed and synced only after its images. On resume, a journal line cut by a
    crash is dropped, images without a journal line are overwritten, and every recorded image
    is checked against its SHA-256.
    """

    def __init__(self, run_dir: Path, manifest: dict[str, object]) -> None:
        self.run_dir = Path(run_dir)
        self.manifest = manifest
        self.done: dict[int, dict[str, object]] = {}

    # --- creating and resuming ---------------------------------------------------------
    @classmethod
    def create(
        cls, run_dir: str | os.PathLike[str], manifest: dict[str, object], d_um: FloatArray
    ) -> RunWriter:
        """A new run: refuses a directory that already holds one."""
        path = Path(run_dir)
        if (path / MANIFEST).exists() or (path / JOURNAL).exists():
            raise FormatError(
                f"{path}: already holds a run; use --resume to continue it or choose another --out"
            )
        (path / "images").mkdir(parents=True, exist_ok=True)
        write_commands(path, d_um)
        full = {"format": RUN_FORMAT, **manifest, "commands_sha256": _sha256(path / "commands.csv")}
        write_text_atomic(path / MANIFEST, json.dumps(full, indent=1) + "\n")
        return cls(path, full)

    @classmethod
    def resume(cls, run_dir: str | os.PathLike[str], rig: dict[str, object]) -> RunWriter:
        """Continue a run: it must come from the same rig and be unedited."""
        path = Path(run_dir)
        manifest = read_manifest(path)
        if manifest.get("format") != RUN_FORMAT:
            raise FormatError(f"{path}: not a run directory of microcal (no {MANIFEST})")
        if manifest.get("rig") != rig:
            raise FormatError(
                f"{path}: this run was made with another rig ({manifest.get('rig')}); "
                f"resume it with that rig"
            )
        if _sha256(path / "commands.csv") != manifest.get("commands_sha256"):
            raise FormatError(
                f"{path}/commands.csv was edited since the run began; refusing to resume"
            )
        writer = cls(path, manifest)
        writer._read_journal()
        return writer

    def _read_journal(self) -> None:
        path = self.run_dir / JOURNAL
        if not path.exists():
            return
        lines = path.read_bytes().split(b"\n")
        good: list[bytes] = []
        for line in lines:
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                break  # cut by a crash: everything after it is lost anyway
            pose = int(record["pose"])
            if pose in self.done:
                raise FormatError(f"{path}: pose {pose} appears twice; the journal was edited")
            for cam, image in (record.get("images") or {}).items():
                file = self.run_dir / image["file"]
                if not file.is_file() or _sha256(file) != image["sha256"]:
                    raise FormatError(
                        f"{file}: missing or changed since it was recorded "
                        f"(camera {cam}, pose {pose})"
                    )
            self.done[pose] = record
            good.append(line)
        # Rewrite the journal without a cut last line, so appends stay well-formed.
        write_text_atomic(path, "".join(g.decode() + "\n" for g in good))

    # --- writing -------------------------------------------------------------------------
    def store(self, pose: int, frames: dict[str, list[Any]], record: dict[str, Any]) -> None:
        """Write a pose's images, then append its journal line (synced)."""
        from .images import write_tiff

        images = {}
        rois = record.pop("roi_px", {})
        for cam, cam_frames in frames.items():
            rel = f"images/{cam}_{pose:04d}.tiff"
            write_tiff(self.run_dir / rel, cam_frames)
            images[cam] = {
                "file": rel,
                "sha256": _sha256(self.run_dir / rel),
                "frames": len(cam_frames),
            }
            if cam in rois:
                x0, y0, w, h = rois[cam]
                images[cam] |= {"offset_px": [x0, y0], "full_size_px": [w, h]}
        line = json.dumps({**record, "images": images}, allow_nan=False)
        with open(self.run_dir / JOURNAL, "a", encoding="utf-8") as fh:
            fh.write(line + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        self.done[pose] = record

    def remaining(self, poses: list[int]) -> list[int]:
        """The poses not yet in the journal, in order."""
        return [p for p in poses if p not in self.done]

    def size_bytes(self) -> int:
        """Bytes the run's files take."""
        return sum(f.stat().st_size for f in self.run_dir.rglob("*") if f.is_file())


def read_journal(run_dir: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The journal's records (a line cut by a crash is ignored)."""
    path = Path(run_dir) / JOURNAL
    if not path.exists():
        return []
    out = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break
    return out
