"""Property-based tests (hypothesis) of msleak's numeric cores: gridding adjointness,
Stokes <-> correlation round trips, cosmology conversions, permutation invariance of the
leakage statistics. Each property runs a bounded number of examples (<= 50)."""

from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

PROFILE = settings(max_examples=40, deadline=None, derandomize=False,
                   suppress_health_check=[HealthCheck.too_slow])

seeds = st.integers(min_value=0, max_value=2**32 - 1)


# ------------------------------------------------------------------------ gridding
@PROFILE
@given(seed=seeds, nrow=st.integers(1, 40), nchan=st.integers(1, 4),
       cell=st.floats(2.0, 40.0), uv_max=st.floats(20.0, 300.0))
def test_cell_gridder_adjoint(seed, nrow, nchan, cell, uv_max):
    """The nearest-cell gridder x -> sum_wv is real-linear (samples enter at (u, v) and
    conjugated at (-u, -v)); its transpose, written here as a degridder
    y -> w (y[cell] + conj(y[mirror])), satisfies Re<G x, y> = Re<x, G^T y>."""
    from msleak.ps.gridding import CellAccumulator, make_grid

    rng = np.random.default_rng(seed)
    grid = make_grid(cell, uv_max)
    u = rng.uniform(-1.2 * uv_max, 1.2 * uv_max, (nrow, nchan))   # some fall outside
    v = rng.uniform(-1.2 * uv_max, 1.2 * uv_max, (nrow, nchan))
    w = rng.uniform(0.0, 2.0, (nrow, nchan)) * (rng.random((nrow, nchan)) > 0.2)
    x = rng.normal(size=(1, nrow, nchan)) + 1j * rng.normal(size=(1, nrow, nchan))
    acc = CellAccumulator(grid, nchan, nstokes=1)
    acc.add(u, v, x, w)
    gx = acc.sum_wv[0]                                          # (chan, v, u)
    y = rng.normal(size=gx.shape) + 1j * rng.normal(size=gx.shape)

    M, g = grid.M, grid.size
    iu = np.rint(u / grid.cell).astype(int)
    iv = np.rint(v / grid.cell).astype(int)
    ok = (w > 0) & (np.abs(iu) <= M) & (np.abs(iv) <= M)
    chan = np.broadcast_to(np.arange(nchan), (nrow, nchan))
    gty = np.zeros((nrow, nchan), complex)
    gty[ok] = w[ok] * (y[chan[ok], iv[ok] + M, iu[ok] + M]
                       + np.conj(y[chan[ok], M - iv[ok], M - iu[ok]]))
    lhs = np.real(np.vdot(gx, y))
    rhs = np.real(np.vdot(x[0], gty))
    assert lhs == pytest.approx(rhs, rel=1e-10, abs=1e-10 * (1 + abs(lhs)))
    # and the weights land where the samples do
    assert acc.sum_w.sum() == pytest.approx(2 * w[ok].sum(), rel=1e-12)
    assert g == 2 * M + 1


@settings(max_examples=25, deadline=None)
@given(seed=seeds, nrow=st.integers(1, 30), npix=st.sampled_from([32, 48, 64]),
       wmax=st.floats(0.0, 200.0))
def test_ducc_wgridder_adjoint_as_used(seed, nrow, npix, wmax):
    """ducc0's vis2dirty (as the wgrid gridder calls it: w-gridding, flip_w, no division
    by n, weights) and dirty2vis with the same arguments are adjoint:
    <vis2dirty(v), d> = Re<v, dirty2vis(d)> to the requested accuracy."""
    from ducc0.wgridder import dirty2vis, vis2dirty

    from msleak.ps.gridding import make_grid

    rng = np.random.default_rng(seed)
    grid = make_grid(16.0, 150.0)
    freq = np.array([150e6])
    lam = 299_792_458.0 / freq[0]
    uvw = np.column_stack([rng.uniform(-150, 150, nrow) * lam, rng.uniform(-150, 150, nrow) * lam,
                           rng.uniform(-wmax, wmax, nrow) * lam])
    wgt = rng.uniform(0.1, 2.0, (nrow, 1))
    vis = rng.normal(size=(nrow, 1)) + 1j * rng.normal(size=(nrow, 1))
    dirty = rng.normal(size=(npix, npix))
    dl = 1.0 / (npix * grid.cell)
    kw = dict(uvw=uvw, freq=freq, wgt=wgt, pixsize_x=dl, pixsize_y=dl, epsilon=1e-9,
              do_wgridding=True, flip_w=True, divide_by_n=False, nthreads=1)
    d = vis2dirty(vis=vis, npix_x=npix, npix_y=npix, **kw)
    back = dirty2vis(dirty=dirty, **kw)
    lhs = float(np.sum(d * dirty))
    rhs = float(np.real(np.vdot(back, vis)))
    scale = np.sqrt(np.sum(d ** 2) * np.sum(dirty ** 2))
    assert abs(lhs - rhs) <= 1e-7 * scale


@settings(max_examples=15, deadline=None)
@given(seed=seeds, nrow=st.integers(1, 20))
def test_wgrid_accumulator_linear(seed, nrow):
    """The wgrid numerators are linear in the visibilities: N(a x + b y) = a N(x) + b N(y)
    for real a, b (the dirty image takes the real part), PSF unchanged."""
    from msleak.ps.gridding import WGridAccumulator, make_grid

    rng = np.random.default_rng(seed)
    grid = make_grid(16.0, 120.0)
    freq = np.array([150e6, 151e6])
    lam = 299_792_458.0 / freq[0]
    uvw = np.column_stack([rng.uniform(-110, 110, (nrow, 2)) * lam, rng.uniform(-5, 5, nrow) * lam])
    wgt = rng.uniform(0.5, 1.5, (nrow, 2))
    x = rng.normal(size=(4, nrow, 2)) + 1j * rng.normal(size=(4, nrow, 2))
    y = rng.normal(size=(4, nrow, 2)) + 1j * rng.normal(size=(4, nrow, 2))
    a, b = rng.normal(size=2)
    out = []
    for vis in (x, y, a * x + b * y):
        acc = WGridAccumulator(grid, freq, epsilon=1e-9)
        acc.add(uvw, vis, wgt)
        out.append(acc.numerators())
    (nx, px), (ny, py), (nz, pz) = out
    np.testing.assert_allclose(nz, a * nx + b * ny, atol=1e-7 * np.abs(nz).max())
    np.testing.assert_allclose(pz, px, rtol=1e-12, atol=1e-12 * np.abs(px).max())


# ------------------------------------------------------------------ conventions
finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@PROFILE
@given(iquv=st.lists(st.tuples(finite, finite, finite, finite), min_size=1, max_size=8),
       feed=st.sampled_from(["linear", "circular"]))
def test_stokes_correlation_round_trip(iquv, feed):
    """Real I, Q, U, V -> correlations -> Stokes is the identity; the correlations are the
    brightness matrix of docs/conventions.md (Hermitian: XY = conj(YX))."""
    from msleak.conventions import correlations_to_stokes, stokes_to_correlations

    s = np.asarray(iquv, float)
    corr = stokes_to_correlations(s, feed)
    i, q, u, v = s.T
    if feed == "linear":
        expect = np.stack([i + q, u + 1j * v, u - 1j * v, i - q], axis=-1)
    else:
        expect = np.stack([i + v, q + 1j * u, q - 1j * u, i - v], axis=-1)
    scale = 1e-12 * (1 + np.abs(s).max())
    np.testing.assert_allclose(corr, expect, atol=scale)
    np.testing.assert_allclose(corr[:, 1], np.conj(corr[:, 2]), atol=scale)
    np.testing.assert_allclose(correlations_to_stokes(corr, feed), s, atol=scale)


@PROFILE
@given(seed=seeds, feed=st.sampled_from(["linear", "circular"]))
def test_correlation_stokes_round_trip_complex(seed, feed):
    """Arbitrary complex correlations (a visibility, not Hermitian) -> Stokes -> back."""
    from msleak.conventions import correlations_to_stokes, stokes_to_correlations

    rng = np.random.default_rng(seed)
    corr = rng.normal(size=(5, 3, 4)) + 1j * rng.normal(size=(5, 3, 4))
    back = stokes_to_correlations(correlations_to_stokes(corr, feed), feed)
    np.testing.assert_allclose(back, corr, atol=1e-12)


# --------------------------------------------------------------------- cosmology
freqs = st.floats(60e6, 240e6)


@settings(max_examples=30, deadline=None)
@given(f1=freqs, f2=freqs, name=st.sampled_from(["Planck18", "Planck15", "WMAP9"]))
def test_cosmology_monotone(f1, f2, name):
    """Higher observed frequency: lower redshift, smaller D_c and X, larger k_perp for
    the same baseline (and z = f21 / nu - 1 exactly)."""
    from msleak.constants import FREQ_21CM
    from msleak.ps.cosmology import cosmo_at

    if abs(f1 - f2) < 1e3:
        return
    lo, hi = sorted((f1, f2))
    a, b = cosmo_at(lo, name), cosmo_at(hi, name)
    assert a.z == pytest.approx(FREQ_21CM / lo - 1, rel=1e-12)
    assert a.z > b.z and a.dc_mpc > b.dc_mpc and a.efunc > b.efunc
    assert a.k_perp(100.0) < b.k_perp(100.0)
    assert a.y_mpc_per_hz > b.y_mpc_per_hz


@settings(max_examples=30, deadline=None)
@given(freq=freqs, b=st.floats(0.0, 5000.0), tau=st.floats(-5e-6, 5e-6))
def test_cosmology_invertible(freq, b, tau):
    """k_perp and k_par invert to the baseline and delay (X and Y), and Y is the
    derivative of the comoving distance with frequency: Y = -dD_c/dnu (numerical)."""
    from msleak.constants import FREQ_21CM
    from msleak.ps.cosmology import cosmo_at, get_cosmology

    c = cosmo_at(freq)
    assert c.k_perp(b) * c.x_mpc_per_rad / (2 * np.pi) == pytest.approx(b, rel=1e-12, abs=1e-12)
    assert c.k_par(tau) * c.y_mpc_per_hz / (2 * np.pi) == pytest.approx(tau, rel=1e-12,
                                                                         abs=1e-24)
    assert np.sign(c.k_par(tau)) == np.sign(tau)
    cosmo = get_cosmology("Planck18")
    dnu = 1e3
    dc = [cosmo.comoving_distance(FREQ_21CM / (freq + s * dnu) - 1).to_value("Mpc") for s in (-1, 1)]
    assert -(dc[1] - dc[0]) / (2 * dnu) == pytest.approx(c.y_mpc_per_hz, rel=1e-6)


# ------------------------------------------------------------------ statistics
@settings(max_examples=30, deadline=None)
@given(seed=seeds, n=st.integers(5, 400), scale=st.floats(0.1, 50.0),
       bins=st.integers(2, 60))
def test_leakage_statistics_permutation_invariant(seed, n, scale, bins):
    """Mean, median, std, peak, histogram and the Pareto fits do not depend on the
    order of the voxels."""
    from msleak.leakage.stats import leakage_statistics

    rng = np.random.default_rng(seed)
    L = scale * np.sqrt(rng.pareto(1.0, n) + rng.random(n))
    a = leakage_statistics(L, bins=bins)
    b = leakage_statistics(rng.permutation(L), bins=bins)
    for name in ("median", "peak", "peak_bin_width"):
        assert getattr(a, name) == getattr(b, name)
    assert a.mean == pytest.approx(b.mean, rel=1e-12)
    assert a.std == pytest.approx(b.std, rel=1e-10)
    np.testing.assert_array_equal(a.hist_counts, b.hist_counts)
    assert a.fit.method == b.fit.method
    assert a.fit.median_w == pytest.approx(b.fit.median_w, rel=1e-6, abs=1e-15)
    if a.fit_hist is not None and b.fit_hist is not None:
        assert a.fit_hist.median_w == pytest.approx(b.fit_hist.median_w, rel=1e-4, abs=1e-15)


def test_jy_per_kelvin_is_the_rayleigh_jeans_law():
    """S = 2 k_B T nu^2 / c^2 Omega, written here from the exact SI constants."""
    from msleak.constants import jy_per_kelvin

    freq = np.linspace(100e6, 200e6, 7)
    omega = 3.3e-5
    expected = 2 * 1.380649e-23 * freq ** 2 / 299_792_458.0 ** 2 * omega / 1e-26
    np.testing.assert_allclose(jy_per_kelvin(freq, omega), expected, rtol=1e-14)
    assert np.ndim(jy_per_kelvin(150e6, omega)) == 0
