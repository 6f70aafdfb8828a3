"""Mueller matrices of beam Jones matrices, the polarized beam and the Stokes I leakage.

:func:`jones_to_mueller` maps (I, Q, U, V) of the sky to apparent Stokes for stations p
and q, M = S_feed^-1 (C J_p kron conj(C J_q)) S_linear (``S``, ``C`` from
:mod:`msleak.conventions`); it is the same for linear and circular feeds.
:func:`polarized_beam` is sqrt(M[1,1]^2 + M[2,2]^2), :func:`leakage` is
sqrt(M[0,1]^2 + M[0,2]^2) / M[0,0] (0-based, from the real part of M), :func:`to_db`
gives 10 log10 with a floor.

Derivation, the figures of merit and their frames: docs/beam.md ("Mueller matrices and
the maps") and docs/science.md section 4.
"""

from __future__ import annotations

import numpy as np

from msleak.conventions import FeedType, feed_basis_matrix, stokes_to_correlations_matrix

__all__ = ["jones_to_mueller", "polarized_beam", "polarized_beam_invariant", "leakage",
           "to_db", "DB_FLOOR"]

#: dB values are clipped below at this level (zero leakage at the phase centre).
DB_FLOOR = -100.0


def jones_to_mueller(jp: np.ndarray, jq: np.ndarray | None = None,
                     feed: FeedType = "linear") -> np.ndarray:
    """Mueller matrices (..., 4, 4) of Jones matrices (..., 2, 2).

    Parameters
    ----------
    jp : (..., 2, 2) complex array
        Station p: sky (North, East) basis to (X, Y) feed voltages.
    jq : (..., 2, 2) complex array, optional
        Station q (default: ``jp``, the auto-correlation Mueller matrix).
    feed : {'linear', 'circular'}
        The feeds whose correlations are formed (the Stokes-space result does not depend
        on it).
    """
    c = feed_basis_matrix(feed)
    jp = c @ np.asarray(jp)
    jq = jp if jq is None else c @ np.asarray(jq)
    kron = np.einsum("...ij,...kl->...ikjl", jp, np.conj(jq))
    kron = kron.reshape(*kron.shape[:-4], 4, 4)
    s_sky = stokes_to_correlations_matrix("linear")
    s_feed_inv = np.linalg.inv(stokes_to_correlations_matrix(feed))
    return s_feed_inv @ kron @ s_sky


def polarized_beam(mueller: np.ndarray) -> np.ndarray:
    """``sqrt(M[1,1]^2 + M[2,2]^2)`` (...) from Mueller matrices (..., 4, 4)."""
    m = np.real(mueller)
    return np.sqrt(m[..., 1, 1] ** 2 + m[..., 2, 2] ** 2)


def polarized_beam_invariant(mueller: np.ndarray) -> np.ndarray:
    """``sqrt(M11^2 + M12^2 + M21^2 + M22^2)`` (...): unchanged by a rotation of the Q, U frame.

    Equal to :func:`polarized_beam` when the Q, U block has no rotation; near a celestial
    pole, where the local (North, East) frame turns with position angle, it shows the beam
    without the ``cos 2 psi`` pattern of the frame rotation.
    """
    m = np.real(mueller)
    return np.sqrt(m[..., 1, 1] ** 2 + m[..., 1, 2] ** 2 + m[..., 2, 1] ** 2 + m[..., 2, 2] ** 2)


def leakage(mueller: np.ndarray) -> np.ndarray:
    """``sqrt(M[0,1]^2 + M[0,2]^2) / M[0,0]`` (...); NaN where ``M[0,0] = 0`` (no beam)."""
    m = np.real(mueller)
    num = np.sqrt(m[..., 0, 1] ** 2 + m[..., 0, 2] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(m[..., 0, 0] != 0, num / np.where(m[..., 0, 0] != 0, m[..., 0, 0], 1),
                        np.nan)


def to_db(x: np.ndarray, reference: float | np.ndarray = 1.0, floor: float = DB_FLOOR
          ) -> np.ndarray:
    """``10 log10(x / reference)`` clipped below at ``floor``; NaN stays NaN."""
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        db = 10 * np.log10(np.abs(x) / reference)
    return np.where(np.isnan(db), np.nan, np.maximum(db, floor))
