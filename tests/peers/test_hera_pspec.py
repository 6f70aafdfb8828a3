"""msleak's delay power spectrum against hera_pspec's on one small HERA MS.

Both codes get the same Measurement Set (four HERA dishes, three 60 s integrations, 32
channels of 195.3 kHz from 135 MHz) whose DATA column holds a point source at the phase
centre with the spectrum S(nu) = S0 + S1 cos(2 pi nu tau0): its delay spectrum is known in
closed form (one peak at tau = 0 and two at +-tau0), and because the source sits at the
phase centre every baseline, time and uv cell sees the same spectrum, so gridding is
trivial. Both use the Blackman-Harris window, the same flat LambdaCDM without radiation
(hera_pspec's cosmology has none), a Gaussian primary beam whose Omega_pp msleak takes as
its beam area, and little h. docs/ps.md "Comparison with hera_pspec" explains every factor.
"""

import warnings

import numpy as np
import pytest

from peers import require

hp = require("hera_pspec", "hera_pspec (HERA's power spectra, msleak[test]) is not installed")
pyuvdata = require("pyuvdata", "pyuvdata (msleak[hera]) is not installed")

import casacore.tables as tables  # noqa: E402
from astropy.coordinates import EarthLocation  # noqa: E402
from scipy.signal import windows  # noqa: E402

import msleak  # noqa: E402
from msleak.constants import BOLTZMANN, SPEED_OF_LIGHT, jy_per_kelvin  # noqa: E402
from msleak.ps.cosmology import cosmo_at, jy2_to_mk2_mpc3, make_cosmology  # noqa: E402

H0, OM0 = 67.66, 0.30966          # Planck18's H0 and Om0 as a flat LambdaCDM, no radiation
NCHAN, TONE_BINS = 32, 6          # channels; tau0 = TONE_BINS / (N dnu), 6 bins from 0
S0, S1 = 1.0, 2.0                 # Jy: equal peaks (S0 at tau = 0, S1 / 2 at +-tau0)
FWHM = np.radians(10.0)           # Gaussian beam: Omega_p = 2 Omega_pp = pi FWHM^2 / (4 ln 2)
OMEGA_P = 2 * np.pi * FWHM ** 2 / (8 * np.log(2))
OMEGA_PP = OMEGA_P / 2
UV_RANGE = (3.0, 20.0)            # wavelengths: the 14.6 m and 29.2 m spacings
FLAT_LCDM = make_cosmology(h0=H0, om0=OM0, tcmb0=0.0)


@pytest.fixture(scope="module")
def hera_ms(tmp_path_factory):
    """The MS, its channel frequencies (Hz) and per-row UVW (m) and antennas."""
    path = tmp_path_factory.mktemp("hera_pspec") / "hera.ms"
    msleak.simulate(path, telescope="hera", stations="HH0,HH1,HH2,HH11", duration=3 / 60,
                    interval=60.0, nchan=NCHAN)
    with tables.table(f"{path}/SPECTRAL_WINDOW", ack=False) as spw:
        freq = spw.getcol("CHAN_FREQ")[0]
    tau0 = TONE_BINS / (NCHAN * (freq[1] - freq[0]))
    spectrum = S0 + S1 * np.cos(2 * np.pi * freq * tau0)
    with tables.table(str(path), readonly=False, ack=False) as t:
        data = np.zeros_like(t.getcol("DATA"))
        data[:, :, 0] = data[:, :, 3] = spectrum  # XX = YY = S(nu): Stokes I only
        t.putcol("DATA", data)
        uvw, a1, a2 = t.getcol("UVW"), t.getcol("ANTENNA1"), t.getcol("ANTENNA2")
    return {"path": path, "freq": freq, "tau0": tau0, "uvw": uvw, "a1": a1, "a2": a2}


def _cell(ms) -> float:
    """Cell size (wavelengths): the 14.6 m East-West spacing at the band centre, so the
    redundant HH0-HH1 and HH1-HH2 baselines sit on a cell centre."""
    fc = 0.5 * (ms["freq"][0] + ms["freq"][-1])
    row = np.flatnonzero((ms["a1"] == 0) & (ms["a2"] == 1))[0]
    return float(np.linalg.norm(ms["uvw"][row]) * fc / SPEED_OF_LIGHT)


@pytest.fixture(scope="module")
def msleak_ps(hera_ms):
    """msleak grid -> transform -> ps of DATA (Blackman-Harris, little h, Omega = Omega_pp)."""
    cube = msleak.grid(hera_ms["path"], column="DATA", cell=_cell(hera_ms),
                       uv_range=UV_RANGE, beam_area=OMEGA_PP)
    delay = msleak.transform(cube, window="blackman-harris")
    return msleak.power_spectrum(delay, h0=H0, om0=OM0, tcmb0=0.0, little_h=True)


def _hera_cosmo():
    return hp.conversions.Cosmo_Conversions(Om_L=1 - OM0, Om_b=0.0, Om_c=OM0, H0=H0)


def _hera_beam():
    """hera_pspec's Gaussian beam; its Omega_p and Omega_pp do not depend on frequency."""
    freqs = np.linspace(125e6, 150e6, 26)
    return hp.pspecbeam.PSpecBeamGauss(FWHM, freqs, cosmo=_hera_cosmo())


@pytest.fixture(scope="module")
def hera_uvp(hera_ms):
    """hera_pspec's delay spectra of every baseline with itself, per time (Jy -> mK with
    its beam, Blackman-Harris, little h)."""
    with pytest.MonkeyPatch.context() as mp, warnings.catch_warnings():
        # pyuvdata's MS reader looks the telescope name up in astropy's site registry,
        # which astropy downloads on first use; tests download nothing, and "HERA" is in
        # pyuvdata's own table of telescopes, which is what it uses then.
        mp.setattr(EarthLocation, "get_site_names", classmethod(lambda cls, *a, **k: []))
        # expected and harmless here: pyuvdata takes HERA's position from that table; it
        # finds the MS's UVW (antenna 2 - antenna 1) opposite to its own baselines and
        # conjugates them (each baseline is crossed with itself: |V|^2 is unchanged);
        # hera_pspec reads pyuvdata's deprecated x_orientation, and casts its window
        # functions (not used here) to real
        for message, category in (
                ("Setting telescope_location to value in known_telescopes", UserWarning),
                ("UVW orientation appears to be flipped", UserWarning),
                ("The Telescope.x_orientation attribute is deprecated", DeprecationWarning),
                ("Casting complex values to real", np.exceptions.ComplexWarning)):
            warnings.filterwarnings("ignore", message=message, category=category)
        uvd = pyuvdata.UVData.from_file(str(hera_ms["path"]), file_type="ms")
        uvd.vis_units = "Jy"  # msleak's DATA is in Jy; the MS has no unit pyuvdata reads
        ds = hp.PSpecData(dsets=[uvd, uvd.copy()], wgts=[None, None], beam=_hera_beam())
        ds.Jy_to_mK()
        bls = sorted(set(zip(uvd.ant_1_array.tolist(), uvd.ant_2_array.tolist())))
        uvp = ds.pspec(bls, bls, (0, 1), [("xx", "xx")], spw_ranges=[(0, NCHAN)],
                       taper="blackman-harris", little_h=True, verbose=False)
    return uvp


def _centre(ms) -> float:
    return 0.5 * (ms["freq"][0] + ms["freq"][-1])


def _msleak_cosmo(freq_hz: float):
    return cosmo_at(freq_hz, FLAT_LCDM)


def _jy_to_mk(freq_hz):
    """msleak's Jy -> mK for a source filling Omega_p (msleak.constants.jy_per_kelvin,
    lambda^2 / (2 k_B Omega_p) K per Jy)."""
    return 1e3 / jy_per_kelvin(freq_hz, OMEGA_P)


def test_cosmology_factors(hera_ms):
    """X = D_c, Y, X^2 Y (h^-3 Mpc^3 per sr Hz), tau -> k_par and baseline -> k_perp.

    Tolerance 1e-8: both integrate the same E(z) (scipy quad, ~1e-10) and hera_pspec's
    21-cm frequency 1420.405751 MHz is 5e-10 below msleak's 1420.405751768 MHz.
    """
    hc, fc = _hera_cosmo(), _centre(hera_ms)
    mc = _msleak_cosmo(fc)
    z, h = hc.f2z(fc), H0 / 100
    assert z == pytest.approx(mc.z, rel=1e-8)
    assert hc.DC(z, little_h=False) == pytest.approx(mc.x_mpc_per_rad, rel=1e-8)
    assert hc.dRpara_df(z, little_h=False) == pytest.approx(mc.y_mpc_per_hz, rel=1e-8)
    assert hc.X2Y(z, little_h=True) == pytest.approx(
        mc.x_mpc_per_rad ** 2 * mc.y_mpc_per_hz * h ** 3, rel=1e-8)
    tau = 1e-6
    assert tau * hc.tau_to_kpara(z, little_h=True) == pytest.approx(mc.k_par(tau) / h,
                                                                    rel=1e-8)
    b_m = 14.6
    assert b_m * hc.bl_to_kperp(z, little_h=True) == pytest.approx(
        mc.k_perp(b_m * fc / SPEED_OF_LIGHT) / h, rel=1e-8)


def test_jy_to_mk_differs_only_by_boltzmann_constant(hera_ms):
    """hera_pspec's Jy -> mK (per channel, its beam's Omega_p) equals msleak's
    (jy_per_kelvin) to 1e-12 once its CODATA 2014 k_B (1.38064852e-23 J/K) is replaced by
    the exact SI value msleak uses (1.380649e-23; ratio 1 + 3.5e-7). msleak's power
    normalisation jy2_to_mk2_mpc3 holds the same conversion: it equals
    B X^2 Y Omega (Jy -> mK over Omega)^2 (1e-12: both are a few float64 operations)."""
    freq = hera_ms["freq"]
    hera = _hera_beam().Jy_to_mK(freq)
    k_ratio = BOLTZMANN / hp.conversions.units.kb
    assert abs(k_ratio - 1) > 1e-7  # the two constants do differ
    np.testing.assert_allclose(hera / k_ratio, _jy_to_mk(freq), rtol=1e-12)
    fc, bandwidth = _centre(hera_ms), NCHAN * (freq[1] - freq[0])
    mc = _msleak_cosmo(fc)
    assert jy2_to_mk2_mpc3(mc, OMEGA_P, bandwidth) == pytest.approx(
        bandwidth * mc.x_mpc_per_rad ** 2 * mc.y_mpc_per_hz * OMEGA_P * _jy_to_mk(fc) ** 2,
        rel=1e-12)


def test_normalisation_window_and_bandwidth(hera_ms, msleak_ps, hera_uvp):
    """The Jy^2 -> mK^2 h^-3 Mpc^3 normalisation, factor by factor.

    hera_pspec: P = |V~_mK|^2 * scalar, scalar = [int dnu (Omega_pp / Omega_p^2)
    (B_pp / B_p^2) / X^2 Y]^-1 with V~ = (1/N) sum w V_mK exp(...) (norm 'I', its delay
    adjustment included); msleak: P = |V~_Jy|^2 / window_norm * jy2_to_mk2_mpc3. The two
    agree when scalar = jy2_to_mk2_mpc3 h^3 / (J_c^2 window_norm), J_c the Jy -> mK factor
    at the band centre.
    """
    fc, freq = _centre(hera_ms), hera_ms["freq"]
    dnu = freq[1] - freq[0]
    taper = hp.pspecbeam.dspec.gen_window("blackman-harris", NCHAN)
    # same window (scipy's symmetric Blackman-Harris) and bandwidth N dnu
    np.testing.assert_allclose(taper, windows.blackmanharris(NCHAN), rtol=0, atol=1e-15)
    assert msleak_ps.attrs["window_norm"] == pytest.approx(np.mean(taper ** 2), rel=1e-12)
    assert msleak_ps.attrs["bandwidth_hz"] == pytest.approx(NCHAN * dnu, rel=1e-12)
    assert msleak_ps.attrs["beam_area_sr"] == pytest.approx(OMEGA_PP, rel=1e-12)
    beam = _hera_beam()
    np.testing.assert_allclose(beam.power_beam_sq_int() / beam.power_beam_int() ** 2,
                               OMEGA_PP / OMEGA_P ** 2, rtol=1e-12)
    h = H0 / 100
    factor = jy2_to_mk2_mpc3(_msleak_cosmo(fc), OMEGA_PP, NCHAN * dnu)
    assert msleak_ps.attrs["jy2_to_mk2_mpc3"] == pytest.approx(factor, rel=1e-12)
    expected = factor * h ** 3 / (_jy_to_mk(fc) ** 2 * np.mean(taper ** 2))
    # hera_pspec integrates 1/X^2 Y times the taper^2 (nearest neighbour) on 2000 points
    # of the band; with the taper that quadrature is off by up to 2.4e-3 depending on the
    # number of points (measured over 1000-5000; -4.6e-4 at the 2000 pspec uses): 1e-3.
    scalar = float(np.ravel(hera_uvp.scalar_array)[0])
    assert scalar == pytest.approx(expected, rel=1e-3)
    # Without a taper its quadrature is smooth, and its band is [nu_0, nu_0 + N dnu]:
    # the scalar equals B Omega_p^2 / Omega_pp times the band's harmonic mean of X^2 Y,
    # computed here with msleak's cosmology (1e-8: the cosmology tolerance; a 101-point
    # trapezoid of a smooth function). That band lies half a channel above the channels'
    # own span, which puts the mean 7.6e-4 below X^2 Y at msleak's band centre.
    band = np.linspace(freq[0], freq[0] + NCHAN * dnu, 101)
    inv = [1 / (c.x_mpc_per_rad ** 2 * c.y_mpc_per_hz * h ** 3)
           for c in map(_msleak_cosmo, band)]
    harmonic = NCHAN * dnu / np.trapezoid(inv, band)
    plain = beam.compute_pspec_scalar(freq[0], freq[0] + NCHAN * dnu, NCHAN, taper="none",
                                      num_steps=2000)
    assert plain == pytest.approx(harmonic * NCHAN * dnu * OMEGA_P ** 2 / OMEGA_PP, rel=1e-8)


def test_k_par_axis(msleak_ps, hera_uvp):
    """Same delays (numpy's fftfreq of N dnu, to 1e-12) and k_par in h Mpc^-1 (1e-8, the
    cosmology tolerance); both take z at the mean channel frequency."""
    np.testing.assert_allclose(hera_uvp.get_dlys(0), msleak_ps["delay3d"].values,
                               rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(hera_uvp.get_kparas(0, little_h=True),
                               msleak_ps["k_par3d"].values, rtol=1e-8, atol=1e-12)


def test_k_perp_of_a_baseline(hera_ms, msleak_ps, hera_uvp):
    """hera_pspec's k_perp of a baseline is its ENU length (m) at the band-centre
    wavelength; msleak's the |b| of the uv cell it is gridded into."""
    fc = _centre(hera_ms)
    mc, h = _msleak_cosmo(fc), H0 / 100
    # one k_perp per (baseline pair, time): the same for every time of a pair
    seps = {}
    for blp, k in zip(hera_uvp.blpair_array, hera_uvp.get_kperps(0, little_h=True)):
        seps.setdefault(hera_uvp.blpair_to_antnums(blp), []).append(k)
    assert all(np.ptp(k) == 0 for k in seps.values())
    seps = {key: k[0] for key, k in seps.items()}
    for (bl1, _bl2), k_hera in seps.items():
        rows = (hera_ms["a1"] == bl1[0]) & (hera_ms["a2"] == bl1[1])
        length = np.linalg.norm(hera_ms["uvw"][rows], axis=1)
        # |UVW| (J2000) is the ENU baseline turned: the same length to 1e-8 (a few
        # 1e-7 m of 15-40 m, the precision of the MS's UVW).
        np.testing.assert_allclose(mc.k_perp(length * fc / SPEED_OF_LIGHT) / h, k_hera,
                                   rtol=1e-8)
    # The cell of the redundant 14.6 m East-West pair: its centre |b| is one cell; the
    # samples' |(u, v)| at the band centre lie within `offset` of it (w left out and
    # earth rotation), which bounds the k_perp difference.
    cell = _cell(hera_ms)
    rows = ((hera_ms["a1"] == 0) & (hera_ms["a2"] == 1)) | (
        (hera_ms["a1"] == 1) & (hera_ms["a2"] == 2))
    b_uv = np.hypot(*hera_ms["uvw"][rows, :2].T) * fc / SPEED_OF_LIGHT
    offset = np.abs(b_uv - cell).max() / cell
    k_cell = msleak_ps["k_perp_cell"].values
    ew = np.argmin(np.abs(k_cell - mc.k_perp(cell) / h))
    assert msleak_ps["v_cell"].values[ew] == 0 and msleak_ps["u_cell"].values[ew] == (
        pytest.approx(cell, rel=1e-12))
    k_hera = seps[((0, 1), (0, 1))]
    assert abs(k_cell[ew] / k_hera - 1) <= offset + 1e-8
    assert offset < 1e-3  # the bound is tight: a cell holds this baseline's samples


def _peaks(delays, tau0):
    """Indices of tau = 0, +tau0 and -tau0 on a delay axis."""
    return [int(np.argmin(np.abs(delays - t))) for t in (0.0, tau0, -tau0)]


def test_power_of_a_known_spectrum(hera_ms, msleak_ps, hera_uvp):
    """Peaks of S0 + S1 cos(2 pi nu tau0) against their closed form, in both codes.

    A spectrum c exp(2 pi i nu tau) on a delay bin gives |V~|^2 = |c|^2 mean(w)^2 there,
    so each peak (c = S0 at 0, S1 / 2 at +-tau0) is 1 Jy^2 mean(w)^2 before the
    normalisation. Tolerance 1e-4: the other peaks are 6 or 12 bins away, where
    Blackman-Harris leaks 1.3e-5 and 0.9e-5 in amplitude, shifting the tau = 0 peak by up
    to 2 x 2 x 1.3e-5 in power (measured -5.2e-5), and the uv cube is single precision
    (5e-8).
    """
    freq, tau0 = hera_ms["freq"], hera_ms["tau0"]
    fc, h = _centre(hera_ms), H0 / 100
    w = windows.blackmanharris(NCHAN)
    peak_jy2 = 1.0 * np.mean(w) ** 2

    # msleak: every used cell (the 14.6 m and 29.2 m East-West cells), all three peaks
    p3d = msleak_ps["power3d"].sel(stokes="I").values  # (delay, cell), mK^2 h^-3 Mpc^3
    assert p3d.shape[1] >= 2
    expected_ms = peak_jy2 / np.mean(w ** 2) * msleak_ps.attrs["jy2_to_mk2_mpc3"] * h ** 3
    idx = _peaks(msleak_ps["delay3d"].values, tau0)
    np.testing.assert_allclose(p3d[idx], expected_ms, rtol=1e-4)

    # hera_pspec: every baseline and time; it converts each channel with its own
    # lambda^2, so its peak is |(1/N) sum w J(nu)|^2 (times the scalar)
    jy_mk = _hera_beam().Jy_to_mK(freq)
    scalar = float(np.ravel(hera_uvp.scalar_array)[0])
    expected_hera = np.mean(w * jy_mk) ** 2 * scalar
    idx = _peaks(hera_uvp.get_dlys(0), tau0)
    for blp in hera_uvp.get_blpairs():
        p = hera_uvp.get_data((0, blp, ("xx", "xx")))  # (time, delay)
        assert np.abs(p.imag).max() < 1e-6 * expected_hera
        np.testing.assert_allclose(p.real[:, idx], expected_hera, rtol=1e-4)

    # measured hera_pspec / msleak = (per-channel Jy -> mK) x (its scalar / msleak's
    # normalisation) x (k_B ratio)^2, each factor computed above; 2e-4 = the two peak
    # tolerances. Together within 1e-3 of 1.
    ratio = hera_uvp.get_data((0, ((0, 1), (0, 1)), ("xx", "xx"))).real[0, idx] / p3d[
        _peaks(msleak_ps["delay3d"].values, tau0), 0]
    np.testing.assert_array_less(np.abs(ratio - 1), 1e-3)
    per_channel = (np.mean(w * jy_mk) / (np.mean(w) * _hera_beam().Jy_to_mK(fc)[0])) ** 2
    norm_ratio = scalar / (msleak_ps.attrs["jy2_to_mk2_mpc3"] * h ** 3
                           / (_jy_to_mk(fc) ** 2 * np.mean(w ** 2)))
    k_b2 = (BOLTZMANN / hp.conversions.units.kb) ** 2
    np.testing.assert_allclose(ratio, per_channel * norm_ratio * k_b2, rtol=2e-4)
