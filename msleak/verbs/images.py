"""uv cubes from FITS image cubes (``msleak grid --image``): the files, their units and
the uvcube product.

Accepted cubes (:func:`msleak.io.images.read_image_cube`): BUNIT ``Jy/beam`` (needs
BMAJ/BMIN or ``beam_fwhm_deg``), ``Jy/pixel``, ``K`` or ``mK``. Each file may hold one
Stokes parameter (no STOKES axis: ``stokes`` tells which) or several, and all the channels
or some (per-channel WSClean images are stacked in frequency order). docs/grid.md.
"""

from __future__ import annotations

import glob
import logging
import math
import os
import re
from typing import Sequence

import numpy as np
import xarray as xr

from msleak.errors import InputError
from msleak.io.images import read_image_cube
from msleak.ps.image import beam_solid_angle, crop_centre, image_to_uv, to_jy_per_pixel
from msleak.ps.uvcube import uvcube_dataset

__all__ = ["image_paths", "read_images", "grid_image"]

log = logging.getLogger(__name__)


def image_paths(image: str | os.PathLike | Sequence[str | os.PathLike]) -> list[str]:
    """The image files of ``image``: a path, a glob pattern or a sequence of them (each
    pattern expanded in sorted order).

    A pattern that matches WSClean's per-channel images (``NAME-0000-Q-image.fits``) and
    also its multi-frequency-synthesis images of the whole band (``NAME-MFS-Q-image.fits``,
    written with ``-channels-out``) keeps the per-channel ones only; files named
    explicitly are always kept.
    """
    items = [image] if isinstance(image, (str, os.PathLike)) else list(image)
    paths: list[str] = []
    for item in items:
        text = os.fspath(item)
        if not os.path.exists(text) and glob.has_magic(text):
            found = sorted(glob.glob(text))
            if not found:
                raise InputError(f"no file matches image {text!r}", param="image")
            channels = [p for p in found if not _is_wsclean_mfs(p)]
            if channels and len(channels) < len(found):
                log.info("--image %r: leaving out %d WSClean MFS image(s) of the whole band",
                         text, len(found) - len(channels))
                found = channels
            paths += found
        else:
            paths.append(text)
    if not paths:
        raise InputError("no image cube given")
    return paths


#: the end of a WSClean multi-frequency-synthesis file name: ``-MFS``, an optional
#: polarization (I, Q, U, V or a correlation such as XX, XYi) and the image type
_WSCLEAN_MFS = re.compile(r"-MFS(?:-(?:[IQUV]|[XYRL]{2}i?))?"
                          r"-(?:image|dirty|residual|first-residual|model|psf|beam(?:-\d+)?)"
                          r"(?:-pb)?\.fits$")


def _is_wsclean_mfs(path: str) -> bool:
    """Whether ``path`` is named as WSClean names a multi-frequency-synthesis image
    (``NAME-MFS-image.fits``, ``NAME-MFS-Q-image.fits``, ``NAME-MFS-psf.fits``, ...)."""
    return _WSCLEAN_MFS.search(os.path.basename(path)) is not None


def _same_pixels(info: dict, ref: dict) -> bool:
    shape = info["cube"][next(iter(info["cube"]))].shape[-2:]
    ref_shape = ref["cube"][next(iter(ref["cube"]))].shape[-2:]
    return (shape == ref_shape
            and all(math.isclose(info[k], ref[k], rel_tol=1e-9, abs_tol=1e-12)
                    for k in ("dl_x", "dl_y", "ra_deg", "dec_deg", "crpix_x", "crpix_y")))


def read_images(paths: Sequence[str], stokes: Sequence[str] = (),
                beam_fwhm_deg: float | None = None) -> tuple[dict, dict]:
    """Read image files into one Jy/pixel cube per Stokes parameter.

    Files may each hold all channels or some (e.g. one per channel); a Stokes parameter's
    channels are stacked in the order of their frequencies (from the FITS spectral axis).

    Returns
    -------
    cubes : {stokes: (chan, y, x) float, Jy/pixel}
    ref : the metadata of :func:`read_image_cube` of the first file, with ``freq`` the
        stacked frequency axis (Hz).
    """
    parts: dict[str, list] = {}
    ref = None
    for i, path in enumerate(paths):
        info = read_image_cube(path, stokes[i] if i < len(stokes) else None)
        ref = ref or info
        if not _same_pixels(info, ref):
            raise InputError(f"{path}: pixel grid (size, increments, reference pixel or "
                             f"direction) differs from {paths[0]}'s; give images of one grid")
        bmaj, bmin = info["bmaj_deg"], info["bmin_deg"]
        beam_sr = (beam_solid_angle(bmaj, bmin) if bmaj and bmin else None) or (
            beam_solid_angle(beam_fwhm_deg, beam_fwhm_deg) if beam_fwhm_deg else None)
        pix_sr = abs(info["dl_x"] * info["dl_y"])
        for s, c in info["cube"].items():
            data = to_jy_per_pixel(c, info["unit"] or "Jy/pixel", info["freq"], pix_sr,
                                   beam_sr)
            parts.setdefault(s, []).extend(
                (f, data[k], path) for k, f in enumerate(info["freq"]))
    cubes, freq = {}, None
    for s, chans in parts.items():
        chans.sort(key=lambda item: item[0])
        for (f1, _, p1), (f2, _, p2) in zip(chans, chans[1:]):
            if math.isclose(f1, f2, rel_tol=1e-9):
                raise InputError(f"{p2}: Stokes {s} at {f2 / 1e6:.6f} MHz is also in {p1}; "
                                 "give each channel once")
        f = np.array([item[0] for item in chans])
        if freq is None:
            freq = f
        elif f.shape != freq.shape or not np.allclose(f, freq, rtol=1e-9):
            raise InputError(f"the images give Stokes {s} other channels than Stokes "
                             f"{next(iter(cubes))}; give every Stokes parameter the same "
                             "channels")
        cubes[s] = np.stack([item[1] for item in chans])
    if freq.size > 1 and not np.allclose(np.diff(freq), np.diff(freq)[0], rtol=1e-6):
        raise InputError(f"{paths[0]}: the channels of the images are not evenly spaced "
                         "(a channel missing?); the delay transform needs a regular axis")
    return cubes, {**ref, "freq": freq}


def grid_image(image: str | os.PathLike | Sequence[str | os.PathLike], *,
               stokes: str | Sequence[str] | None = None, fov_deg: float | None = None,
               uv_range: tuple[float, float] = (30.0, 180.0),
               beam_fwhm_deg: float | None = None, beam_area_sr: float | None = None
               ) -> xr.Dataset:
    """A uvcube Dataset from FITS images (FFT of the inner ``fov_deg`` x ``fov_deg``).

    Parameters
    ----------
    image : FITS file(s) or glob(s) (:func:`image_paths`, :func:`read_images`).
    stokes : Stokes label of each file without a STOKES axis (default I); a string
        ``"Q,U"`` or a sequence.
    fov_deg : inner field of view used (default the whole image, cut to an even square).
    uv_range : wavelengths; the cube keeps cells up to ``max`` (the PS bins use the range).
    beam_fwhm_deg : restoring beam FWHM for Jy/beam images without BMAJ/BMIN.
    beam_area_sr : Omega for the cosmological normalisation (default the FoV area).

    Every pixel is a sample of weight 1: ``weight`` is 1 in every cell.
    """
    paths = image_paths(image)
    labels = _stokes_labels(stokes)
    cubes, ref = read_images(paths, labels, beam_fwhm_deg)
    shape = next(iter(cubes.values())).shape
    npix = min(shape[-2:])
    if fov_deg is not None:
        if not fov_deg > 0:
            raise InputError(f"fov must be positive, got {fov_deg}", param="fov")
        npix = int(round(fov_deg / math.degrees(abs(ref["dl_x"]))))
        if npix < 4:
            raise InputError(f"fov {fov_deg} deg is less than 4 pixels", param="fov")
        if npix > min(shape[-2:]):
            raise InputError(f"fov {fov_deg} deg is larger than the image "
                             f"({min(shape[-2:]) * math.degrees(abs(ref['dl_x'])):.3g} deg)",
                             param="fov")
    npix -= npix % 2
    uv_min, uv_max = (float(x) for x in uv_range)
    if not (0 <= uv_min < uv_max):
        raise InputError(f"uv range {uv_min}..{uv_max} wavelengths is empty: need 0 <= MIN < MAX")
    zeros = np.zeros((shape[0], npix, npix))
    stack = np.stack([crop_centre(cubes.get(s, zeros), npix) if s in cubes else zeros
                      for s in "IQUV"])
    vis4, cell, M = image_to_uv(stack, ref["dl_x"], ref["dl_y"], uv_max)
    weight = np.ones(vis4.shape[1:])
    centres = np.arange(-M, M + 1) * cell
    fov = npix * math.degrees(abs(ref["dl_x"]))
    if uv_max > M * cell:
        log.warning("the image pixels resolve only %.1f wavelengths (< uv max %g)", M * cell,
                    uv_max)
    attrs = {
        "cell_lambda": cell, "uv_min_lambda": uv_min, "uv_max_lambda": uv_max,
        "units": "Jy", "source": "; ".join(os.path.abspath(p) for p in paths),
        "source_kind": "image", "column": "", "field_id": -1, "spw_id": -1,
        "image_units": ref["unit"], "stokes_given": "".join(s for s in "IQUV" if s in cubes),
        "gridder": "image-fft", "w_correction": "none needed (image cube)",
        "weighting": "uniform (every cell weight 1)", "fov_deg": fov,
        "pixel_deg": math.degrees(abs(ref["dl_x"])),
        "beam_area_sr": float(beam_area_sr) if beam_area_sr else math.radians(fov) ** 2,
        "beam_area_source": "given" if beam_area_sr else "area of the field of view box",
    }
    return uvcube_dataset(vis4, weight, ref["freq"], centres, attrs)


def _stokes_labels(stokes: str | Sequence[str] | None) -> list[str]:
    """``"Q,U"`` or ``["Q", "U"]`` as checked labels."""
    if stokes is None:
        return []
    items = stokes.split(",") if isinstance(stokes, str) else list(stokes)
    labels = [str(x).strip().upper() for x in items]
    if any(label not in ("I", "Q", "U", "V") for label in labels):
        raise InputError(f"stokes {stokes!r}: use I, Q, U or V, comma separated",
                         param="stokes")
    return labels
