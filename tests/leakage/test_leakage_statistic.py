"""The per-voxel P_P of the leakage statistics, end to end from a Measurement Set.

DATA of a simulated NCP observation is filled with Stokes I, Q, U per sample and run
through ``msleak grid``, ``transform``, ``ps`` and ``leakage``. The Stokes -> correlation
conversion is written out here (DP3/CASA convention, linear feeds, V = 0):
XX = I + Q, XY = U + iV, YX = U - iV, YY = I - Q.

Known answers. P = Q + iU is not Hermitian, so each cell (u, tau) of the Hermitian half
gives two P voxels, (u, tau) and (-u, -tau), with the same P_I. For independent circular
Gaussian I and P every voxel's W = P_I / |P~|^2 is a ratio of exponentials, CDF
w / (w + r^2) with r^2 = E|I|^2 / E|Q + iU|^2, so the data and Pareto medians of
L_I = 100 sqrt(W) are 100 r. The symmetric P_Q + P_U (Gamma of shape 2) instead gives
CDF 1 - (1 + w / (2 r^2))^-2 and the median 100 r sqrt(2 (sqrt 2 - 1)) = 0.910 x 100 r.
"""

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.io.products import open_product

R = 0.003
SYMMETRIC = np.sqrt(2 * (np.sqrt(2) - 1))       # median factor of P_Q + P_U


def _ms(path, nchan, chan_width_hz):
    from msleak.verbs.simulate import simulate

    return simulate(path, field="ncp", duration=1.0, nchan=nchan,
                    chan_width=chan_width_hz, stations="CS*HBA*")


def _fill(ms, i, q, u):
    """DATA = correlations of Stokes (i, q, u) (row, chan), V = 0, XX, XY, YX, YY."""
    import casacore.tables as pt

    with pt.table(f"{ms}/POLARIZATION", ack=False) as t:
        assert list(t.getcell("CORR_TYPE", 0)) == [9, 10, 11, 12]   # XX, XY, YX, YY
    with pt.table(str(ms), readonly=False, ack=False) as t:
        t.putcol("DATA", np.stack([i + q, u, u, i - q], axis=-1))


def _gauss(rng, shape, sigma):
    return sigma * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / np.sqrt(2)


def _chain(ms, out, window):
    """grid -> transform -> ps -> leakage through the CLI; the products' paths."""
    paths = {k: out / f"{k}.h5" for k in ("grid", "delay", "ps")}
    runner = CliRunner()
    for args in (["grid", ms, "-o", paths["grid"], "--beam-area-model", "airy"],
                 ["transform", paths["grid"], "-o", paths["delay"], "--window", window],
                 ["ps", paths["delay"], "-o", paths["ps"]],
                 ["leakage", paths["ps"], "-o", out / "leak", "--no-figures"]):
        r = runner.invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output + r.stderr
    paths["stats"] = out / "leak" / "stats.csv"
    return paths


@pytest.fixture(scope="module")
def gaussian_chain(tmp_path_factory):
    """Independent complex Gaussian I, Q, U per sample, E|I|^2 / E|Q + iU|^2 = R^2: the
    whole HBA core, 1 h, 80 channels of 97.7 kHz, window none (independent delays of
    white noise), about 17 000 voxels."""
    d = tmp_path_factory.mktemp("gauss")
    ms = _ms(d / "noise.ms", 80, 97656.25)
    import casacore.tables as pt

    with pt.table(str(ms), ack=False) as t:
        shape = (t.nrows(), 80)
    rng = np.random.default_rng(7)
    _fill(ms, _gauss(rng, shape, R), _gauss(rng, shape, np.sqrt(0.5)),
          _gauss(rng, shape, np.sqrt(0.5)))
    return _chain(ms, d, "none")


def test_gaussian_stokes_medians_are_100_r(gaussian_chain):
    row = next(csv.DictReader(open(gaussian_chain["stats"])))
    ps = open_product(gaussian_chain["ps"], "ps")
    ndelay, ncell = ps.sizes["delay3d"], ps.sizes["cell"]
    assert ncell > 80 and int(row["n_voxels"]) == 2 * ndelay * ncell   # no voxel masked
    # the sample pins the medians to ~1 % (bootstrap), the tolerance is 3 %
    assert float(row["median_err"]) < 0.01 * 100 * R
    assert float(row["pareto_median_err"]) < 0.01 * 100 * R
    assert float(row["median"]) == pytest.approx(100 * R, rel=0.03)
    assert float(row["pareto_median"]) == pytest.approx(100 * R, rel=0.03)
    res = open_product(gaussian_chain["stats"].parent / "leakage.h5", "leakage")
    assert "power3d_P_mirror" in res.attrs["P_P_voxels"]


def test_symmetric_estimator_is_low_by_the_gamma2_factor(gaussian_chain):
    """P_Q + P_U per cell on the same data (computed here from power3d's Q and U)."""
    p3 = open_product(gaussian_chain["ps"], "ps")["power3d"]
    w = p3.sel(stokes="I").values / (p3.sel(stokes="Q").values + p3.sel(stokes="U").values)
    assert 100 * np.sqrt(np.median(w)) == pytest.approx(100 * R * SYMMETRIC, rel=0.03)


def test_mirror_power_is_the_mirrored_voxel_of_the_delay_cube(gaussian_chain):
    """power3d_P_mirror (made from Q~ - i U~ of the cell) equals |P~|^2 read from the
    w-gridded delay cube at (-u, -v) and -tau: the gridded Q and U are Hermitian and the
    relation holds with the code's FFT sign and normalisation."""
    dl = open_product(gaussian_chain["delay"], "delay")
    ps = open_product(gaussian_chain["ps"], "ps")
    p_vis = dl["vis"].sel(stokes="P").values                      # (delay, v, u)
    n, cell = dl.sizes["delay"], dl.attrs["cell_lambda"]
    m = (dl.sizes["u"] - 1) // 2
    iu = np.rint(ps["u_cell"].values / cell).astype(int) + m
    iv = np.rint(ps["v_cell"].values / cell).astype(int) + m
    j_mirror = (n - np.arange(n)) % n            # fftshift order, even n
    assert np.allclose(dl["delay"].values[j_mirror][1:], -dl["delay"].values[1:])
    scale = (ps.attrs["jy2_to_mk2_mpc3"] or 1.0) / dl.attrs["window_norm"]
    direct = np.abs(p_vis[j_mirror][:, 2 * m - iv, 2 * m - iu]) ** 2 * scale
    np.testing.assert_allclose(ps["power3d_P_mirror"].values, direct, rtol=1e-9)
    np.testing.assert_allclose(ps["power3d"].sel(stokes="P").values,
                               np.abs(p_vis[:, iv, iu]) ** 2 * scale, rtol=1e-9)


def test_rotated_polarization_gives_exact_leakage(tmp_path):
    """Q = cos(2 chi) A, U = sin(2 chi) A, I = eps (cos(2 chi) Q + sin(2 chi) U) = eps A per
    sample: the chain is linear and the same for I, Q and U, so both P voxels of every
    pair have |P~|^2 = P_I / eps^2 and L_I = 100 eps in every voxel (to the float32
    rounding of DATA)."""
    ms = _ms(tmp_path / "rot.ms", 20, 195312.5)
    import casacore.tables as pt

    with pt.table(str(ms), ack=False) as t:
        shape = (t.nrows(), 20)
    eps, chi = 0.01, 0.4
    a = _gauss(np.random.default_rng(8), shape, 1.0)
    q, u = np.cos(2 * chi) * a, np.sin(2 * chi) * a
    _fill(ms, eps * (np.cos(2 * chi) * q + np.sin(2 * chi) * u), q, u)
    paths = _chain(ms, tmp_path, "blackman-harris")
    from msleak.leakage import leakage_voxels

    ps = open_product(paths["ps"], "ps")
    L = leakage_voxels(ps).L
    assert L.size == 2 * ps.sizes["delay3d"] * ps.sizes["cell"] > 1000
    np.testing.assert_allclose(L, 100 * eps, rtol=1e-3)
    row = next(csv.DictReader(open(paths["stats"])))
    for col in ("median", "pareto_median", "mean"):
        assert float(row[col]) == pytest.approx(100 * eps, rel=1e-3)
