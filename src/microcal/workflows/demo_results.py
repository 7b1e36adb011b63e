"""The sections of a demo's results.json that every demo writes alike: the measurement's
error by truth, the models' validation, the oracle and the acquisition's poses (keys in
docs/formats.md)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

from .._validation import FloatArray
from ..journal_record import JournalRecord

__all__ = ["FittedDemo", "fit_sections"]


class FittedDemo(Protocol):
    """What a demo's result holds once its poses are measured and its models fitted."""

    @property
    def models(self) -> Mapping[str, Any]: ...  # name -> identification (its ``validation``)

    @property
    def oracle(self) -> Mapping[str, float]: ...

    @property
    def measurement_rms_um(self) -> float: ...

    @property
    def measurement_rms_axis_um(self) -> FloatArray: ...  # (3,)

    @property
    def mahalanobis_mean_sq(self) -> float: ...


def fit_sections(
    result: FittedDemo, records: Sequence[JournalRecord], acquisition: Mapping[str, object]
) -> dict[str, object]:
    """results.json's ``measurement``, ``models``, ``oracle`` and ``acquisition`` (poses,
    stored, then ``acquisition``'s own keys, then the failed poses with their reasons)."""
    axis_rms = result.measurement_rms_axis_um.tolist()
    return {
        "measurement": {"rms_error_um": result.measurement_rms_um,
                        "rms_error_axis_um": dict(zip("xyz", axis_rms, strict=True)),
                        "mahalanobis_mean_sq": result.mahalanobis_mean_sq},
        "models": {k: {"validation": v.validation} for k, v in result.models.items()},
        "oracle": {f"{k}_um": v for k, v in result.oracle.items()},
        "acquisition": {
            "poses": len(records),
            "stored": sum(r.status == "ok" for r in records),
            **acquisition,
            "failed": [{"pose": r.pose, "reason": r.reason or ""}
                       for r in records if r.status != "ok"],
        },
    }  # fmt: skip
