"""The all-sky sky verb (docs/sky.md, "All-sky skies"): :func:`make_allsky` generates the
polarized foreground on every HEALPix pixel and writes it as a pyradiosky SkyH5 file.
"""

from __future__ import annotations

import os

from msleak.adapters.skyh5 import write_skyh5
from msleak.errors import InputError
from msleak.io.products import call_record, refuse_existing
from msleak.sky.allsky import (BOX_DEG, CELL_DEG, FIELD_REFERENCE, AllSky, check_geometry,
                               generate_allsky, healpix_to_unit)
from msleak.sky.foreground import ForegroundParams
from msleak.sky.healpix import HEALPIX_UNITS

__all__ = ["make_allsky"]


def make_allsky(output: str | os.PathLike | None = None, *, nside: int,
                freq_min: float = 150e6, nchan: int = 50, chan_width: float = 195312.5,
                seed: int | None = None, units: str = "K",
                params: ForegroundParams | None = None, cell_deg: float = CELL_DEG,
                box_deg: float = BOX_DEG, overwrite: bool = False) -> AllSky:
    """Generate the diffuse polarized foreground (Q, U) on all ``12 nside^2`` HEALPix pixels
    (RING, ICRS) and write it to ``output`` (SkyH5); the options are those of
    ``msleak sky OUT.skyh5 --healpix NSIDE``.

    Parameters
    ----------
    output : SkyH5 file to write (None: return only)
    nside : HEALPix NSIDE, a power of 2
    freq_min, chan_width : Hz; channel i is centred at freq_min + i chan_width
    nchan : channels
    seed : random seed (None: fresh entropy, recorded in the file's history)
    units : "K" or "Jy/sr" (Rayleigh-Jeans)
    params : the physics (:class:`~msleak.sky.foreground.ForegroundParams`), as the flat
        cube's; ``p_rms_k`` is the rms of |P| over the whole sphere
    cell_deg : angle one transverse cell subtends (the flat cube's pixel) [0.3]
    box_deg : the largest transverse scale of the random fields (the flat cube's width) [15]
    overwrite : replace an existing ``output``

    Returns
    -------
    :class:`~msleak.sky.allsky.AllSky`: the sky in ``units`` (the values written), each
    pixel's total Faraday depth and the generator's record (``meta``).
    """
    command = call_record(make_allsky, dict(locals()))
    check_geometry(nside, cell_deg, box_deg)
    if units not in HEALPIX_UNITS:
        raise InputError(f"units {units!r} is not one of {', '.join(HEALPIX_UNITS)} for a "
                         "HEALPix sky", param="units")
    (params or ForegroundParams()).validate()
    refuse_existing(output, overwrite)
    result = generate_allsky(nside=nside, freq_min_hz=freq_min, nchan=nchan,
                             chan_width_hz=chan_width, seed=seed, params=params,
                             cell_deg=cell_deg, box_deg=box_deg,
                             field_reference=FIELD_REFERENCE)
    sky = healpix_to_unit(result.sky, units)
    result = AllSky(sky=sky, faraday_depth=result.faraday_depth, meta=result.meta)
    if output is not None:
        write_skyh5(output, sky, history=_history(command, result, params), overwrite=overwrite)
    return result


def _history(command: str, result: AllSky, params: ForegroundParams | None) -> str:
    """The SkyH5 history: what made the sky, its parameters and measured statistics."""
    from dataclasses import asdict

    from msleak import __version__

    physics = ", ".join(f"{k}={v}" for k, v in asdict(params or ForegroundParams()).items())
    stats = ", ".join(f"{k}={v}" for k, v in result.meta.items())
    return (f"msleak {__version__}: {command}\n"
            "msleak.sky.allsky all-sky foreground (Jelic et al. 2008/2010 model B on HEALPix "
            "RING, ICRS; Q, U referred to each pixel's celestial North, IAU)\n"
            f"parameters: {physics}\nrecord: {stats}\n")
