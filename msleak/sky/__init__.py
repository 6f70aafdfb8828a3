"""Sky models: diffuse polarized foreground cubes, cube cropping and re-centring, and
point-source skies (cube voxels or makesourcedb files) for predict.

Public API::

    SkyCube, generate_foreground_cube, ForegroundParams          cubes and the generator
    crop, recentre, convert_units, crop_npix_for_fov              cube operations
    PointSources, sources_from_cube, lmn                          point sources
    HealpixSky, healpix_sources                                   all-sky HEALPix skies
    burn_slab, polarized_brightness                               Faraday physics
"""

from msleak.sky.cube import (SkyCube, convert_units, crop, crop_npix_for_fov,
                             jansky_to_kelvin, kelvin_to_jansky, make_celestial_wcs,
                             pixel_directions, pixel_solid_angle, recentre)
from msleak.sky.faraday import burn_slab, polarized_brightness
from msleak.sky.healpix import HealpixSky, healpix_sources
from msleak.sky.foreground import ForegroundParams, generate_foreground_cube
from msleak.sky.sources import DEFAULT_RTOL, PointSources, lmn, sources_from_cube

__all__ = [
    "SkyCube", "ForegroundParams", "generate_foreground_cube", "crop", "recentre",
    "convert_units", "crop_npix_for_fov", "kelvin_to_jansky", "jansky_to_kelvin",
    "make_celestial_wcs", "pixel_directions", "pixel_solid_angle", "PointSources",
    "sources_from_cube", "lmn", "DEFAULT_RTOL", "burn_slab",
    "polarized_brightness", "HealpixSky", "healpix_sources",
]
