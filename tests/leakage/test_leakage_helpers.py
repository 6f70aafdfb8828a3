"""Synthetic PS products (docs/products.md "ps") for the leakage tests, and their checks.

``make_ps`` builds a self-consistent product from per-voxel complex Stokes I and P
amplitudes: ``power3d`` = |V|^2 of every voxel (u, tau), ``power3d_P_mirror`` = |P~|^2
of its mirror (-u, -tau), and the 2D ``power`` is the plain average of the voxels in
each (|k_par|, k_perp) bin (for P: of both voxels of each pair), computed here
independently of msleak.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from msleak.io.products import save_product

STOKES = ["I", "Q", "U", "V", "P"]
WEDGE_H, WEDGE_P = 3.0, 0.4


def geometry(ndelay: int = 20, ncell: int = 60, nperp: int = 6, seed: int = 0):
    """Signed k_par per delay (Mpc^-1), k_perp per cell, k_perp bin edges."""
    rng = np.random.default_rng(seed)
    dk = 0.05
    k_par3d = (np.arange(ndelay) - ndelay // 2) * dk  # includes 0 and both signs
    edges = np.linspace(0.02, 0.2, nperp + 1)
    # every bin gets cells: spread cells over the bins, then jitter inside
    which = np.arange(ncell) % nperp
    k_perp_cell = edges[which] + rng.uniform(0.05, 0.95, ncell) * np.diff(edges)[which]
    return k_par3d, k_perp_cell, edges


def cylindrical(p3d: np.ndarray, k_par3d, k_perp_cell, edges):
    """Average (delay, cell) power into (|k_par|, k_perp) bins; returns power, counts, k_par."""
    k_par = np.unique(np.round(np.abs(k_par3d), 12))
    ipar = np.searchsorted(k_par, np.round(np.abs(k_par3d), 12))
    iperp = np.digitize(k_perp_cell, edges) - 1
    power = np.zeros(p3d.shape[:-2] + (k_par.size, edges.size - 1))
    counts = np.zeros((k_par.size, edges.size - 1))
    for d in range(p3d.shape[-2]):
        for c in range(p3d.shape[-1]):
            power[..., ipar[d], iperp[c]] += p3d[..., d, c]
            counts[ipar[d], iperp[c]] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        power = np.where(counts > 0, power / np.maximum(counts, 1), 0.0)
    return power, counts, k_par


def make_ps_dataset(v_i: np.ndarray, v_p: np.ndarray, k_par3d=None, k_perp_cell=None,
                    edges=None, units: str = "mK^2 Mpc^3", power3d_i=None, power3d_p=None,
                    drop_stokes: str | None = None, with_power3d: bool = True,
                    nk: int = 8, v_p_mirror=None, with_mirror: bool = True) -> xr.Dataset:
    """A PS product dataset from complex voxel amplitudes (delay3d, cell) of I and P.

    ``v_p_mirror``: P amplitudes of the mirrored voxels (-u, -tau) (default ``v_p``:
    equal power in both). ``power3d_i``/``power3d_p`` override |v|^2 (e.g. to inject
    zeros or negatives; the mirror then takes the same override unless ``v_p_mirror``
    is given). ``drop_stokes`` removes one Stokes label (bad-input tests).
    """
    ndelay, ncell = v_i.shape
    if k_par3d is None:
        k_par3d, k_perp_cell, edges = geometry(ndelay, ncell)
    p_i = np.abs(v_i) ** 2 if power3d_i is None else power3d_i
    p_p = np.abs(v_p) ** 2 if power3d_p is None else power3d_p
    p_m = p_p if v_p_mirror is None else np.abs(v_p_mirror) ** 2
    pair = 0.5 * (p_p + p_m)
    p3d = np.stack([p_i, 0.5 * pair, 0.5 * pair, np.zeros_like(p_i), p_p])
    binned = np.stack([p_i, 0.5 * pair, 0.5 * pair, np.zeros_like(p_i), pair])
    power, counts, k_par = cylindrical(binned, k_par3d, k_perp_cell, edges)
    k_perp = 0.5 * (edges[1:] + edges[:-1])
    kk = np.hypot(k_par3d[:, None], k_perp_cell[None, :])
    k_edges = np.linspace(0, kk.max() * 1.001, nk + 1)
    ik = np.digitize(kk, k_edges) - 1
    counts_sph = np.bincount(ik.ravel(), minlength=nk).astype(float)
    power_sph = np.array([np.bincount(ik.ravel(), weights=p.ravel(), minlength=nk)
                          for p in binned]) / np.maximum(counts_sph, 1)
    stokes = list(STOKES)
    ds = xr.Dataset(
        {
            "power": (("stokes", "k_par", "k_perp"), power, {"units": units}),
            "counts": (("k_par", "k_perp"), counts),
            "power_sph": (("stokes", "k"), power_sph, {"units": units}),
            "counts_sph": (("k",), counts_sph),
            "k_perp_bounds": (("k_perp", "nv"), np.column_stack([edges[:-1], edges[1:]])),
        },
        coords={"stokes": stokes, "k_par": k_par, "k_perp": k_perp,
                "k": 0.5 * (k_edges[1:] + k_edges[:-1]),
                "delay3d": np.arange(ndelay) * 1e-7, "cell": np.arange(ncell)},
        attrs={"wedge_slope_horizon": WEDGE_H, "wedge_slope_primary": WEDGE_P,
               "cosmology": "Planck18", "redshift": 8.1, "units": units,
               "freq_centre_hz": 155e6, "window": "blackmanharris", "cross_power": 0,
               "stokes_convention": "test"},
    )
    if with_power3d:
        ds["power3d"] = (("stokes", "delay3d", "cell"), p3d, {"units": units})
        if with_mirror:
            ds["power3d_P_mirror"] = (("delay3d", "cell"), p_m, {"units": units})
        ds = ds.assign_coords(k_par3d=("delay3d", k_par3d),
                              k_perp_cell=("cell", k_perp_cell),
                              u_cell=("cell", k_perp_cell * 100.0),
                              v_cell=("cell", np.zeros(ncell)))
    if drop_stokes is not None:
        keep = [s for s in stokes if s != drop_stokes]
        ds = ds.sel(stokes=keep)
    return ds


def gaussian_voxels(shape, sigma: float, rng) -> np.ndarray:
    """Circular complex Gaussian values of total variance sigma^2 (E|v|^2 = sigma^2)."""
    return sigma * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2.0)


def rotated_leakage(v_p: np.ndarray, eps: float, rng) -> np.ndarray:
    """Stokes I = eps x (a random rotation of Q + iU), exactly: |v_i| = eps |v_p|."""
    return eps * np.exp(1j * rng.uniform(0, 2 * np.pi, v_p.shape)) * v_p


def write_ps(path, ds: xr.Dataset):
    return save_product(ds, path, "ps", overwrite=True)


# ---- checks of the helper itself ---------------------------------------------------------

def test_cylindrical_average_matches_direct_mean():
    rng = np.random.default_rng(1)
    k_par3d, k_perp_cell, edges = geometry(8, 30, 3)
    p = rng.uniform(1, 2, (8, 30))
    power, counts, k_par = cylindrical(p, k_par3d, k_perp_cell, edges)
    # direct: bin (|k_par| = k_par[1], k_perp bin 2)
    sel = (np.isclose(np.abs(k_par3d), k_par[1]))[:, None] & \
        ((k_perp_cell >= edges[2]) & (k_perp_cell < edges[3]))[None, :]
    assert counts[1, 2] == sel.sum() > 0
    assert np.isclose(power[1, 2], p[sel].mean(), rtol=1e-12)
    assert counts.sum() == p.size


def test_rotated_leakage_has_exact_ratio():
    rng = np.random.default_rng(2)
    v_p = gaussian_voxels((5, 7), 1.0, rng)
    v_i = rotated_leakage(v_p, 0.02, rng)
    np.testing.assert_allclose(np.abs(v_i) ** 2 / np.abs(v_p) ** 2, 0.02**2, rtol=1e-12)
