"""Identifiability (rank, gauge, exact symmetries, named null-space directions), uncertainty of calibration
problems, and the predicted accuracy of a calibrated model at new configurations."""

from kincal.analysis.columns import scatter_columns
from kincal.analysis.covariance import correlated_pairs, covariance
from kincal.analysis.identifiability import Direction, Identifiability, analyse, identify, select_columns
from kincal.analysis.linearization import Linearization
from kincal.analysis.prediction import Prediction, predicted_accuracy, validation_predictions

__all__ = ["Direction", "Identifiability", "Linearization", "Prediction", "analyse", "correlated_pairs",
           "covariance", "identify", "predicted_accuracy", "scatter_columns", "select_columns",
           "validation_predictions"]
