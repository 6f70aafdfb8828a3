"""Point-source skies: voxels of a cube, or parametric sources of a makesourcedb file.

:class:`PointSources` holds either

* **tabulated** spectra (from a cube): ``freq`` (nchan_sky,) Hz and ``stokes``
  (nsrc, nchan_sky, 4) Jy; every voxel of the cube is a source at its pixel's direction
  with (I, Q, U, V) at that channel (docs/science.md section 3), or
* **parametric** spectra with the semantics of DP3 (``base/PointSource.cc``):
  reference flux ``stokes_ref`` (nsrc, 4) Jy at ``ref_freq`` (nsrc,) Hz, spectral terms
  ``spectral_index`` (nsrc, nterms) applied to Stokes I only, logarithmic
  (I = I0 (nu/nu0)^(c0 + c1 log10(nu/nu0) + ...)) or not (I = I0 + c0 x + c1 x^2 + ...,
  x = nu/nu0 - 1), and an optional rotation measure (``rotation_measure``, NaN for none)
  with which Q + iU = I(nu) * pol_fraction * exp(2i (pol_angle + RM lambda^2)),
  ``pol_angle`` being the angle at lambda = 0 (rad). Without RM, Q, U and V are constant.

Directions are J2000 (RA, Dec) in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from msleak.constants import SPEED_OF_LIGHT
from msleak.errors import InputError
from msleak.sky.cube import SkyCube, convert_units, pixel_directions

__all__ = ["PointSources", "lmn", "sources_from_cube", "DEFAULT_RTOL"]

#: Default relative tolerance for matching an MS channel to a sky-cube channel.
DEFAULT_RTOL = 1e-6


def lmn(ra: np.ndarray, dec: np.ndarray, ra0: float, dec0: float
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Direction cosines of (ra, dec) about the phase centre (ra0, dec0), all in rad.

    l = cos(dec) sin(ra - ra0)
    m = sin(dec) cos(dec0) - cos(dec) sin(dec0) cos(ra - ra0)
    n = sin(dec) sin(dec0) + cos(dec) cos(dec0) cos(ra - ra0)
    """
    ra, dec = np.asarray(ra, float), np.asarray(dec, float)
    dra = ra - ra0
    cd, sd = np.cos(dec), np.sin(dec)
    l_ = cd * np.sin(dra)
    m_ = sd * math.cos(dec0) - cd * math.sin(dec0) * np.cos(dra)
    n_ = sd * math.sin(dec0) + cd * math.cos(dec0) * np.cos(dra)
    return l_, m_, n_


@dataclass(frozen=True, eq=False)
class PointSources:
    """Point sources with tabulated or parametric (DP3-style) spectra; see module doc.

    Attributes
    ----------
    ra, dec : (nsrc,) rad, J2000
    freq : (nchan_sky,) Hz, tabulated skies only
    stokes : (nsrc, nchan_sky, 4) Jy (I, Q, U, V), tabulated skies only
    ref_freq : (nsrc,) Hz (0 where not given), parametric only
    stokes_ref : (nsrc, 4) Jy at ref_freq, parametric only
    spectral_index : (nsrc, nterms) spectral terms for Stokes I (zero padded)
    log_si : (nsrc,) bool, logarithmic spectral index (DP3's LogarithmicSI)
    rotation_measure : (nsrc,) rad m^-2, NaN where the source has none
    pol_fraction, pol_angle : (nsrc,) polarized fraction of I and angle at lambda = 0 (rad),
        used where rotation_measure is set
    names : source names (optional)
    """

    ra: np.ndarray
    dec: np.ndarray
    freq: np.ndarray | None = None
    stokes: np.ndarray | None = None
    ref_freq: np.ndarray | None = None
    stokes_ref: np.ndarray | None = None
    spectral_index: np.ndarray | None = None
    log_si: np.ndarray | None = None
    rotation_measure: np.ndarray | None = None
    pol_fraction: np.ndarray | None = None
    pol_angle: np.ndarray | None = None
    names: tuple[str, ...] | None = None

    def __post_init__(self):
        n = len(np.atleast_1d(self.ra))
        if len(np.atleast_1d(self.dec)) != n:
            raise InputError("ra and dec must have the same length")
        if self.is_tabulated == self.is_parametric:
            raise InputError("PointSources needs either freq+stokes (tabulated) or "
                             "stokes_ref (parametric)")
        if self.is_tabulated:
            if self.stokes.shape != (n, len(self.freq), 4):
                raise InputError(f"stokes must be (nsrc, nchan, 4) = ({n}, {len(self.freq)}, "
                                 f"4), got {self.stokes.shape}")
        elif self.stokes_ref.shape != (n, 4):
            raise InputError(f"stokes_ref must be (nsrc, 4), got {self.stokes_ref.shape}")
        if self.names is not None and len(self.names) != n:
            raise InputError("one name per source is needed")

    # ---------------------------------------------------------------- constructors
    @classmethod
    def parametric(cls, ra, dec, i, q=0.0, u=0.0, v=0.0, *, ref_freq=0.0,
                   spectral_index=None, log_si=True, rotation_measure=None,
                   names=None) -> "PointSources":
        """Parametric sources from Stokes at ``ref_freq`` (Hz), as in a makesourcedb file.

        With a rotation measure (rad m^-2, NaN for none) Q and U are those at ``ref_freq``
        and the polarized fraction and angle follow DP3's rule: pol_fraction =
        sqrt(Q^2 + U^2) / I, pol_angle = atan2(U, Q) / 2 - RM lambda_ref^2 (mod pi).
        """
        ra = np.atleast_1d(np.asarray(ra, float))
        n = ra.size
        b = lambda x: np.broadcast_to(np.asarray(x, float), (n,)).copy()  # noqa: E731
        iquv = np.stack([b(i), b(q), b(u), b(v)], axis=1)
        nu0 = b(ref_freq)
        si = (np.zeros((n, 0)) if spectral_index is None
              else np.atleast_2d(np.asarray(spectral_index, float)))
        if si.shape[0] == 1 and n > 1:
            si = np.repeat(si, n, axis=0)
        rm = b(np.nan if rotation_measure is None else rotation_measure)
        pf, pa = np.zeros(n), np.zeros(n)
        has = np.isfinite(rm)
        if np.any(has):
            if np.any(nu0[has] <= 0):
                raise InputError("a RotationMeasure with Q/U needs a ReferenceFrequency > 0")
            if np.any(iquv[has, 0] == 0):
                raise InputError("a RotationMeasure source needs Stokes I != 0 (DP3 defines "
                                 "its polarization as a fraction of I)")
            lam0 = SPEED_OF_LIGHT / nu0[has]
            pf[has] = np.hypot(iquv[has, 1], iquv[has, 2]) / iquv[has, 0]
            pa[has] = np.mod(0.5 * np.arctan2(iquv[has, 2], iquv[has, 1])
                             - rm[has] * lam0**2, np.pi)
        return cls(ra=ra, dec=np.atleast_1d(np.asarray(dec, float)), ref_freq=nu0,
                   stokes_ref=iquv, spectral_index=si, log_si=np.broadcast_to(
                       np.asarray(log_si, bool), (n,)).copy(),
                   rotation_measure=rm, pol_fraction=pf, pol_angle=pa,
                   names=tuple(names) if names is not None else None)

    # ---------------------------------------------------------------- properties
    @property
    def is_tabulated(self) -> bool:
        return self.freq is not None and self.stokes is not None

    @property
    def is_parametric(self) -> bool:
        return self.stokes_ref is not None

    def __len__(self) -> int:
        return len(np.atleast_1d(self.ra))

    def lmn(self, ra0: float, dec0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Direction cosines (l, m, n), each (nsrc,), about (ra0, dec0) in rad."""
        return lmn(self.ra, self.dec, ra0, dec0)

    def select(self, mask: np.ndarray) -> "PointSources":
        """The subset of sources where ``mask`` (nsrc,) is true."""
        mask = np.asarray(mask, bool)
        kw = {}
        for name in ("ra", "dec", "stokes", "ref_freq", "stokes_ref", "spectral_index",
                     "log_si", "rotation_measure", "pol_fraction", "pol_angle"):
            value = getattr(self, name)
            kw[name] = None if value is None else value[mask]
        names = None if self.names is None else tuple(np.asarray(self.names)[mask])
        return PointSources(freq=self.freq, names=names, **kw)

    # ---------------------------------------------------------------- spectra
    def at_frequencies(self, freq_hz, *, rtol: float = DEFAULT_RTOL,
                       interpolate: bool = False) -> np.ndarray:
        """Stokes (I, Q, U, V) of every source at the given frequencies.

        Parameters
        ----------
        freq_hz : (nchan,) Hz
        rtol : tabulated skies: a requested frequency matches a sky channel when
            |f - f_sky| <= rtol * f (default 1e-6, i.e. 150 Hz at 150 MHz)
        interpolate : tabulated skies: linear interpolation in frequency instead of exact
            matching (frequencies outside the sky's channel range are an error)

        Returns
        -------
        (nsrc, nchan, 4) float64, Jy
        """
        f = np.atleast_1d(np.asarray(freq_hz, float))
        if self.is_tabulated:
            return self._tabulated(f, rtol, interpolate)
        return self._parametric(f)

    def _tabulated(self, f, rtol, interpolate):
        fs = np.asarray(self.freq, float)
        order = np.argsort(fs)
        fs_sorted = fs[order]
        if not interpolate:
            pos = np.clip(np.searchsorted(fs_sorted, f), 1, max(1, fs.size - 1))
            lo = np.clip(pos - 1, 0, fs.size - 1)
            hi = np.clip(pos, 0, fs.size - 1)
            near = np.where(np.abs(fs_sorted[lo] - f) <= np.abs(fs_sorted[hi] - f), lo, hi)
            diff = np.abs(fs_sorted[near] - f)
            bad = diff > rtol * np.abs(f)
            if np.any(bad):
                k = int(np.argmax(bad))
                raise InputError(
                    f"frequency {f[k] / 1e6:.6f} MHz has no sky channel within rtol={rtol:g} "
                    f"(nearest {fs_sorted[near[k]] / 1e6:.6f} MHz); make the sky on the MS "
                    "channels or pass interpolate_frequency", param="interpolate_frequency")
            return np.ascontiguousarray(self.stokes[:, order[near], :], dtype=float)
        if np.any(f < fs_sorted[0] * (1 - rtol)) or np.any(f > fs_sorted[-1] * (1 + rtol)):
            raise InputError(f"frequencies {f.min() / 1e6:.6f}-{f.max() / 1e6:.6f} MHz are "
                             f"outside the sky's {fs_sorted[0] / 1e6:.6f}-"
                             f"{fs_sorted[-1] / 1e6:.6f} MHz; cannot interpolate")
        if fs.size == 1:
            return np.repeat(self.stokes[:, :1, :], f.size, axis=1).astype(float)
        fc = np.clip(f, fs_sorted[0], fs_sorted[-1])
        hi = np.clip(np.searchsorted(fs_sorted, fc), 1, fs.size - 1)
        lo = hi - 1
        w = (fc - fs_sorted[lo]) / (fs_sorted[hi] - fs_sorted[lo])
        s = self.stokes[:, order, :]
        return (s[:, lo, :] * (1 - w)[None, :, None] + s[:, hi, :] * w[None, :, None])

    def _parametric(self, f):
        n = len(self)
        out = np.empty((n, f.size, 4))
        i0 = self.stokes_ref[:, 0][:, None]
        itot = np.repeat(i0, f.size, axis=1)
        si = self.spectral_index
        has_si = np.any(si != 0, axis=1) if si is not None and si.size else np.zeros(n, bool)
        if np.any(has_si):
            nu0 = self.ref_freq
            if np.any(nu0[has_si] <= 0):
                raise InputError("a SpectralIndex needs a ReferenceFrequency > 0")
            idx = np.nonzero(has_si)[0]
            for k in idx:
                if self.log_si[k]:
                    base = np.log10(f / nu0[k])
                    expo = np.polynomial.polynomial.polyval(base, si[k])
                    itot[k] = i0[k] * 10.0 ** (base * expo)
                else:
                    x = f / nu0[k] - 1.0
                    itot[k] = i0[k] + x * np.polynomial.polynomial.polyval(x, si[k])
        out[:, :, 0] = itot
        out[:, :, 1] = self.stokes_ref[:, 1][:, None]
        out[:, :, 2] = self.stokes_ref[:, 2][:, None]
        out[:, :, 3] = self.stokes_ref[:, 3][:, None]
        rm = self.rotation_measure
        if rm is not None and np.any(np.isfinite(rm)):
            has = np.isfinite(rm)
            lam2 = (SPEED_OF_LIGHT / f) ** 2
            chi = 2.0 * (self.pol_angle[has][:, None] + rm[has][:, None] * lam2[None, :])
            p = itot[has] * self.pol_fraction[has][:, None]
            out[has, :, 1] = p * np.cos(chi)
            out[has, :, 2] = p * np.sin(chi)
        return out


def sources_from_cube(cube: SkyCube) -> PointSources:
    """Every voxel of a cube as a point source, in Jy (docs/science.md section 3).

    Returns
    -------
    Tabulated :class:`PointSources`, sources in pixel order (y-major), spectra at the
    cube's channels; K cubes are converted with S = 2 k_B T Omega_pix / lambda^2.
    Q and U are passed unchanged: the cube's are referred to the local North of each
    pixel (FITS convention, :mod:`msleak.sky.cube`), which is the frame predict and the
    beam use at each source's direction.
    """
    cube = convert_units(cube, "Jy/pixel")
    ny, nx = cube.npix
    ra, dec = pixel_directions(cube.wcs, (ny, nx))
    nchan = cube.data.shape[1]
    stokes = np.zeros((ny * nx, nchan, 4))
    for k, label in enumerate("IQUV"):
        if label in cube.stokes:
            plane = cube.data[cube.stokes.index(label)]          # (nchan, ny, nx)
            stokes[:, :, k] = plane.reshape(nchan, ny * nx).T
    return PointSources(ra=ra.ravel(), dec=dec.ravel(), freq=np.asarray(cube.freq, float),
                        stokes=stokes)
