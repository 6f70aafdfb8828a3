"""Polarization conventions shared by predict and grid.

Linear feeds (CORR_TYPE XX, XY, YX, YY = 9, 10, 11, 12)::

    I = (XX + YY) / 2     Q = (XX - YY) / 2     U = (XY + YX) / 2     V = (XY - YX) / (2i)
    B = [[I + Q, U + iV], [U - iV, I - Q]]

Circular feeds (CORR_TYPE RR, RL, LR, LL = 5, 6, 7, 8)::

    I = (RR + LL) / 2     V = (RR - LL) / 2     Q = (RL + LR) / 2     U = (RL - LR) / (2i)
    B = [[I + V, Q + iU], [Q - iU, I - V]]

This is the convention of DP3, OSKAR and CASA (I is the mean, not the sum, of the
parallel-hand correlations). P = Q + iU is the complex linear polarization.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from msleak.errors import InputError

__all__ = [
    "STOKES",
    "FeedType",
    "feed_type_from_corr_types",
    "stokes_to_correlations_matrix",
    "correlations_to_stokes_matrix",
    "stokes_to_correlations",
    "correlations_to_stokes",
    "STOKES_CONVENTION",
]

FeedType = Literal["linear", "circular"]

#: Stokes labels, in the order used by every msleak product (P = Q + iU last).
STOKES = ("I", "Q", "U", "V", "P")

STOKES_CONVENTION = (
    "I=(XX+YY)/2, Q=(XX-YY)/2, U=(XY+YX)/2, V=(XY-YX)/(2i) for linear feeds; "
    "I=(RR+LL)/2, V=(RR-LL)/2, Q=(RL+LR)/2, U=(RL-LR)/(2i) for circular feeds; P=Q+iU"
)

_LINEAR = (9, 10, 11, 12)
_CIRCULAR = (5, 6, 7, 8)

# rows: correlations (in CORR_TYPE order), columns: I, Q, U, V
_S_LINEAR = np.array([[1, 1, 0, 0],
                      [0, 0, 1, 1j],
                      [0, 0, 1, -1j],
                      [1, -1, 0, 0]], dtype=complex)
_S_CIRCULAR = np.array([[1, 0, 0, 1],
                        [0, 1, 1j, 0],
                        [0, 1, -1j, 0],
                        [1, 0, 0, -1]], dtype=complex)


def feed_type_from_corr_types(corr_types) -> FeedType:
    """Feed type from POLARIZATION::CORR_TYPE; only full-polarization linear or circular.

    Raises
    ------
    InputError
        For any other set of correlations (e.g. Stokes products or only XX, YY).
    """
    ct = tuple(int(c) for c in np.asarray(corr_types).ravel())
    if ct == _LINEAR:
        return "linear"
    if ct == _CIRCULAR:
        return "circular"
    raise InputError(
        f"unsupported CORR_TYPE {list(ct)}: msleak needs four correlations, "
        "XX,XY,YX,YY (9,10,11,12) or RR,RL,LR,LL (5,6,7,8)")


def stokes_to_correlations_matrix(feed: FeedType = "linear") -> np.ndarray:
    """The 4x4 matrix S with correlations = S @ (I, Q, U, V); shape (corr, stokes)."""
    if feed == "linear":
        return _S_LINEAR.copy()
    if feed == "circular":
        return _S_CIRCULAR.copy()
    raise InputError(f"unknown feed type {feed!r}: use 'linear' or 'circular'")


def correlations_to_stokes_matrix(feed: FeedType = "linear") -> np.ndarray:
    """The inverse of :func:`stokes_to_correlations_matrix`; shape (stokes, corr)."""
    return np.linalg.inv(stokes_to_correlations_matrix(feed))


def stokes_to_correlations(iquv: np.ndarray, feed: FeedType = "linear") -> np.ndarray:
    """Correlations (..., 4) from Stokes (..., 4) = (I, Q, U, V)."""
    return np.asarray(iquv) @ stokes_to_correlations_matrix(feed).T


def correlations_to_stokes(corr: np.ndarray, feed: FeedType = "linear") -> np.ndarray:
    """Stokes (..., 4) = (I, Q, U, V) from correlations (..., 4) in CORR_TYPE order."""
    return np.asarray(corr) @ correlations_to_stokes_matrix(feed).T
