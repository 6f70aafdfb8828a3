"""Write a :class:`~msleak.sky.healpix.HealpixSky` as a pyradiosky SkyH5 file.

The file holds a healpix ``SkyModel`` (ICRS, the sky's ordering and pixels, ``spectral_type``
"full": one Stokes value per channel) that ``pyradiosky.SkyModel.from_file`` reads back;
Q and U keep msleak's (and pyradiosky's) IAU convention, referred to each pixel's celestial
North. pyradiosky is imported only here, when a file is written (the ``healpix`` extra).
docs/sky.md, "All-sky skies".
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

from msleak.errors import InputError
from msleak.io.products import refuse_existing
from msleak.sky.healpix import HealpixSky

__all__ = ["write_skyh5"]

#: astropy unit strings of the brightness units a HealpixSky carries
_UNITS = {"K": "K", "Jy/sr": "Jy/sr"}


def _pyradiosky():
    if importlib.util.find_spec("pyradiosky") is None:
        raise InputError("writing a SkyH5 sky needs the Python package pyradiosky: "
                         "pip install 'msleak[healpix]'")
    from pyradiosky import SkyModel

    return SkyModel


def write_skyh5(path: str | os.PathLike, sky: HealpixSky, *, history: str = "",
                overwrite: bool = False) -> Path:
    """Write ``sky`` to ``path`` (SkyH5), through a temporary name renamed at the end.

    Parameters
    ----------
    path : the file to write (``.skyh5`` by convention)
    sky : the HEALPix sky; its Stokes (4, nchan, npix) become pyradiosky's ``stokes`` in
        ``sky.unit`` with ``freq_array`` the channel frequencies (Hz)
    history : the file's ``history`` (what made the sky)
    overwrite : replace an existing file

    Returns
    -------
    The path written.
    """
    import astropy.units as u

    path = Path(path)
    refuse_existing(path, overwrite)
    if not path.parent.is_dir():
        raise InputError(f"the folder of {path} does not exist", param="output")
    SkyModel = _pyradiosky()
    model = SkyModel(component_type="healpix", nside=sky.nside, hpx_order=sky.order,
                     hpx_inds=sky.pixels, frame="icrs", spectral_type="full",
                     freq_array=sky.freq_hz * u.Hz,
                     stokes=sky.stokes * u.Unit(_UNITS[sky.unit]),
                     history=history or "msleak HEALPix sky")
    tmp = path.with_name(f".{path.name}.partial")
    try:
        model.write_skyh5(str(tmp), clobber=True)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
