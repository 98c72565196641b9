"""Sparse correspondences between target and source, by an escalation ladder: plain SIFT first,
costlier matching only when its verified geometry is weak (see :mod:`geofill.match.ladder`)."""

from .features import to_gray_u8
from .ladder import MIN_MATCHES_FOR_F, ROBUST_METHODS, RUNGS, Matches, RungReport, match_pair

__all__ = [
    "MIN_MATCHES_FOR_F",
    "ROBUST_METHODS",
    "RUNGS",
    "Matches",
    "RungReport",
    "match_pair",
    "to_gray_u8",
]
