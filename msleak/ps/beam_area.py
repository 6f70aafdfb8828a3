"""The primary-beam area Omega of the cosmological normalisation, from a beam model's
Jones matrices (read from the MS by :func:`msleak.verbs.grid_tasks.ms_beam_area`).

``Omega = int A(l, m)^2 R(l, m)^2 dl dm / n`` where A is the station power beam normalised
to the phase centre (the mean over stations of M00 = (|Jxx|^2 + |Jxy|^2 + |Jyx|^2 +
|Jyy|^2) / 2 of the beam model, at the band centre and the middle of the observation) and
R the gridder's amplitude response (:func:`msleak.ps.gridding.gridder_response`). The
integral is a sum on a SIN grid wide enough that A R is negligible at its edge.
"""

from __future__ import annotations

import numpy as np

from msleak.ps.gridding import gridder_response

__all__ = ["beam_area_from_power", "beam_area_from_jones", "BEAM_AREA_MODELS"]

#: ``beam_area_model`` choices: auto (everybeam when the MS has the LOFAR tables, else
#: dipole; chosen by msleak.verbs.grid), a beam model of msleak.beam, or the analytic Airy
#: disc of a cell-wide station (msleak.ps.gridding.beam_area_model)
BEAM_AREA_MODELS = ("auto", "everybeam", "dipole", "airy")


def beam_area_from_power(power: np.ndarray, response: np.ndarray, l: np.ndarray,
                         m: np.ndarray) -> float:
    """``sum A^2 R^2 dl dm / n`` on a regular (m, l) grid; ``power`` (m, l) is A, already
    normalised to 1 at the phase centre; ``l``, ``m`` (npix,) direction cosines."""
    ll, mm = np.meshgrid(l, m)
    n = np.sqrt(np.clip(1.0 - ll ** 2 - mm ** 2, 1e-12, None))
    step = (l[1] - l[0]) * (m[1] - m[0])
    return float(np.sum((power * response) ** 2 / n) * step)


def beam_area_from_jones(jones: np.ndarray, centre: np.ndarray, l_deg: np.ndarray,
                         m_deg: np.ndarray, gridder: str, cell: float) -> float | None:
    """Omega (sr) from a beam model's Jones matrices at one time and frequency: ``jones``
    (station, 1, 1, m x l, 2, 2) on the SIN grid of ``l_deg``, ``m_deg`` (degrees) and
    ``centre`` (station, 1, 1, 2, 2) at the phase centre; A is the mean over stations of
    M00, normalised to the phase centre, R the ``gridder``'s response for ``cell``.
    None when the beam is zero at the phase centre."""
    power = 0.5 * np.sum(np.abs(jones[:, 0, 0]) ** 2, axis=(-2, -1)).mean(axis=0)
    power0 = 0.5 * np.sum(np.abs(centre[:, 0, 0]) ** 2, axis=(-2, -1)).mean()
    if not power0 > 0:
        return None
    a = (power / power0).reshape(np.size(m_deg), np.size(l_deg))
    l, m = np.sin(np.radians(l_deg)), np.sin(np.radians(m_deg))
    ll, mm = np.meshgrid(l, m)
    return beam_area_from_power(a, gridder_response(gridder, ll, mm, cell), l, m)
