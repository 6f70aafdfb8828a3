"""Polarization conventions shared by predict and grid.

Linear feeds (CORR_TYPE XX, XY, YX, YY = 9, 10, 11, 12)::

    I = (XX + YY) / 2     Q = (XX - YY) / 2     U = (XY + YX) / 2     V = (XY - YX) / (2i)
    B = [[I + Q, U + iV], [U - iV, I - Q]]

Circular feeds (CORR_TYPE RR, RL, LR, LL = 5, 6, 7, 8)::

    I = (RR + LL) / 2     V = (RR - LL) / 2     Q = (RL + LR) / 2     U = (RL - LR) / (2i)
    B = [[I + V, Q + iU], [Q - iU, I - V]]

This is the convention of DP3, OSKAR and CASA (I is the mean, not the sum, of the
parallel-hand correlations). P = Q + iU is the complex linear polarization.

Circular feed voltages are ``(R, L) = C (X, Y)`` with ``C = [[1, i], [1, -i]] / sqrt(2)``
(:data:`LINEAR_TO_CIRCULAR_FEEDS`): the circular brightness matrix above is ``C B C^H`` of
the linear one.

A Measurement Set may store the four products of one feed type in any order (OVRO-LWA
writes XX, YY, XY, YX), or only the two parallel hands (XX, YY or RR, LL);
:func:`correlation_layout` says where each product sits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from msleak.errors import InputError

__all__ = [
    "STOKES",
    "FeedType",
    "CORR_NAMES",
    "CorrelationLayout",
    "correlation_layout",
    "feed_type_from_corr_types",
    "feed_basis_matrix",
    "LINEAR_TO_CIRCULAR_FEEDS",
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
#: casacore Stokes enumeration names of the correlation products
CORR_NAMES = {5: "RR", 6: "RL", 7: "LR", 8: "LL", 9: "XX", 10: "XY", 11: "YX", 12: "YY"}

#: (R, L) feed voltages = LINEAR_TO_CIRCULAR_FEEDS @ (X, Y) feed voltages
LINEAR_TO_CIRCULAR_FEEDS = np.array([[1, 1j], [1, -1j]]) / np.sqrt(2.0)

# rows: correlations (canonical order XX, XY, YX, YY / RR, RL, LR, LL), columns: I, Q, U, V
_S_LINEAR = np.array([[1, 1, 0, 0],
                      [0, 0, 1, 1j],
                      [0, 0, 1, -1j],
                      [1, -1, 0, 0]], dtype=complex)
_S_CIRCULAR = np.array([[1, 0, 0, 1],
                        [0, 1, 1j, 0],
                        [0, 1, -1j, 0],
                        [1, 0, 0, -1]], dtype=complex)


@dataclass(frozen=True)
class CorrelationLayout:
    """Where each correlation product sits on an MS's correlation axis.

    ``slots[k]`` is the index, in the canonical order XX, XY, YX, YY (or RR, RL, LR, LL),
    of the product the MS stores at position ``k``.
    """

    feed: FeedType
    slots: tuple[int, ...]

    @property
    def names(self) -> tuple[str, ...]:
        """The stored products in MS order, e.g. ('XX', 'YY', 'XY', 'YX')."""
        canon = _LINEAR if self.feed == "linear" else _CIRCULAR
        return tuple(CORR_NAMES[canon[k]] for k in self.slots)

    @property
    def full(self) -> bool:
        """True when all four products are stored."""
        return len(self.slots) == 4

    @property
    def stokes_missing(self) -> tuple[str, ...]:
        """Stokes labels the stored products cannot give (the cross hands are missing)."""
        if self.full:
            return ()
        return ("U", "V", "P") if self.feed == "linear" else ("Q", "U", "P")

    def to_canonical(self, data: np.ndarray) -> np.ndarray:
        """Correlations (..., 4) in canonical order from stored ones (..., n); a product the
        MS does not store is 0."""
        data = np.asarray(data)
        if self.slots == (0, 1, 2, 3):
            return data
        out = np.zeros(data.shape[:-1] + (4,), dtype=data.dtype)
        out[..., list(self.slots)] = data
        return out

    def from_canonical(self, corr: np.ndarray) -> np.ndarray:
        """The stored products (..., n) in MS order from canonical correlations (..., 4)."""
        corr = np.asarray(corr)
        return corr if self.slots == (0, 1, 2, 3) else corr[..., list(self.slots)]

    def __str__(self) -> str:
        return f"{self.feed} {','.join(self.names)}"


def correlation_layout(corr_types) -> CorrelationLayout:
    """The layout of POLARIZATION::CORR_TYPE: the four products of linear or circular feeds
    in any order, or their two parallel hands (XX, YY or RR, LL) in either order.

    Raises
    ------
    InputError
        For any other set of correlations (Stokes products, mixed feeds, one product, ...).
    """
    ct = tuple(int(c) for c in np.asarray(corr_types).ravel())
    for feed, canon in (("linear", _LINEAR), ("circular", _CIRCULAR)):
        allowed = (set(canon), {canon[0], canon[3]})
        if len(set(ct)) == len(ct) and set(ct) in allowed:
            return CorrelationLayout(feed, tuple(canon.index(c) for c in ct))
    known = {1: "I", 2: "Q", 3: "U", 4: "V", **CORR_NAMES}
    names = ",".join(known.get(c, str(c)) for c in ct)
    raise InputError(
        f"unsupported CORR_TYPE {list(ct)} ({names}): msleak needs the four correlations "
        "XX,XY,YX,YY (9-12) or RR,RL,LR,LL (5-8) in any order, or the two parallel hands "
        "XX,YY or RR,LL")


def feed_type_from_corr_types(corr_types) -> FeedType:
    """Feed type ('linear' or 'circular') of POLARIZATION::CORR_TYPE
    (:func:`correlation_layout`, which raises InputError for an unsupported set)."""
    return correlation_layout(corr_types).feed


def feed_basis_matrix(feed: FeedType = "linear") -> np.ndarray:
    """The 2x2 matrix taking (X, Y) feed voltages to the feeds' own: identity or
    :data:`LINEAR_TO_CIRCULAR_FEEDS`."""
    if feed == "linear":
        return np.eye(2, dtype=complex)
    if feed == "circular":
        return LINEAR_TO_CIRCULAR_FEEDS.copy()
    raise InputError(f"unknown feed type {feed!r}: use 'linear' or 'circular'")


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
