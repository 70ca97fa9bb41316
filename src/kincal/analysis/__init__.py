"""Identifiability (rank, gauge, named null-space directions), uncertainty of calibration problems, and the
predicted accuracy of a calibrated model at new configurations."""

from kincal.analysis.covariance import correlated_pairs, covariance
from kincal.analysis.identifiability import Direction, Identifiability, analyse, select_columns
from kincal.analysis.prediction import Prediction, predicted_accuracy, validation_predictions

__all__ = ["Direction", "Identifiability", "Prediction", "analyse", "correlated_pairs", "covariance",
           "predicted_accuracy", "select_columns", "validation_predictions"]
