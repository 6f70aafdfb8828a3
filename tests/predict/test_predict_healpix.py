"""predict of all-sky HEALPix skies: every pixel above the horizon, each a point source at
its centre (docs/predict.md, "All-sky HEALPix skies").

* one lit pixel equals a point source at the pixel centre carrying the pixel's flux
  (Rayleigh-Jeans, written here), through no beam, the dipole and the LOFAR beam: the
  visibilities and their leaked Stokes I per baseline to 1e-10;
* a uniform Q sky on the autocorrelations (u = v = w = 0): without a beam exactly half
  the sphere's pixels (HEALPix pixel centres come in antipodal pairs), and the cap above
  30 deg to the pixelization; through the dipole beam, the integral of its Mueller element
  over the visible hemisphere computed here with astropy alone;
* a pixel below ``min_elevation`` (found with astropy) contributes exactly nothing, also
  when it rises during the observation, also on rows predicted from their own UVW;
  ``extent`` keeps the pixels within it; both are recorded with the column;
* the command line, and its one-line errors.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from ms_helpers import C, channel_freqs, one_error_line, phase_centre, table
from msleak.cli import cli
from msleak.errors import InputError
from msleak.sky.healpix import HealpixSky
from msleak.sky.sources import PointSources
from msleak.verbs.predict import predict
from msleak.verbs.simulate import simulate

K_B = 1.380649e-23
NSIDE = 16
NPIX = 12 * NSIDE**2


@pytest.fixture(scope="module")
def ms(tmp_path_factory):
    """Three LOFAR HBA fields with autocorrelations, 3C196 around transit, 4 x 300 s, two
    channels 1 MHz apart."""
    return simulate(tmp_path_factory.mktemp("hp") / "hp.ms", field="3c196",
                    duration=4 * 300 / 3600, interval=300.0, freq_min=150e6, nchan=2,
                    chan_width=1e6, stations="CS001HBA0,CS002HBA0,CS003HBA0",
                    autocorrelations=True)


def _centres(order="ring"):
    """ICRS (ra, dec) rad of every pixel centre (astropy-healpix)."""
    from astropy_healpix import healpix_to_lonlat

    lon, lat = healpix_to_lonlat(np.arange(NPIX), NSIDE, order=order)
    return lon.to_value("rad"), lat.to_value("rad")


def _elevations(ms, ra, dec) -> np.ndarray:
    """(ntime, npix) elevation (deg) of J2000 directions seen from the mean antenna
    position at the MS's times (astropy AltAz, no refraction)."""
    import astropy.units as u
    from astropy.coordinates import FK5, AltAz, EarthLocation, SkyCoord
    from astropy.time import Time

    with table(f"{ms}/ANTENNA") as t:
        centre = t.getcol("POSITION").mean(axis=0)
    with table(ms) as t:
        times = np.unique(t.getcol("TIME"))
    loc = EarthLocation.from_geocentric(*centre, unit=u.m)
    sky = SkyCoord(ra=ra * u.rad, dec=dec * u.rad, frame=FK5(equinox="J2000"))
    return np.stack([sky.transform_to(AltAz(obstime=Time(t / 86400, format="mjd",
                                                         scale="utc"), location=loc)).alt.deg
                     for t in times])


def _sky(stokes_k: np.ndarray, freq, order="ring", unit="K") -> HealpixSky:
    return HealpixSky(nside=NSIDE, order=order, pixels=np.arange(NPIX), freq_hz=freq,
                      stokes=stokes_k, unit=unit)


def _jy_per_k(freq) -> np.ndarray:
    """Rayleigh-Jeans flux (Jy) of 1 K over one pixel, 2 k nu^2 / c^2 * 4 pi / (12 NSIDE^2)."""
    return 2 * K_B * np.asarray(freq) ** 2 / C**2 * (4 * np.pi / NPIX) / 1e-26


def _run(ms, sky, **kw):
    kw = {"beam": "none", "double": True, "scheduler": "sync", **kw}
    return predict(str(ms), sky, column=None, **kw)


def _stokes_i(vis) -> np.ndarray:
    return 0.5 * (vis.values[..., 0] + vis.values[..., 3])


# ----------------------------------------------------------------------------- a pixel


@pytest.mark.parametrize("beam", ["none", "dipole", "everybeam"])
def test_one_lit_pixel_is_a_point_source_at_its_centre(ms, beam):
    freq = channel_freqs(ms)
    ra, dec = _centres("nested")
    ra0, dec0 = phase_centre(ms)
    # a pixel about 10 deg from the phase centre, where the beam leaks
    sep = np.arccos(np.sin(dec) * np.sin(dec0) + np.cos(dec) * np.cos(dec0) * np.cos(ra - ra0))
    lit = int(np.argmin(np.abs(sep - np.radians(10.0))))
    stokes = np.zeros((4, freq.size, NPIX))
    stokes[1:3, :, lit] = [[3.0, -1.0], [2.0, 4.0]]         # Q, U (K); I = V = 0
    healpix = _run(ms, _sky(stokes, freq, order="nested"), beam=beam)
    flux = np.zeros((1, freq.size, 4))
    flux[0, :, 1:3] = (stokes[1:3, :, lit] * _jy_per_k(freq)).T
    point = _run(ms, PointSources(ra=ra[lit:lit + 1], dec=dec[lit:lit + 1], freq=freq,
                                  stokes=flux), beam=beam)
    peak = np.abs(point.values).max()
    assert peak > 0
    np.testing.assert_allclose(healpix.values, point.values, rtol=0, atol=1e-10 * peak)
    leaked = _stokes_i(point)
    if beam != "none":
        assert np.abs(leaked).max() > 1e-4 * peak              # the beam leaks Q, U into I
    np.testing.assert_allclose(_stokes_i(healpix), leaked, rtol=0,
                               atol=1e-10 * max(np.abs(leaked).max(), 1e-300))


# ----------------------------------------------------------------------------- uniform Q


def _autocorrelations(vis) -> np.ndarray:
    return np.flatnonzero(vis.antenna1.values == vis.antenna2.values)


@pytest.mark.parametrize("min_elevation,tolerance", [(0.0, 1e-12), (30.0, 1e-2)])
def test_uniform_q_without_beam_sums_the_visible_cap(ms, min_elevation, tolerance):
    """XX = Q Omega(cap), YY = -XX, XY = YX = 0 on every autocorrelation; Omega = 2 pi
    (1 - sin(min_elevation)). The horizon holds exactly half the pixels (their centres
    come in antipodal pairs); above 30 deg the pixelization leaves 4e-3 at NSIDE 16."""
    freq = channel_freqs(ms)
    stokes = np.zeros((4, freq.size, NPIX))
    stokes[1] = 1.0                                            # 1 Jy/sr of Q
    vis = _run(ms, _sky(stokes, freq, unit="Jy/sr"), min_elevation=min_elevation)
    auto = vis.values[_autocorrelations(vis)]
    cap = 2 * np.pi * (1 - np.sin(np.radians(min_elevation)))
    np.testing.assert_allclose(auto[..., 0], cap, rtol=tolerance)
    np.testing.assert_allclose(auto[..., 3], -auto[..., 0], rtol=1e-12)
    assert np.abs(auto[..., 1:3]).max() < 1e-12 * cap


def _dipole_integral(ms, station: int, time_s: float, freq: float, diameter: float,
                     nalt: int = 48, naz: int = 192) -> np.ndarray:
    """(2, 2) integral over the sky above the station's horizon of A^2 [(a.n)(b.n) -
    (a.e)(b.e)] (sr), a, b the dipoles along the station's North and East, n, e the sky's
    J2000 North and East there (astropy finite differences), A the Airy pattern of the
    dish ``diameter`` (m) about the phase centre: the XX, XY, YX, YY of a uniform 1 Jy/sr
    Q sky (docs/beam.md, "The dipole model"). Gauss-Legendre in elevation, uniform in
    azimuth; it settles to about 2.5e-4 of the largest element (48 x 192 against 96 x 384
    and 192 x 768 nodes): the sky's basis turns round the celestial pole, where a uniform
    Q is not defined, within one cell."""
    import astropy.units as u
    from astropy.coordinates import FK5, AltAz, EarthLocation, SkyCoord
    from astropy.time import Time
    from scipy.special import j1

    with table(f"{ms}/ANTENNA") as t:
        loc = EarthLocation.from_geocentric(*t.getcol("POSITION")[station], unit=u.m)
    frame = AltAz(obstime=Time(time_s / 86400, format="mjd", scale="utc"), location=loc)
    node, weight = np.polynomial.legendre.leggauss(nalt)
    alt, az = np.meshgrid((node + 1) * np.pi / 4, np.arange(naz) * 2 * np.pi / naz,
                          indexing="ij")
    dw = ((weight * np.pi / 4)[:, None] * np.cos(alt) * 2 * np.pi / naz).ravel()
    alt, az = alt.ravel(), az.ravel()
    s = np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], -1)
    j2000 = SkyCoord(az=az * u.rad, alt=alt * u.rad, frame=frame).transform_to(
        FK5(equinox="J2000"))
    ra, dec = j2000.ra.rad, j2000.dec.rad

    def enu(r, d):
        c = SkyCoord(ra=r * u.rad, dec=d * u.rad, frame=FK5(equinox="J2000")).transform_to(frame)
        return np.stack([np.cos(c.alt.rad) * np.sin(c.az.rad),
                         np.cos(c.alt.rad) * np.cos(c.az.rad), np.sin(c.alt.rad)], -1)

    h = 1e-6
    north = enu(ra, dec + h) - enu(ra, dec - h)
    east = enu(ra + h / np.cos(dec), dec) - enu(ra - h / np.cos(dec), dec)
    north /= np.linalg.norm(north, axis=1)[:, None]
    east /= np.linalg.norm(east, axis=1)[:, None]
    pointing = enu(np.array([phase_centre(ms)[0]]), np.array([phase_centre(ms)[1]]))[0]
    x = np.pi * diameter * freq * np.sin(np.arccos(np.clip(s @ pointing, -1, 1))) / C
    airy2 = np.where(x < 1e-8, 1.0, 2 * j1(x) / np.maximum(x, 1e-300)) ** 2
    dipoles = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])      # X North, Y East (ENU)
    pn, pe = north @ dipoles.T, east @ dipoles.T                 # (npoint, 2)
    return np.einsum("k,ka,kb->ab", dw * airy2, pn, pn) - np.einsum(
        "k,ka,kb->ab", dw * airy2, pe, pe)


def test_uniform_q_through_a_dipole_equals_the_beam_integral(ms):
    """A uniform 1 K Q sky through crossed dipoles with a 1 m Airy factor (broad: 0.6 at
    the horizon), no centre correction, on the autocorrelation of the first station at the
    first time: equal to _dipole_integral times 2 k nu^2 / c^2 to 1e-3 of the largest
    element. Against the finest quadrature (192 x 768) the sum over the pixel centres
    differs by 2.1e-4 at NSIDE 16 (pixels straddle the horizon, and a uniform Q turns round
    the celestial pole within one pixel), 6e-5 at 32, 5e-5 at 64; against the 48 x 192
    quadrature used here by 5e-5. A Q that did not turn with the basis, swapped dipoles or
    a wrong flux scale fail by O(1)."""
    freq = channel_freqs(ms)
    stokes = np.zeros((4, freq.size, NPIX))
    stokes[1] = 1.0
    vis = _run(ms, _sky(stokes, freq), beam="dipole", diameter=1.0, centre_correction=False)
    row = _autocorrelations(vis)[0]
    station = int(vis.antenna1.values[row])
    with table(ms) as t:
        first = float(np.unique(t.getcol("TIME"))[0])
    assert float(vis.time.values[row]) == first
    expected = _dipole_integral(ms, station, first, freq[0], 1.0) * (
        2 * K_B * freq[0] ** 2 / C**2 / 1e-26)
    got = vis.values[row, 0].reshape(2, 2)
    scale = np.abs(expected).max()
    print(f"dipole integral (Jy): {expected.ravel()}, msleak - integral relative to the "
          f"largest: {(got.real - expected).ravel() / scale}")
    assert np.abs(got.imag).max() < 1e-12 * scale
    np.testing.assert_allclose(got.real, expected, rtol=0, atol=1e-3 * scale)


@pytest.mark.parametrize("field", ["ncp", "3c196"])
def test_blocks_of_pixels_add_up_to_the_sky(tmp_path, field, monkeypatch):
    """The sum over the pixels is the same whatever the size of the blocks the beam is
    evaluated in (the default, and a few pixels at a time): each block's centre
    correction is the beam at the phase centre evaluated with that block's pixels, which
    at the NCP spread over more than 80 deg from their mean. A random Q/U sky through the
    LOFAR beam with the correction, in double precision, to 1e-6 of the peak: each block
    converts its directions to ITRF through its own fitted map (within 5e-7 rad of
    casacore). Before the widest maps were fitted over the whole sphere, the NCP's blocks
    differed by 0.1 of the peak."""
    from msleak.verbs import predict_chunks

    ms = simulate(tmp_path / "b.ms", field=field, duration=2 * 600 / 3600, interval=600.0,
                  freq_min=150e6, nchan=2, chan_width=1e6, stations="CS001HBA0,CS002HBA0,"
                  "CS003HBA0,CS004HBA0")
    freq = channel_freqs(ms)
    stokes = np.zeros((4, freq.size, NPIX))
    stokes[1:3] = np.random.default_rng(7).normal(size=(2, freq.size, NPIX))
    whole = _run(ms, _sky(stokes, freq), beam="everybeam")
    for name in ("PIXEL_BEAM_BYTES", "MIN_PIXEL_BEAM_BYTES"):   # a few pixels a block
        monkeypatch.setattr(predict_chunks, name, 200_000)
    blocks = _run(ms, _sky(stokes, freq), beam="everybeam")
    peak = np.abs(whole.values).max()
    np.testing.assert_allclose(blocks.values, whole.values, rtol=0, atol=1e-6 * peak)


# ----------------------------------------------------------------------------- horizon


def _crossing(elev: np.ndarray, low: float, high: float) -> tuple[int, float, int]:
    """(pixel, threshold, k): a pixel between ``low`` and ``high`` deg that moves most in
    elevation between times k and k + 1, and the threshold midway."""
    k = 1
    step = np.abs(elev[k + 1] - elev[k])
    band = (elev.min(axis=0) > low) & (elev.max(axis=0) < high)
    pixel = int(np.flatnonzero(band)[np.argmax(step[band])])
    return pixel, float(0.5 * (elev[k, pixel] + elev[k + 1, pixel])), k


@pytest.mark.parametrize("beam", ["none", "everybeam"])
def test_pixel_below_min_elevation_contributes_nothing(ms, beam):
    """A pixel always 20 deg below the horizon gives exact zeros; one that crosses
    ``min_elevation`` between two times gives exact zeros at the times it is below and its
    point source's visibilities at the others; with a pixel that stays up, the rows where
    the other is below are those of that pixel alone (exactly without a beam; through the
    LOFAR beam to 1e-7: its J2000 -> ITRF map is fitted over the directions evaluated
    together, which then differ)."""
    freq = channel_freqs(ms)
    ra, dec = _centres()
    elev = _elevations(ms, ra, dec)
    high = int(np.argmax(elev.min(axis=0)))                    # near the zenith
    low = int(np.flatnonzero(elev.max(axis=0) < -20.0)[0])     # always well below
    rising, threshold, k = _crossing(elev, 10.0, 30.0)
    assert abs(elev[k + 1, rising] - elev[k, rising]) > 0.1   # margins >> 20" aberration

    def sky_of(*pixels):
        stokes = np.zeros((4, freq.size, NPIX))
        stokes[1:3, :, list(pixels)] = 1.0
        return _sky(stokes, freq)

    assert np.all(_run(ms, sky_of(low), beam=beam).values == 0)
    alone = _run(ms, sky_of(rising), beam=beam, min_elevation=threshold)
    with table(ms) as t:
        times = np.unique(t.getcol("TIME"))
    up = elev[np.searchsorted(times, alone.time.values), rising] >= threshold
    assert up.any() and not up.all()
    assert np.all(alone.values[~up] == 0)
    flux = np.zeros((1, freq.size, 4))
    flux[0, :, 1:3] = _jy_per_k(freq)[:, None]
    point = _run(ms, PointSources(ra=ra[[rising]], dec=dec[[rising]], freq=freq,
                                  stokes=flux), beam=beam)
    peak = np.abs(point.values).max()
    np.testing.assert_allclose(alone.values[up], point.values[up], rtol=0, atol=1e-10 * peak)
    one = _run(ms, sky_of(high), beam=beam, min_elevation=threshold)
    both = _run(ms, sky_of(high, low, rising), beam=beam, min_elevation=threshold)
    tolerance = 0 if beam == "none" else 1e-7 * np.abs(one.values).max()
    np.testing.assert_allclose(both.values[~up], one.values[~up], rtol=0, atol=tolerance)
    assert np.abs(both.values[up] - one.values[up]).max() > 1e-3 * peak


@pytest.mark.parametrize("beam", ["none", "dipole"])
def test_rows_with_their_own_uvw_keep_the_horizon(ms, tmp_path, beam, monkeypatch):
    """Rows whose UVW are moved by 5 cm are predicted per baseline: there too a lit pixel
    equals its point source, one rising through ``min_elevation`` gives exact zeros while
    below it and its point source's visibilities once above, and one always below the
    horizon gives zeros."""
    import shutil

    from msleak.predict import chunks

    summed = []
    per_baseline = chunks.predict_rows
    monkeypatch.setattr(chunks, "predict_rows", lambda jones, tidx, *a, **k: (
        summed.append(np.size(tidx)), per_baseline(jones, tidx, *a, **k))[1])
    moved = shutil.copytree(ms, tmp_path / "moved.ms")
    with table(moved, readonly=False) as t:
        uvw = t.getcol("UVW")
        rows = np.flatnonzero(t.getcol("ANTENNA1") != t.getcol("ANTENNA2"))[::2]
        uvw[rows] += [0.05, -0.03, 0.02]
        t.putcol("UVW", uvw)
    freq = channel_freqs(moved)
    ra, dec = _centres()
    elev = _elevations(moved, ra, dec)
    high = int(np.argmax(elev.min(axis=0)))
    low = int(np.flatnonzero(elev.max(axis=0) < -20.0)[0])
    rising, threshold, _ = _crossing(elev, 10.0, 30.0)
    flux = np.zeros((1, freq.size, 4))
    flux[0, :, 1:3] = 2.0 * _jy_per_k(freq)[:, None]
    for pixel, limit in ((high, 0.0), (rising, threshold)):
        stokes = np.zeros((4, freq.size, NPIX))
        stokes[1:3, :, [pixel, low]] = 2.0
        healpix = _run(moved, _sky(stokes, freq), beam=beam, min_elevation=limit)
        point = _run(moved, PointSources(ra=ra[[pixel]], dec=dec[[pixel]], freq=freq,
                                         stokes=flux), beam=beam)
        with table(moved) as t:
            times = np.unique(t.getcol("TIME"))
        up = elev[np.searchsorted(times, healpix.time.values), pixel] >= limit
        assert np.all(healpix.values[~up] == 0)
        peak = np.abs(point.values).max()
        np.testing.assert_allclose(healpix.values[up], point.values[up], rtol=0,
                                   atol=1e-10 * peak)
        assert np.isin(np.flatnonzero(up), rows).any()           # moved rows among them
    assert up.any() and not up.all()
    assert sum(summed) >= 2 * rows.size                 # they were summed per baseline


def test_extent_keeps_the_pixels_within_it(ms, tmp_path):
    import astropy.units as u
    from astropy.coordinates import SkyCoord

    freq = channel_freqs(ms)
    ra, dec = _centres()
    rng = np.random.default_rng(5)
    stokes = np.zeros((4, freq.size, NPIX))
    stokes[1:3] = rng.normal(size=(2, freq.size, NPIX))
    ra0, dec0 = phase_centre(ms)
    sep = SkyCoord(ra * u.rad, dec * u.rad).separation(SkyCoord(ra0 * u.rad, dec0 * u.rad)).deg
    inside = stokes.copy()
    inside[:, :, sep > 40.0] = 0
    assert 0 < np.count_nonzero(sep <= 40.0) < NPIX // 4
    cut = _run(ms, _sky(stokes, freq), extent=40.0)
    np.testing.assert_allclose(cut.values, _run(ms, _sky(inside, freq)).values, rtol=0,
                               atol=1e-10 * np.abs(cut.values).max())
    # recorded with the column
    target = tmp_path / "rec.ms"
    import shutil

    shutil.copytree(ms, target)
    predict(str(target), _sky(stokes, freq), column="MODEL_HP", beam="none", extent=40.0,
            min_elevation=5.0, scheduler="sync")
    with table(target) as t:
        state = t.getcolkeyword("MODEL_HP", "MSLEAK_PREDICT")
    assert state["extent_deg"] == 40.0 and state["min_elevation_deg"] == 5.0
    assert state["flat_spectrum"] is False or state["flat_spectrum"] == 0


# ----------------------------------------------------------------------------- errors, CLI


@pytest.mark.parametrize("kwargs,words", [
    ({"min_elevation": 90.0}, "min_elevation must be in [-90, 90)"),
    ({"extent": 0.0}, "extent must be in (0, 180]"),
    ({"extent": [10.0, 20.0]}, "`extent` is given 2 times for 1 `sky`"),
    ({"method": "degrid"}, "is a HEALPix sky"),
])
def test_verb_refuses_bad_settings(ms, kwargs, words):
    freq = channel_freqs(ms)
    with pytest.raises(InputError) as err:
        _run(ms, _sky(np.ones((4, freq.size, NPIX)), freq), **kwargs)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_one_map_off_the_channels_names_flat_spectrum(ms):
    freq = channel_freqs(ms)
    one = HealpixSky(nside=NSIDE, order="ring", pixels=np.arange(NPIX), freq_hz=[140e6],
                     stokes=np.ones((4, 1, NPIX)))
    with pytest.raises(InputError, match="pass flat_spectrum"):
        _run(ms, one)
    flat = HealpixSky(nside=NSIDE, order="ring", pixels=np.arange(NPIX), freq_hz=[140e6],
                      stokes=np.ones((4, 1, NPIX)), flat=True)
    tabulated = _sky(np.ones((4, freq.size, NPIX)), freq)
    np.testing.assert_array_equal(_run(ms, flat).values, _run(ms, tabulated).values)


def _skyh5(path, freq):
    import astropy.units as u
    from pyradiosky import SkyModel

    stokes = np.zeros((4, freq.size, NPIX))
    stokes[1] = 1.0
    SkyModel(nside=NSIDE, hpx_inds=np.arange(NPIX), stokes=stokes * u.K, spectral_type="full",
             freq_array=freq * u.Hz, frame="icrs", hpx_order="ring").write_skyh5(str(path))
    return path


def test_cli_predicts_a_skyh5_sky_with_extent_and_min_elevation(ms, tmp_path):
    import shutil

    target = shutil.copytree(ms, tmp_path / "cli.ms")
    sky = _skyh5(tmp_path / "allsky.skyh5", channel_freqs(ms))
    result = CliRunner().invoke(cli, ["predict", str(target), "--sky", str(sky), "--beam",
                                      "none", "--extent", "60", "--min-elevation", "10",
                                      "--double"])
    assert result.exit_code == 0, result.output
    with table(target) as t:
        written = t.getcol("MODEL_DATA")
    expected = _run(target, _sky(np.stack([np.zeros((2, NPIX)), np.ones((2, NPIX)),
                                           np.zeros((2, NPIX)), np.zeros((2, NPIX))]),
                                 channel_freqs(ms)), extent=60.0, min_elevation=10.0)
    np.testing.assert_allclose(written, expected.values, rtol=1e-6,
                               atol=1e-6 * np.abs(expected.values).max())


@pytest.mark.parametrize("args,words", [
    (["--min-elevation", "95"], "--min-elevation must be in [-90, 90)"),
    (["--extent", "-3"], "--extent must be in (0, 180]"),
    (["--method", "degrid"], "use --method direct or auto"),
])
def test_cli_errors_are_one_line(ms, tmp_path, args, words):
    sky = _skyh5(tmp_path / "allsky.skyh5", channel_freqs(ms))
    result = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--beam", "none",
                                      *args])
    assert words in one_error_line(result)
