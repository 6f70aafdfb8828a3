"""The primary-beam area Omega of the cosmological normalisation, from an MS's beam model.

``Omega = int A(l, m)^2 R(l, m)^2 dl dm / n`` where A is the station power beam normalised
to the phase centre (the mean over stations of M00 = (|Jxx|^2 + |Jxy|^2 + |Jyx|^2 +
|Jyy|^2) / 2 of the beam model, at the band centre and the middle of the observation) and
R the gridder's amplitude response (:func:`msleak.ps.gridding.gridder_response`). The
integral is a sum on a SIN grid wide enough that A R is negligible at its edge.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from msleak.adapters.beams import load_beam
from msleak.beam.maps import sin_grid
from msleak.errors import BeamUnavailable, InputError
from msleak.io import ms as msio
from msleak.ps.gridding import gridder_response

__all__ = ["beam_area_from_power", "ms_beam_area", "BEAM_AREA_MODELS"]

log = logging.getLogger(__name__)

#: ``--beam-area-model`` choices: auto (everybeam when the MS has the LOFAR tables, else
#: dipole; chosen by msleak.ps.grid), a beam model of msleak.beam, or the analytic Airy
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


def ms_beam_area(ms: str | Path, *, model: str, gridder: str, cell: float,
                 freq_hz: float | None = None, field_id: int = 0, ddid: int = 0,
                 half_width_deg: float = 12.0, npix: int = 97) -> tuple[float, str]:
    """Omega (sr) from the beam model of ``ms`` and a description of how it was made.

    The beam is that of the stations in the rows of ``field_id`` and ``ddid`` (the rows
    grid reads) about that field's phase centre. ``freq_hz``: where to evaluate it (default
    the middle channel of ``ddid``; grid passes the centre of its whole frequency axis, so
    several subband MSs give one Omega).

    Raises
    ------
    InputError
        Also when the model cannot describe the MS; the message then names grid's options.
    """
    if model not in ("everybeam", "dipole"):
        raise InputError(f"beam-area model {model!r} is not one read from the MS")
    field = msio.read_fields(ms)[field_id]
    times = msio.read_times(ms, field_id=field_id, ddid=ddid)
    if times.size == 0:
        raise InputError(f"{ms}: no rows, so no time at which to evaluate the beam")
    spw_id = msio.read_data_descriptions(ms)[ddid][0]
    freq = msio.read_spectral_windows(ms)[spw_id].freq
    t_mid = times[times.size // 2]
    f_mid = float(freq[freq.size // 2]) if freq_hz is None else float(freq_hz)
    l_deg, m_deg, ra, dec = sin_grid(field.ra, field.dec, 2 * half_width_deg, npix)
    try:
        beam = load_beam(model, ms, field_id=field_id, ddid=ddid)
    except BeamUnavailable as err:
        others = "`--beam-area-model dipole`, " if model != "dipole" else ""
        raise BeamUnavailable(err.reason, setting=err.setting,
                              remedy=f"use {others}`--beam-area-model airy` or "
                                     "`--beam-area SR`") from err
    jones = beam.jones(np.array([t_mid]), np.array([f_mid]), ra.ravel(), dec.ravel())
    power = 0.5 * np.sum(np.abs(jones[:, 0, 0]) ** 2, axis=(-2, -1)).mean(axis=0)
    centre = beam.jones_centre(np.array([t_mid]), np.array([f_mid]))
    power0 = 0.5 * np.sum(np.abs(centre[:, 0, 0]) ** 2, axis=(-2, -1)).mean()
    if not power0 > 0:
        raise InputError(f"{ms}: the {model} beam is zero at the phase centre")
    a = (power / power0).reshape(ra.shape)
    l, m = np.sin(np.radians(l_deg)), np.sin(np.radians(m_deg))
    ll, mm = np.meshgrid(l, m)
    omega = beam_area_from_power(a, gridder_response(gridder, ll, mm, cell), l, m)
    how = (f"int A^2 R^2 dOmega: A the {model} station power beam of the MS (mean M00 over "
           f"stations at {f_mid / 1e6:.3f} MHz, mid-observation), R the gridder's response")
    log.info("beam area from the %s beam: %.3e sr", model, omega)
    return omega, how
