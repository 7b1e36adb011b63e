"""Kinematic models of a Cartesian micromanipulator: matrix (Eq 4.5) and polynomial (Eq 4.6-4.10).

A model maps inputs ``u`` (the joint values ``dx, dy, dz`` in µm, and optionally further
measured inputs such as the temperature ``T``) to the end-effector position in {G} (µm):
``p_axis = sum_a coef[axis, a] * term_a(u)`` for axis in x, y, z. Each axis has its own
subset of terms (after stepwise selection). The base position ``P_B`` of the thesis is the
constant term.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..errors import DegenerateDataError, FormatError, InputError
from .least_squares import check_design, fit_least_squares
from .stepwise import StepwiseResult, stepwise_fit
from .terms import (
    JOINTS,
    Term,
    design_matrix,
    matrix_terms,
    parse_term,
    polynomial_terms,
    terms_without,
)

__all__ = [
    "AXES",
    "KinematicModel",
    "check_inputs_move",
    "fit_matrix_model",
    "fit_model",
    "fit_polynomial_model",
    "held_from_limits",
]

#: Output axes of every model, in {G}.
AXES: tuple[str, ...] = ("x", "y", "z")
ModelKind = Literal["matrix", "polynomial"]


class _Generic:
    """A model with wave terms: evaluated term by term (the design matrix and its derivative)."""

    def __init__(self, model: KinematicModel) -> None:
        used = np.flatnonzero(model.selected.any(axis=0))
        self.index = {name: i for i, name in enumerate(model.inputs)}
        self.joints = model.joints
        self.terms = [model.terms[a] for a in used]
        self.coef = np.ascontiguousarray(model.coefficients[:, used])
        # each joint's derivative: (column, factor, term) triples, prepared once
        self.deriv = [
            [(col, c, d) for col, t in enumerate(self.terms) for c, d in t.derivative(joint)]
            for joint in model.joints
        ]

    def predict(self, u: FloatArray) -> FloatArray:
        X = np.empty((u.shape[0], len(self.terms)))
        for col, t in enumerate(self.terms):
            X[:, col] = t.value(u, self.index)
        out: FloatArray = X @ self.coef.T
        return out

    def jacobian(self, u: FloatArray) -> FloatArray:
        J = np.empty((u.shape[0], 3, len(self.joints)))
        for b, parts in enumerate(self.deriv):
            dX = np.zeros((u.shape[0], len(self.terms)))
            for col, c, d in parts:
                dX[:, col] += c * d.value(u, self.index)
            J[:, :, b] = dX @ self.coef.T
        return J


class _Compiled:
    """A model reduced to its selected terms as exponent tables, for fast evaluation.

    The value of every term is gathered from one table of powers of the inputs; the
    Jacobian uses the derivative polynomials (exponent lowered by one, coefficient times
    the exponent), prepared once. Points are processed in chunks so that temporaries stay
    small whatever N is.
    """

    CHUNK = 32768

    def __init__(self, model: KinematicModel) -> None:
        used = np.flatnonzero(model.selected.any(axis=0))
        index = {name: i for i, name in enumerate(model.inputs)}
        k = len(model.inputs)
        exps = np.zeros((used.size, k), dtype=np.intp)
        for row, a in enumerate(used):
            for name, power in model.terms[a].powers:
                exps[row, index[name]] = power
        self.k = k
        self.exps = exps
        self.coef = np.ascontiguousarray(model.coefficients[:, used])  # (3, m)
        self.max_exp = int(exps.max()) if exps.size else 0
        self.deriv: list[tuple[np.ndarray, FloatArray]] = []
        for j in model.joints:
            col = index[j]
            rows = np.flatnonzero(exps[:, col] > 0)
            lowered = exps[rows].copy()
            lowered[:, col] -= 1
            self.deriv.append((lowered, self.coef[:, rows] * exps[rows, col]))
        self.rows = np.arange(k)[None, :]

    def _table(self, u: FloatArray) -> FloatArray:
        T = np.empty((self.k, self.max_exp + 1, u.shape[0]))
        T[:, 0] = 1.0
        if self.max_exp >= 1:
            T[:, 1] = u.T
        for e in range(2, self.max_exp + 1):
            T[:, e] = T[:, e - 1] * T[:, 1]
        return T

    def _eval(self, T: FloatArray, exps: np.ndarray, coef: FloatArray) -> FloatArray:
        if exps.shape[0] == 0:
            return np.zeros((3, T.shape[2]))
        terms = T[self.rows.T, exps.T].prod(axis=0)  # (m, c)
        out: FloatArray = coef @ terms
        return out

    def predict(self, u: FloatArray) -> FloatArray:
        out = np.empty((u.shape[0], 3))
        for s in range(0, u.shape[0], self.CHUNK):
            T = self._table(u[s : s + self.CHUNK])
            out[s : s + self.CHUNK] = self._eval(T, self.exps, self.coef).T
        return out

    def jacobian(self, u: FloatArray) -> FloatArray:
        J = np.empty((u.shape[0], 3, len(self.deriv)))
        for s in range(0, u.shape[0], self.CHUNK):
            T = self._table(u[s : s + self.CHUNK])
            for b, (exps, coef) in enumerate(self.deriv):
                J[s : s + self.CHUNK, :, b] = self._eval(T, exps, coef).T
        return J


@dataclass(frozen=True, eq=False)
class KinematicModel:
    """A model linear in its coefficients, one row of coefficients per output axis.

    Attributes
    ----------
    kind : {"matrix", "polynomial"}
    inputs : tuple of str
        Names of the input columns (joints first, then further inputs such as ``T``).
    joints : tuple of str
        The inputs that are joint commands (a compensator solves for them).
    terms : tuple of Term
        The candidate terms (m of them).
    coefficients : (3, m) float
        Zero where a term is not selected for an axis.
    selected : (3, m) bool
    covariance : (3, m, m) float
        Covariance of each axis's coefficients (µm² per unit of the terms); zero rows and
        columns for unselected terms.
    selection : dict
        How the terms were chosen: ``{"method": "all" | "stepwise", "penter": ..., ...}``.
    held_um : dict of str -> float
        Joints the device holds still, each at its one value, µm: the axis a two-axis X-Y
        positioner lacks, kept as a joint so that commands keep the three columns
        ``dx, dy, dz``. No term uses a held joint; a compensator solves for the others and
        sets it to its value. Empty for a manipulator whose every joint moves.
    """

    kind: ModelKind
    inputs: tuple[str, ...]
    joints: tuple[str, ...]
    terms: tuple[Term, ...]
    coefficients: FloatArray
    selected: np.ndarray
    covariance: FloatArray
    selection: Mapping[str, object]
    held_um: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        m = len(self.terms)
        if self.coefficients.shape != (3, m) or self.selected.shape != (3, m):
            raise InputError(
                f"coefficients, selected: expected shape (3, {m}), got "
                f"{self.coefficients.shape} and {self.selected.shape}"
            )
        if self.covariance.shape != (3, m, m):
            raise InputError(
                f"covariance: expected shape (3, {m}, {m}), got {self.covariance.shape}"
            )
        missing = [j for j in self.joints if j not in self.inputs]
        if missing:
            raise InputError(f"joints {missing} are not among the inputs {list(self.inputs)}")
        for t in self.terms:
            unknown = [n for n in t.inputs if n not in self.inputs]
            if unknown:
                raise InputError(
                    f"term {t.name} uses {unknown}, not among the inputs {list(self.inputs)}"
                )
            held = [n for n in t.inputs if n in self.held_um]
            if held:
                raise InputError(f"term {t.name} uses the held joint(s) {held}")
        for name, value in self.held_um.items():
            if name not in self.joints or not np.isfinite(value):
                raise InputError(
                    f"held_um: expected joints among {list(self.joints)} with finite values, "
                    f"got {name!r}: {value!r}"
                )
        if len(self.held_um) == len(self.joints):
            raise InputError(f"held_um: every joint {list(self.joints)} is held; none moves")

    # --- evaluation ----------------------------------------------------------------------
    @property
    def n_parameters(self) -> int:
        """Number of selected coefficients over the three axes."""
        return int(self.selected.sum())

    @property
    def moving_joints(self) -> tuple[str, ...]:
        """The joints a compensator solves for: all but the held ones."""
        return tuple(j for j in self.joints if j not in self.held_um)

    @property
    def rest_um(self) -> FloatArray:
        """(j,) each joint's value where nothing moves it: a held joint's value, else 0."""
        return np.array([self.held_um.get(j, 0.0) for j in self.joints])

    @property
    def extra_inputs(self) -> tuple[str, ...]:
        """Inputs that are not joints (given, not solved for)."""
        return tuple(i for i in self.inputs if i not in self.joints)

    def _inputs(self, u: ArrayLike) -> FloatArray:
        return as_rows(u, "u", len(self.inputs))

    def predict_um(self, u: ArrayLike) -> FloatArray:
        """End-effector positions for the given inputs.

        Parameters
        ----------
        u : (N, k) or (k,) float
            Inputs in the order of :attr:`inputs` (joints in µm first).

        Returns
        -------
        p_um : (N, 3) float
            Positions in {G}, µm.
        """
        return self._compiled.predict(self._inputs(u))

    def jacobian(self, u: ArrayLike) -> FloatArray:
        """Derivative of the position with respect to the joints.

        Parameters
        ----------
        u : (N, k) or (k,) float

        Returns
        -------
        J : (N, 3, j) float
            ``J[n, axis, b] = d p_axis / d joint_b`` (µm per µm).
        """
        return self._compiled.jacobian(self._inputs(u))

    @cached_property
    def _compiled(self) -> _Compiled | _Generic:
        used = np.asarray(self.selected.any(axis=0), dtype=bool)
        if all(t.is_monomial for t, keep in zip(self.terms, used.tolist(), strict=True) if keep):
            return _Compiled(self)
        return _Generic(self)

    def prediction_std_um(self, u: ArrayLike) -> FloatArray:
        """Standard deviation of the prediction from the coefficients' uncertainty.

        Returns
        -------
        std_um : (N, 3) float
        """
        X = design_matrix(self._inputs(u), self.inputs, self.terms)
        var = np.einsum("nm,amk,nk->na", X, self.covariance, X)
        out: FloatArray = np.sqrt(np.maximum(var, 0.0))
        return out

    def prediction_covariance_um2(self, u: ArrayLike) -> FloatArray:
        """Covariance between the predictions at several inputs from the coefficients'
        uncertainty.

        One set of coefficients predicts every input, so their errors reach all the
        predictions alike: ``cov[a, i, j] = X_i Σ_a X_j^T`` (``X`` the terms at each input,
        ``Σ_a`` axis a's coefficient covariance). The axes' coefficients are fitted apart
        and their covariance between axes is not kept: none is given.

        Returns
        -------
        cov_um2 : (3, N, N) float
            Per axis; its diagonals are :meth:`prediction_std_um` squared.
        """
        X = design_matrix(self._inputs(u), self.inputs, self.terms)
        out: FloatArray = np.einsum("nm,amk,jk->anj", X, self.covariance, X)
        return out

    def axis_terms(self, axis: int) -> list[tuple[str, float, float]]:
        """(term name, coefficient, standard error) of the selected terms of one axis."""
        se = np.sqrt(np.maximum(np.diagonal(self.covariance[axis]), 0.0))
        return [
            (t.name, float(self.coefficients[axis, a]), float(se[a]))
            for a, t in enumerate(self.terms)
            if self.selected[axis, a]
        ]

    @property
    def R(self) -> FloatArray:
        """(3, j) coefficients of the linear joint terms (the matrix R of Eq 4.5)."""
        R = np.zeros((3, len(self.joints)))
        for a, t in enumerate(self.terms):
            if t.is_monomial and t.degree == 1 and t.inputs[0] in self.joints:
                R[:, self.joints.index(t.inputs[0])] = self.coefficients[:, a]
        return R

    @property
    def p_base_um(self) -> FloatArray:
        """(3,) the end-effector at zero inputs (P_B of Eq 4.5), µm: the constant term, or
        for a model with wave terms (not zero at zero inputs) the prediction there."""
        if not all(t.is_monomial for t in self.terms):
            out0: FloatArray = self.predict_um(np.zeros(len(self.inputs)))[0]
            return out0
        for a, t in enumerate(self.terms):
            if t.degree == 0:
                out: FloatArray = self.coefficients[:, a].copy()
                return out
        return np.zeros(3)

    # --- serialisation ---------------------------------------------------------------------
    def to_dict(self) -> dict[str, object]:
        """Plain JSON-ready dict (the ``model`` object of calibration.json)."""
        return {
            "kind": self.kind,
            "inputs": list(self.inputs),
            "joints": list(self.joints),
            "outputs": [f"{a}_um" for a in AXES],
            "terms": [t.name for t in self.terms],
            "selected": self.selected.tolist(),
            "coefficients": self.coefficients.tolist(),
            "covariance": self.covariance.tolist(),
            "selection": dict(self.selection),
            **({"held_joints_um": dict(self.held_um)} if self.held_um else {}),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> KinematicModel:
        """Inverse of :meth:`to_dict`; raises FormatError naming what is wrong."""
        try:
            terms = tuple(parse_term(t) for t in _names(data["terms"], "terms"))
            m = len(terms)
            coef = np.asarray(data["coefficients"], dtype=np.float64)
            sel = np.asarray(data["selected"], dtype=bool)
            cov = np.asarray(data["covariance"], dtype=np.float64)
            if coef.shape != (3, m) or sel.shape != (3, m) or cov.shape != (3, m, m):
                raise FormatError(
                    f"model: expected coefficients (3, {m}), selected (3, {m}) and covariance "
                    f"(3, {m}, {m}) for {m} terms, got {coef.shape}, {sel.shape}, {cov.shape}"
                )
            if not (np.all(np.isfinite(coef)) and np.all(np.isfinite(cov))):
                raise FormatError("model: coefficients and covariance must be finite numbers")
            kind = data["kind"]
            if kind not in ("matrix", "polynomial"):
                raise FormatError(f"model.kind: expected 'matrix' or 'polynomial', got {kind!r}")
            _check_unselected(terms, coef, sel, cov)
            selection = data.get("selection", {})
            if not isinstance(selection, Mapping):
                raise FormatError(f"model.selection: expected an object, got {selection!r}")
            return cls(
                kind=kind,
                inputs=tuple(_names(data["inputs"], "inputs")),
                joints=tuple(_names(data["joints"], "joints")),
                terms=terms,
                coefficients=coef,
                selected=sel,
                covariance=cov,
                selection=dict(selection),
                held_um=_held_record(data.get("held_joints_um", {})),
            )
        except KeyError as exc:
            raise FormatError(f"model: missing key {exc.args[0]!r}") from None
        except (AttributeError, InputError, TypeError, ValueError) as exc:
            if isinstance(exc, FormatError):
                raise
            raise FormatError(f"model: {exc}") from None


def _check_unselected(
    terms: tuple[Term, ...], coef: FloatArray, sel: np.ndarray, cov: FloatArray
) -> None:
    """Refuse a record whose unselected terms keep coefficients (the model would use them as
    if selected: a term selected on one axis is evaluated on all three) or whose variances
    are negative (a standard deviation below zero)."""
    stray = np.flatnonzero(np.any((coef != 0) & ~sel, axis=0))
    if stray.size:
        names = ", ".join(terms[a].name for a in stray[:6]) + (", ..." if stray.size > 6 else "")
        raise FormatError(
            f"model: the terms {names} are not selected but keep coefficients; microcal writes "
            f"0 there: fit the model again (or set them to 0, or select them)"
        )
    axis, term = np.nonzero(np.diagonal(cov, axis1=1, axis2=2) < 0)
    if axis.size:
        raise FormatError(
            f"model.covariance: the variance of {terms[term[0]].name} on axis "
            f"{AXES[axis[0]]} is negative (a standard deviation below zero); fit the model again"
        )


def _names(value: object, key: str) -> list[str]:
    """A list of names of a model's record (``terms``, ``inputs``, ``joints``)."""
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise FormatError(f"model.{key}: expected a list of names, got {value!r}")
    return [str(v) for v in value]


def _held_record(value: object) -> dict[str, float]:
    """``held_joints_um`` of a model's record: joint names to numbers (not booleans)."""
    if not isinstance(value, dict) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value.values()
    ):
        raise FormatError(f"held_joints_um: expected {{joint: µm}}, got {value!r}")
    return {str(k): float(v) for k, v in value.items()}


def held_from_limits(limits_um: ArrayLike) -> dict[str, float]:
    """The joints a device holds still, with their value (µm): those whose soft limits
    (3, 2) are one value, as a two-axis X-Y positioner's z (``devices.held_axes``)."""
    lim = as_array(limits_um, "limits_um", (len(JOINTS), 2))
    return {j: float(lim[k, 0]) for k, j in enumerate(JOINTS) if lim[k, 0] == lim[k, 1]}


def _inputs_and_targets(
    u: ArrayLike, p_um: ArrayLike, inputs: Sequence[str]
) -> tuple[FloatArray, FloatArray]:
    U = as_array(u, "u", (None, len(inputs)), finite=False)
    P = as_array(p_um, "p_um", (U.shape[0], 3), finite=False)
    for name, arr in (("u", U), ("p_um", P)):
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        if bad.size:
            rows = ", ".join(str(i) for i in bad[:5]) + (" ..." if bad.size > 5 else "")
            raise DegenerateDataError(
                f"{name}: {bad.size} sample(s) with NaN or infinite values (rows {rows}); "
                f"drop the failed poses before fitting"
            )
    return U, P


def check_inputs_move(U: FloatArray, inputs: Sequence[str], names: Sequence[str]) -> None:
    """Refuse inputs among ``names`` that have one value in every row of U (N, k)."""
    for j, name in enumerate(inputs):
        if name in names and U.shape[0] and np.ptp(U[:, j]) == 0:
            raise DegenerateDataError(
                f"input {name!r} has the same value in every sample: its effect cannot be "
                f"identified (move that axis over its range; a device without that axis, an "
                f"X-Y positioner, is fitted from its run directory, whose run.json says so)"
            )


def fit_model(
    u: ArrayLike,
    p_um: ArrayLike,
    terms: Sequence[Term],
    *,
    kind: ModelKind,
    inputs: Sequence[str] = JOINTS,
    joints: Sequence[str] = JOINTS,
    select: Literal["all", "stepwise"] = "all",
    penter: float = 0.05,
    premove: float = 0.10,
    held_um: dict[str, float] | None = None,
) -> KinematicModel:
    """Fit a model with the given terms to measured positions.

    Parameters
    ----------
    u : (N, k) float
        Inputs (joints in µm first, in the order of ``inputs``).
    p_um : (N, 3) float
        Measured end-effector positions in {G}, µm.
    terms : sequence of Term
        Candidate terms; the constant is always fitted (as the intercept in stepwise).
    select : {"all", "stepwise"}
        Fit every term, or select per axis by :func:`stepwise_fit`.
    held_um : dict of str -> float, optional
        Joints the device holds still (a two-axis positioner's missing axis) and their
        value: the terms that use them are left out.

    Raises
    ------
    DegenerateDataError
        Too few samples for the terms, an input that never changes, or a rank-deficient design.
    """
    inputs = tuple(inputs)
    held = dict(held_um or {})
    U, P = _inputs_and_targets(u, p_um, inputs)
    terms = terms_without(terms, held)
    check_inputs_move(U, inputs, [n for n in inputs if n not in held])
    if Term() not in terms:
        terms = (*terms, Term())
    names = [t.name for t in terms]
    X = design_matrix(U, inputs, terms)
    m = len(terms)
    n = U.shape[0]
    if n <= m:
        raise DegenerateDataError(
            f"fit: expected more samples than candidate terms, got {n} samples for {m} terms "
            f"per axis; acquire more poses or choose a smaller model"
        )
    check_design(X, names)
    const = names.index("1")
    coef = np.zeros((3, m))
    selected = np.zeros((3, m), dtype=bool)
    cov = np.zeros((3, m, m))
    steps: list[list[dict[str, object]]] = []
    for axis in range(3):
        if select == "stepwise":
            others = [a for a in range(m) if a != const]
            sw: StepwiseResult = stepwise_fit(X[:, others], P[:, axis], penter, premove)
            chosen = [others[i] for i in np.flatnonzero(sw.in_model)] + [const]
            steps.append(
                [
                    {"action": s.action, "term": names[others[s.column]], "pval": s.pval}
                    for s in sw.history
                ]
            )
        elif select == "all":
            chosen = list(range(m))
        else:
            raise InputError(f"select: expected 'all' or 'stepwise', got {select!r}")
        chosen.sort()
        fit = fit_least_squares(X[:, chosen], P[:, axis], [names[a] for a in chosen])
        coef[axis, chosen] = fit.coef
        selected[axis, chosen] = True
        cov[axis][np.ix_(chosen, chosen)] = fit.covariance
    selection: dict[str, object] = {"method": select, "n_samples": n}
    if select == "stepwise":
        selection |= {"penter": penter, "premove": premove, "history": steps}
    return KinematicModel(kind, inputs, tuple(joints), terms, coef, selected, cov, selection, held)


def fit_matrix_model(
    d_um: ArrayLike, p_um: ArrayLike, held_um: dict[str, float] | None = None
) -> KinematicModel:
    """The matrix model of Eq 4.5, ``p = R d + P_B``, by least squares (Eq 4.14).

    Parameters
    ----------
    d_um : (N, 3) float
        Joint commands dx, dy, dz, µm.
    p_um : (N, 3) float
        Measured positions in {G}, µm.
    held_um : dict of str -> float, optional
        Joints held still and their value (see :func:`fit_model`).
    """
    return fit_model(d_um, p_um, matrix_terms(), kind="matrix", held_um=held_um)


def fit_polynomial_model(
    u: ArrayLike,
    p_um: ArrayLike,
    *,
    select: Literal["all", "stepwise"] = "stepwise",
    penter: float = 0.05,
    premove: float = 0.10,
    degree: int = 2,
    extra: dict[str, int] | None = None,
    held_um: dict[str, float] | None = None,
) -> KinematicModel:
    """The polynomial model of Eq 4.6-4.10, terms selected stepwise by default.

    Parameters
    ----------
    u : (N, 3 + e) float
        Joint commands dx, dy, dz (µm), then the extra inputs in the order of ``extra``.
    p_um : (N, 3) float
    extra : dict, optional
        Further inputs and their highest power, e.g. ``{"T": 2}`` for T and T² (Eq 4.10).
    held_um : dict of str -> float, optional
        Joints held still and their value (see :func:`fit_model`).
    """
    extra = dict(extra or {})
    inputs = JOINTS + tuple(extra)
    terms = polynomial_terms(JOINTS, degree, extra)
    return fit_model(
        u,
        p_um,
        terms,
        kind="polynomial",
        inputs=inputs,
        select=select,
        penter=penter,
        premove=premove,
        held_um=held_um,
    )
