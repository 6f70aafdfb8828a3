"""Stokes power spectra on arrays (docs/science.md sections 5, 6); the verbs ``grid``,
``transform`` and ``power_spectrum`` that read and write them are :mod:`msleak.verbs`.

:mod:`msleak.ps.gridding`   uv grids and gridders (nearest cell; w-corrected via ducc0)
:mod:`msleak.ps.chunks`     the chunk tasks' rows, weights and memory model
:mod:`msleak.ps.uvcube`     gridded arrays -> uvcube Dataset
:mod:`msleak.ps.image`      image cube -> uv cells (unit conversion, spatial FFT)
:mod:`msleak.ps.beam_area`  Omega from a beam model's Jones matrices
:mod:`msleak.ps.delay`      spectral windows, the delay transform, the delay Dataset
:mod:`msleak.ps.binning`    cylindrical, spherical and 1D averages
:mod:`msleak.ps.spectra`    the power of the voxels and the ps Dataset
:mod:`msleak.ps.cosmology`  k_perp, k_par, wedge slopes, Jy^2 -> mK^2 Mpc^3
"""

from __future__ import annotations

__all__: list[str] = []
