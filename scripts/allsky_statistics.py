"""The all-sky foreground at its defaults against the flat cube at its defaults, at matched
resolution (docs/sky.md, "The defaults at matched resolution").

Usage: python scripts/allsky_statistics.py SEED [SEED ...]   (one line per seed)

Per seed: the flat cube (50 x 50 x 100 cells of 0.3 deg) and the sphere at NSIDE 256
(0.23 deg pixels, the default 0.3 deg cells and 15 deg box), one channel at 150 MHz. It
prints the std of the total Faraday depth (flat: over the box; sphere: over the disc of
radius 7.5 deg about the NCP), the rms |P| there, and the slope of C_l of P over
l = 30-150 (flat: the box's flat-sky spectrum; sphere: EE + BB over the whole sphere, and
the same flat estimator on a 50 x 50 SIN grid of 0.3 deg about the NCP, nearest pixel).
Needs the ``healpix`` extra; about 2 min and 3 GB per seed.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

NSIDE = 256
CELL_DEG = 0.3
NGRID = 50


def slope(ell: np.ndarray, cl: np.ndarray, lo: float = 30, hi: float = 150) -> float:
    use = (ell >= lo) & (ell <= hi) & np.isfinite(cl) & (cl > 0)
    return float(np.polyfit(np.log(ell[use]), np.log(cl[use]), 1)[0])


def one_seed(seed: int) -> str:
    import healpy

    from msleak.sky.allsky import generate_allsky
    from msleak.sky.faraday import polarized_brightness
    from msleak.sky.foreground import ForegroundParams, build_box
    from msleak.sky.spectrum import angular_power_spectrum

    params = ForegroundParams()
    box, _ = build_box(params, NGRID, seed)
    p = polarized_brightness(box.amp, box.chi0, box.dphi, np.array([150e6]))[0]
    p *= params.p_rms_k / np.sqrt(np.mean(np.abs(p) ** 2))
    ell, cl, _ = angular_power_spectrum(p, math.radians(CELL_DEG), nbins=12)
    flat = (box.faraday_depth()[-1].std(), np.sqrt(np.mean(np.abs(p) ** 2)), slope(ell, cl))

    sky = generate_allsky(nside=NSIDE, nchan=1, seed=seed, params=params, freq_min_hz=150e6)
    q, u = sky.sky.stokes[1, 0], sky.sky.stokes[2, 0]
    patch = healpy.query_disc(NSIDE, healpy.ang2vec(0.0, 90.0, lonlat=True),
                              math.radians(NGRID * CELL_DEG / 2))
    cls = healpy.anafast(np.stack([np.zeros_like(q), q, -u]), pol=True)
    grid = (np.arange(NGRID) - (NGRID - 1) / 2) * math.radians(CELL_DEG)
    l, m = np.meshgrid(grid, grid)
    pix = healpy.vec2pix(NSIDE, l.ravel(), -m.ravel(), np.sqrt(1 - l**2 - m**2).ravel())
    ell2, cl2, _ = angular_power_spectrum((q[pix] + 1j * u[pix]).reshape(NGRID, NGRID),
                                          math.radians(CELL_DEG), nbins=12)
    return (f"seed {seed}: flat phi_std {flat[0]:.2f} prms {flat[1]:.2f} slope {flat[2]:.2f}"
            f" | sphere phi_std {sky.faraday_depth[patch].std():.2f}"
            f" prms {np.sqrt(np.mean(q[patch]**2 + u[patch]**2)):.2f}"
            f" slope(sphere) {slope(np.arange(cls[1].size), cls[1] + cls[2]):.2f}"
            f" slope(patch) {slope(ell2, cl2):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", nargs="+", type=int)
    for seed in ap.parse_args().seeds:
        print(one_seed(seed), flush=True)


if __name__ == "__main__":
    main()
