"""OpenCV's chessboard calibration at its best ``cornerSubPix`` half-window, for comparisons
made in the same test run as microcal's.

Corners: ``findChessboardCorners`` (default flags), else ``findChessboardCornersSB``; then
``cornerSubPix`` with each half-window 2..8 (EPS + COUNT 30 / 0.001). Mono: ``calibrateCamera``
with its default lens model on the views the camera found. Stereo: ``stereoCalibrate`` with
``CALIB_FIX_INTRINSIC`` (that half-window's mono intrinsics) on the views both found, the
second camera's corner list reversed in a view where the board was numbered from the other
end (the reversal that makes the disparities most uniform). The best of the half-windows is
taken for each figure, so the comparison is fair to OpenCV.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

HALF_WINDOWS = range(2, 9)
CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.001)


def _found(gray: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    ok, c = cv2.findChessboardCorners(gray, size)
    if not ok:
        ok, c = cv2.findChessboardCornersSB(gray, size)
    return c.reshape(-1, 1, 2).astype(np.float32) if ok else None


def _spread(a: np.ndarray, b: np.ndarray) -> float:
    d = (b - a).reshape(-1, 2)
    return float(np.sum((d - d.mean(axis=0)) ** 2))


class OpenCVReference:
    """OpenCV's figures for one set of images per camera (views matched by index)."""

    def __init__(self, files: Mapping[str, Sequence[Path]], size: tuple[int, int]) -> None:
        self.size = size
        self.grays = {c: [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in fs]
                      for c, fs in files.items()}  # fmt: skip
        self.raw = {c: [_found(g, size) for g in gs] for c, gs in self.grays.items()}
        obj = np.zeros((size[0] * size[1], 3), np.float32)
        obj[:, :2] = np.mgrid[0 : size[0], 0 : size[1]].T.reshape(-1, 2)
        self.obj = obj
        self.corners: dict[int, dict[str, list[np.ndarray | None]]] = {}
        self.mono: dict[int, dict[str, tuple[float, np.ndarray, np.ndarray]]] = {}
        for h in HALF_WINDOWS:
            self.corners[h] = {
                c: [None if r is None else
                    cv2.cornerSubPix(self.grays[c][i], r.copy(), (h, h), (-1, -1), CRITERIA)
                    for i, r in enumerate(raws)]
                for c, raws in self.raw.items()
            }  # fmt: skip
            self.mono[h] = {}
            for c, cs in self.corners[h].items():
                img = [q for q in cs if q is not None]
                shape = self.grays[c][0].shape[::-1]
                rms, K, dist, _, _ = cv2.calibrateCamera([obj] * len(img), img, shape, None, None)
                self.mono[h][c] = (float(rms), K, dist)

    def best_mono_rms_px(self, camera: str) -> tuple[float, int]:
        """The least mono RMS over the half-windows, and that half-window."""
        h = min(HALF_WINDOWS, key=lambda k: self.mono[k][camera][0])
        return self.mono[h][camera][0], h

    def stereo_rms_px(self, a: str, b: str, h: int) -> float:
        """Stereo RMS of cameras a and b with half-window h."""
        ca, cb = self.corners[h][a], self.corners[h][b]
        pairs = [(qa, qb) for qa, qb in zip(ca, cb, strict=True)
                 if qa is not None and qb is not None]  # fmt: skip
        pa, pb = [], []
        for qa, qb in pairs:
            pa.append(qa)
            pb.append(min((qb, qb[::-1].copy()), key=lambda q, qa=qa: _spread(qa, q)))
        _, Ka, da = self.mono[h][a]
        _, Kb, db = self.mono[h][b]
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-6)
        out = cv2.stereoCalibrate([self.obj] * len(pa), pa, pb, Ka, da, Kb, db,
                                  self.grays[a][0].shape[::-1], flags=cv2.CALIB_FIX_INTRINSIC,
                                  criteria=crit)  # fmt: skip
        return float(out[0])

    def best_stereo_rms_px(self, a: str, b: str) -> tuple[float, int]:
        """The least stereo RMS of cameras a and b over the half-windows, and that one."""
        rms = {h: self.stereo_rms_px(a, b, h) for h in HALF_WINDOWS}
        h = min(rms, key=lambda k: rms[k])
        return rms[h], h
