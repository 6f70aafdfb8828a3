"""The all-sky foreground on HEALPix pixels (msleak.sky.allsky), its SkyH5 file and
``msleak sky OUT.skyh5 --healpix NSIDE``: Burn's slab per pixel, the flat cube's statistics,
reproducibility, the file read back by pyradiosky, units and the command's errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

healpy = pytest.importorskip("healpy")
pyradiosky = pytest.importorskip("pyradiosky")

from msleak.cli import cli  # noqa: E402
from msleak.constants import jy_per_kelvin  # noqa: E402
from msleak.errors import InputError  # noqa: E402
from msleak.sky.allsky import generate_allsky, healpix_to_unit  # noqa: E402
from msleak.sky.faraday import burn_slab, polarized_brightness  # noqa: E402
from msleak.sky.foreground import ForegroundParams, build_box  # noqa: E402
from msleak.sky.spectrum import angular_power_spectrum  # noqa: E402
from msleak.verbs.allsky import make_allsky  # noqa: E402

TINY = ForegroundParams(ncells_los=6)


def _read_skyh5(path):
    """A SkyH5 file read back with pyradiosky directly (not msleak's readers)."""
    return pyradiosky.SkyModel.from_file(str(path))


# --- Burn's slab, pixel by pixel ---------------------------------------------------------

def _expected_uniform(nside, params, freq):
    """Burn's slab at every pixel of a uniform medium, from vector geometry written here: the
    regular field is fixed in space, equal to (east, north, towards us) at the NCP, where
    North points to RA 180 deg and East to RA 90 deg."""
    b_e, b_n, b_par = params.b_regular_ug
    bvec = b_e * np.array([0.0, 1.0, 0.0]) + b_n * np.array([-1.0, 0.0, 0.0]) \
        - b_par * np.array([0.0, 0.0, 1.0])
    r = np.array(healpy.pix2vec(nside, np.arange(12 * nside ** 2))).T       # (npix, 3)
    east = np.cross([0.0, 0.0, 1.0], r)
    east /= np.linalg.norm(east, axis=1)[:, None]
    north = np.cross(r, east)
    towards = -(r @ bvec)
    bperp = bvec[None] - (r @ bvec)[:, None] * r
    chi0 = np.arctan2(bperp @ np.zeros(3) + east @ bvec, north @ bvec) + np.pi / 2
    depth = params.ne_mean_cm3 * towards * params.depth_pc * 0.812
    p0 = params.intrinsic_fraction * np.linalg.norm(bperp, axis=1) ** (
        (params.electron_index + 1) / 2)
    pol = np.array([burn_slab(a, c, f, freq) for a, c, f in zip(p0, chi0, depth)]).T
    ref = np.array([burn_slab(a, c, f, params.ref_freq_hz)
                    for a, c, f in zip(p0, chi0, depth)])
    scale = params.p_rms_k / np.sqrt(np.mean(np.abs(ref) ** 2))
    return pol * scale * ((freq / params.ref_freq_hz) ** -params.beta)[:, None], depth


def test_uniform_slab_is_burn_at_every_pixel():
    """Random fields off, constant n_e and B_par along each line of sight: each pixel's
    Q + iU is Burn's slab; the per-cell integration is exact, so 1e-9 relative to the largest
    |P| (float64 sums over 40 cells) is the tolerance."""
    params = ForegroundParams(ncells_los=40, b_random_rms_ug=0.0, ne_sigma_ln=0.0,
                              ncr_sigma_ln=0.0, b_regular_ug=(1.0, 0.5, 1.0),
                              ne_mean_cm3=0.003)
    freq = 115e6 + 37.5e6 * np.arange(3)
    result = generate_allsky(nside=4, freq_min_hz=115e6, nchan=3, chan_width_hz=37.5e6,
                             seed=0, params=params)
    want, depth = _expected_uniform(4, params, freq)
    got = result.sky.stokes[1] + 1j * result.sky.stokes[2]
    assert np.abs(depth).max() > 2.0                     # real differential rotation:
    assert np.abs(depth).max() * (299792458.0 / 115e6) ** 2 > 2 * np.pi   # turns > 1 rad
    np.testing.assert_allclose(result.faraday_depth, depth, rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(got - want)) < 1e-9 * np.max(np.abs(want))
    assert np.all(result.sky.stokes[[0, 3]] == 0)


# --- the flat cube's statistics ----------------------------------------------------------

#: the matched configuration: one transverse cell per HEALPix pixel of NSIDE 32 (1.83 deg),
#: a flat box of 50 cells (90 deg), 50 cells along the line of sight; a regular field along
#: the line of sight at the NCP only, so that the sky is statistically the same everywhere
NSIDE, CELL, NCELLS = 32, 1.8, 50
STATS_PARAMS = ForegroundParams(b_regular_ug=(0.0, 0.0, 0.2), ncells_los=NCELLS,
                                depth_pc=10.0 * NCELLS)
SEEDS = range(4)


def _slope(ell, cl, lo=6, hi=48):
    use = (ell >= lo) & (ell <= hi) & np.isfinite(cl) & (cl > 0)
    return np.polyfit(np.log(ell[use]), np.log(cl[use]), 1)[0]


@pytest.fixture(scope="module")
def statistics():
    """(flat, sphere) per seed: Faraday-depth std over the box / over the patch, rms |P| at
    150 MHz, slope of the angular power spectrum of P over ell 6-48."""
    flat, sphere = [], []
    for seed in SEEDS:
        box, _ = build_box(STATS_PARAMS, 50, seed)
        p = polarized_brightness(box.amp, box.chi0, box.dphi, np.array([150e6]))[0]
        p *= STATS_PARAMS.p_rms_k / np.sqrt(np.mean(np.abs(p) ** 2))
        ell, cl, _ = angular_power_spectrum(p, math.radians(CELL), nbins=12)
        flat.append((box.faraday_depth()[-1].std(), np.sqrt(np.mean(np.abs(p) ** 2)),
                     _slope(ell, cl)))
        result = generate_allsky(nside=NSIDE, nchan=1, seed=seed, params=STATS_PARAMS,
                                 cell_deg=CELL, box_deg=50 * CELL)
        q, u = result.sky.stokes[1, 0], result.sky.stokes[2, 0]
        patch = healpy.query_disc(NSIDE, healpy.ang2vec(0.0, 90.0, lonlat=True),
                                  math.radians(25 * CELL))
        cls = healpy.anafast(np.stack([np.zeros_like(q), q, -u]), pol=True)
        clp = cls[1] + cls[2]                            # EE + BB: the power of Q + iU
        sphere.append((result.faraday_depth[patch].std(),
                       np.sqrt(np.mean(q[patch] ** 2 + u[patch] ** 2)),
                       _slope(np.arange(clp.size), clp)))
    return np.array(flat), np.array(sphere)


#: 3 x the standard deviation of the difference of the 4-seed means, from the scatter
#: measured over 6 seeds (docs/sky.md): Faraday-depth std 0.9 (flat) and 1.1 (sphere)
#: rad m^-2, patch rms |P| 0.6 K, PS slope 0.34 (flat) and 0.09 (sphere)
TOL_PHI, TOL_PRMS, TOL_SLOPE = 2.1, 0.9, 0.53


def test_faraday_depth_spread_matches_the_flat_cube(statistics):
    flat, sphere = statistics
    assert abs(flat[:, 0].mean() - sphere[:, 0].mean()) < TOL_PHI
    assert sphere[:, 0].mean() > 1.0                       # a real spread, not zero


def test_patch_rms_polarized_brightness_matches_the_flat_cube(statistics):
    flat, sphere = statistics
    np.testing.assert_allclose(flat[:, 1], STATS_PARAMS.p_rms_k, rtol=1e-12)
    assert abs(sphere[:, 1].mean() - flat[:, 1].mean()) < TOL_PRMS


def test_angular_power_slope_matches_the_flat_cube(statistics):
    flat, sphere = statistics
    assert abs(flat[:, 2].mean() - sphere[:, 2].mean()) < TOL_SLOPE
    assert sphere[:, 2].mean() < -0.2                      # red, not white


# --- reproducibility, units, the file ------------------------------------------------------

def test_one_seed_one_sky_bit_for_bit():
    a = generate_allsky(nside=4, nchan=2, seed=11, params=TINY)
    b = generate_allsky(nside=4, nchan=2, seed=11, params=TINY)
    c = generate_allsky(nside=4, nchan=2, seed=12, params=TINY)
    assert np.array_equal(a.sky.stokes, b.sky.stokes)
    assert not np.array_equal(a.sky.stokes, c.sky.stokes)
    fresh = generate_allsky(nside=4, nchan=2, params=TINY)
    again = generate_allsky(nside=4, nchan=2, seed=fresh.meta["SEED"], params=TINY)
    assert np.array_equal(fresh.sky.stokes, again.sky.stokes)


def test_rms_polarized_brightness_over_the_sphere():
    result = generate_allsky(nside=4, nchan=1, seed=3, params=TINY)
    p = np.hypot(result.sky.stokes[1, 0], result.sky.stokes[2, 0])
    assert math.isclose(np.sqrt(np.mean(p ** 2)), TINY.p_rms_k, rel_tol=1e-12)


@pytest.mark.parametrize("units", ["K", "Jy/sr"])
def test_skyh5_reads_back_as_written(tmp_path, units):
    path = tmp_path / "all.skyh5"
    result = make_allsky(path, nside=4, nchan=3, seed=5, units=units, params=TINY)
    model = _read_skyh5(path)
    assert model.component_type == "healpix" and model.spectral_type == "full"
    assert model.nside == 4 and model.hpx_order == "ring" and model.frame == "icrs"
    assert np.array_equal(model.hpx_inds, np.arange(192))
    assert np.array_equal(model.freq_array.to_value("Hz"), result.sky.freq_hz)
    assert model.stokes.unit.to_string() == {"K": "K", "Jy/sr": "Jy / sr"}[units]
    assert np.array_equal(model.stokes.value, result.sky.stokes)
    assert "seed=5" in model.history and "celestial North" in model.history


def test_kelvin_and_jansky_per_steradian_agree():
    """Rayleigh-Jeans per steradian, and the same pixel fluxes through HealpixSky.flux_jy."""
    sky = generate_allsky(nside=2, nchan=3, seed=1, params=TINY).sky
    jy = healpix_to_unit(sky, "Jy/sr")
    per_k = jy_per_kelvin(sky.freq_hz, 1.0)
    np.testing.assert_allclose(jy.stokes, sky.stokes * per_k[None, :, None], rtol=1e-14)
    np.testing.assert_allclose(jy.flux_jy(), sky.flux_jy(), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(healpix_to_unit(jy, "K").stokes, sky.stokes, rtol=1e-13)


@pytest.mark.parametrize("nside", [0, 3, 12, -4])
def test_nside_not_a_power_of_two_is_refused(nside):
    with pytest.raises(InputError, match="nside must be a power of 2"):
        generate_allsky(nside=nside, nchan=1, params=TINY)


# --- the command -------------------------------------------------------------------------

SMALL = ["--nchan", "2", "--ncells-los", "6", "--seed", "2"]


def run(*args):
    return CliRunner().invoke(cli, ["sky", *map(str, args)])


def _one_line_error(res, text):
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and text in lines[0], res.output
    assert "Traceback" not in res.output


def test_command_writes_a_skyh5_file(tmp_path):
    out = tmp_path / "all.skyh5"
    res = run(out, "--healpix", 2, *SMALL, "--units", "Jy/sr")
    assert res.exit_code == 0, res.output
    assert "48 HEALPix pixels (NSIDE 2" in res.output
    model = _read_skyh5(out)
    want = make_allsky(None, nside=2, nchan=2, seed=2, units="Jy/sr",
                       params=ForegroundParams(ncells_los=6))
    assert np.array_equal(model.stokes.value, want.sky.stokes)


@pytest.mark.parametrize("nside", ["3", "100"])
def test_command_refuses_a_bad_nside(tmp_path, nside):
    res = run(tmp_path / "a.skyh5", "--healpix", nside, *SMALL)
    _one_line_error(res, "--healpix must be a power of 2")
    assert not (tmp_path / "a.skyh5").exists()


@pytest.mark.parametrize("flat", [["--npix", "20"], ["--crop", "x.fits"],
                                  ["--phase-centre", "10,20"], ["--fov", "4"]])
def test_command_refuses_flat_options_with_healpix(tmp_path, flat):
    res = run(tmp_path / "a.skyh5", "--healpix", 2, *SMALL, *flat)
    _one_line_error(res, f"{flat[0]} shape a flat cube and cannot be used with --healpix")


def test_command_respects_overwrite(tmp_path):
    out = tmp_path / "all.skyh5"
    out.write_text("keep me")
    _one_line_error(run(out, "--healpix", 2, *SMALL), "exists")
    assert out.read_text() == "keep me"
    assert run(out, "--healpix", 2, *SMALL, "--overwrite").exit_code == 0
    assert _read_skyh5(out).nside == 2


def test_command_refuses_healpix_only_options_on_a_cube(tmp_path):
    _one_line_error(run(tmp_path / "c.fits", "--cell-deg", 1), "--cell-deg applies to")
    _one_line_error(run(tmp_path / "c.fits", "--units", "Jy/sr"), "Jy/sr is for --healpix")
    _one_line_error(run(tmp_path / "a.skyh5", "--healpix", 2, "--units", "Jy/pixel"),
                    "K or Jy/sr")
