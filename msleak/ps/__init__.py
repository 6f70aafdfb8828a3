"""Stokes power spectra from Measurement Sets or image cubes (docs/science.md sections 5, 6).

The flow is ``grid -> transform -> ps``:

:mod:`msleak.ps.gridding`   uv grids and gridders (nearest cell; w-corrected via ducc0)
:mod:`msleak.ps.image`      image cube -> uv cells (unit conversion, spatial FFT)
:mod:`msleak.ps.delay`      spectral windows and the delay transform
:mod:`msleak.ps.binning`    cylindrical, spherical and 1D averages
:mod:`msleak.ps.cosmology`  k_perp, k_par, wedge slopes, Jy^2 -> mK^2 Mpc^3
:mod:`msleak.ps.grid`       MS or images -> uvcube product (``msleak.grid``)
:mod:`msleak.ps.grid_tasks` MS checks and chunk tasks of the grid
:mod:`msleak.ps.fitscube`   FITS image cubes -> uvcube product
:mod:`msleak.ps.transform`  uvcube -> delay product (``msleak.transform``)
:mod:`msleak.ps.power`      delay product -> ps product (``msleak.power_spectrum``)
"""

from __future__ import annotations

__all__: list[str] = []
