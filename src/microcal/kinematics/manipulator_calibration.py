"""The calibration of one manipulator: its identified model, validation figures and inverse."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..errors import DegenerateDataError, FormatError, InputError
from .compensators import Compensator
from .extra_inputs import default_extra_inputs
from .models import KinematicModel

__all__ = ["ManipulatorCalibration"]


@dataclass(frozen=True)
class ManipulatorCalibration:
    """The calibration of one manipulator: its model and the figures that validate it.

    ``validation`` is calibration.json's ``validation`` object of the model; ``extra`` the
    manipulator's other keys (``joint_range_um``, ``matrix_model``, ``matrix_validation``,
    ``device`` and any a newer microcal wrote), as JSON values, read by the properties below.
    """

    name: str
    model: KinematicModel
    validation: Mapping[str, object] = field(default_factory=dict)
    extra: Mapping[str, object] = field(default_factory=dict)

    def predict_um(self, u: ArrayLike) -> FloatArray:
        """Position in {G} (µm) for joint values (and further inputs), (N, 3).

        Parameters
        ----------
        u : (N, k) or (k,) float, or (N, j) or (j,) float
            Inputs in the order of the model's ``inputs`` (joints in µm first); or the joints
            alone, the extra inputs then taking their defaults (each approach direction +1,
            every joint arriving moving up; a model with a temperature input needs it given).

        Raises
        ------
        InputError
            Another number of columns, or joints alone for a model whose extra inputs have
            no default (the message names them).
        """
        m = self.model
        u_arr = np.asarray(u, dtype=np.float64)
        if m.extra_inputs and u_arr.shape[-1:] == (len(m.joints),):
            rows = np.atleast_2d(u_arr)
            extra = np.broadcast_to(
                default_extra_inputs(m.extra_inputs), (rows.shape[0], len(m.extra_inputs))
            )
            return m.predict_um(np.hstack([rows, extra]))
        return m.predict_um(u)

    @cached_property
    def matrix_model(self) -> KinematicModel | None:
        """The matrix model stored beside a polynomial one (for the matrix compensator;
        read on first use)."""
        data = self.extra.get("matrix_model")
        if data is None:
            return self.model if self.model.kind == "matrix" else None
        if not isinstance(data, Mapping):
            raise FormatError(f"matrix_model: expected a model's object, got {data!r}")
        return KinematicModel.from_dict(data)

    @property
    def matrix_validation(self) -> Mapping[str, object]:
        """The validation object of the matrix model kept beside a polynomial one ({} for
        none)."""
        value = self.extra.get("matrix_validation")
        return value if isinstance(value, Mapping) else {}

    @cached_property
    def compensator(self) -> Compensator:
        """The model prepared for inversion (built on first use)."""
        return Compensator(self.model)

    @property
    def joint_range_um(self) -> FloatArray | None:
        """(3, 2) range of the joints in the identification data, if recorded."""
        rng = self.extra.get("joint_range_um")
        return None if rng is None else np.asarray(rng, dtype=np.float64)

    def outside_joint_range_um(self, d_um: ArrayLike) -> FloatArray | None:
        """The (3, 2) range of :attr:`joint_range_um` when the joints ``d_um`` (3,) lie
        outside it (the model extrapolates there); None when inside or not recorded."""
        rng = self.joint_range_um
        d = np.asarray(d_um, dtype=np.float64)
        if rng is None or not np.any((d < rng[:, 0]) | (d > rng[:, 1])):
            return None
        return rng

    def joints_for(
        self,
        p_um: ArrayLike,
        *,
        extra: ArrayLike | None = None,
        limits_um: ArrayLike | None = None,
    ) -> FloatArray:
        """Joint commands (µm) that put the end-effector at ``p_um`` in {G}: the compensator.

        The matrix model is inverted exactly (Eq 4.16); a polynomial model is solved by the
        optimal compensator (Eq 4.17-4.19).

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Desired positions in {G}, µm.
        extra : float or (N, e) float, optional
            Values of the model's extra inputs (the temperature in °C), if it has any; left
            out, each approach direction is +1 (the joints arrive moving up, as a fixed
            approach from below makes them), and a model with other inputs asks for them.
        limits_um : (3, 2) float, optional
            Soft limits per joint; a target outside raises LimitError and nothing is returned.

        Returns
        -------
        d_um : (N, 3) float

        Raises
        ------
        DegenerateDataError
            A target for which the model has no solution (it did not converge).
        LimitError
            A target that needs joints outside ``limits_um``.
        """
        comp = self.compensator
        if limits_um is not None:
            comp = Compensator(self.model, limits_um)
        if self.model.kind == "matrix":
            return comp.linear(p_um, extra=extra)
        result = comp.solve(p_um, extra=extra)
        if not result.converged.all():
            bad = int(np.flatnonzero(~result.converged)[0])
            raise DegenerateDataError(
                f"{int((~result.converged).sum())} target(s) have no solution of the model "
                f"(first: row {bad}, residual {result.residual_um[bad]:.3g} µm); "
                f"is the target inside the calibrated workspace?"
            )
        return result.d_um

    @property
    def device(self) -> str:
        """The identity of the device it was made on (empty when not recorded)."""
        return str(self.extra.get("device") or "")

    def check_device(self, identity: str) -> None:
        """Refuse to drive a device other than the one this calibration was made on.

        Raises
        ------
        InputError
            Both identities are known and differ (the message gives both).
        """
        if self.device and identity and identity != self.device:
            raise InputError(
                f"manipulator {self.name!r} was calibrated on {self.device}, but the rig's "
                f"manipulator is {identity}; calibrate this device (acquire, measure, fit) or "
                "open the rig it was calibrated on (a command opens the simulator unless its "
                "--rig names a rig file)"
            )

    def to_dict(self) -> dict[str, object]:
        """The manipulator's object in calibration.json."""
        return {**self.extra, "model": self.model.to_dict(), "validation": self.validation}
