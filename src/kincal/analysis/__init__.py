"""Identifiability (rank, gauge, named null-space directions) and uncertainty of calibration problems."""

from kincal.analysis.covariance import correlated_pairs, covariance
from kincal.analysis.identifiability import Direction, Identifiability, analyse, select_columns

__all__ = ["Direction", "Identifiability", "analyse", "correlated_pairs", "covariance", "select_columns"]
