"""Kinematic models and their identification (pure math layer, thesis 4.1, 4.3, 5.2)."""

from .least_squares import LinearFit, fit_least_squares
from .models import AXES, KinematicModel, fit_matrix_model, fit_model, fit_polynomial_model
from .stepwise import StepwiseResult, StepwiseStep, stepwise_fit
from .terms import (
    JOINTS,
    Term,
    design_matrix,
    matrix_terms,
    parse_term,
    polynomial_terms,
)
from .validation import (
    CrossValidation,
    Validation,
    cross_validate,
    kfold_indices,
    prediction_errors,
    validate_split,
)

__all__ = [
    "AXES",
    "JOINTS",
    "CrossValidation",
    "KinematicModel",
    "LinearFit",
    "StepwiseResult",
    "StepwiseStep",
    "Term",
    "Validation",
    "cross_validate",
    "design_matrix",
    "fit_least_squares",
    "fit_matrix_model",
    "fit_model",
    "fit_polynomial_model",
    "kfold_indices",
    "matrix_terms",
    "parse_term",
    "polynomial_terms",
    "prediction_errors",
    "stepwise_fit",
    "validate_split",
]
