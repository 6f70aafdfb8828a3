"""Stokes power spectra from Measurement Sets or image cubes (docs/science.md sections 5, 6).

The flow is ``grid -> transform -> ps``:

:mod:`msleak.ps.gridding`   uv grids and gridders (nearest cell; w-corrected via ducc0)
:mod:`msleak.ps.image`      image cube -> uv cells (unit conversion, spatial FFT)
:mod:`msleak.ps.delay`      spectral windows and the delay transform
:mod:`msleak.ps.binning`    cylindrical, spherical and 1D averages
:mod:`msleak.ps.cosmology`  k_perp, k_par, wedge slopes, Jy^2 -> mK^2 Mpc^3
:mod:`msleak.ps.uvcube`     MS -> uvcube product (chunked reads)
:mod:`msleak.ps.fitscube`   FITS image cubes -> uvcube product
:mod:`msleak.ps.spectra`    uvcube -> delay product -> ps product
"""

from __future__ import annotations

__all__ = ["grid_ms", "grid_image", "transform_uvcube", "power_spectrum"]


def __getattr__(name):  # lazy: keep `import msleak.ps` light
    if name == "grid_ms":
        from msleak.ps.uvcube import grid_ms
        return grid_ms
    if name == "grid_image":
        from msleak.ps.fitscube import grid_image
        return grid_image
    if name in ("transform_uvcube", "power_spectrum"):
        from msleak.ps import spectra
        return getattr(spectra, name)
    raise AttributeError(name)
