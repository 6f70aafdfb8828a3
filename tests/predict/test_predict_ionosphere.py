"""``msleak predict --ionosphere``: ionospheric Faraday rotation per station in front of the
beam, against answers known in advance: a constant RM equals the sky turned by
2 RM lambda^2 channel by channel (with and without a beam and its centre correction, direct
and degridded), and RMs that differ between stations equal an independent sum with a
rotation matrix on each side of the brightness."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from casa_ms import build_ms
from ms_helpers import C, channel_freqs, direct_dft, lm_to_radec, one_error_line, \
    phase_centre, table
from msleak.beam.ionosphere import RANDOM_RM_MEAN, RANDOM_RM_RMS, faraday_rotation, random_rm
from msleak.cli import cli
from msleak.errors import InputError
from msleak.sky.sources import PointSources
from msleak.verbs.predict import predict

NCHAN = 4


@pytest.fixture(scope="module")
def ms(tmp_path_factory):
    return build_ms(tmp_path_factory.mktemp("iono") / "iono.ms", ntime=3, nchan=NCHAN)


def _times(ms):
    with table(ms) as t:
        return np.unique(t.getcol("TIME"))


def _names(ms):
    with table(f"{ms}/ANTENNA") as t:
        return [str(n) for n in t.getcol("NAME")]


def _sources(ms):
    """Three polarized sources near the phase centre: (ra, dec, I, Q, U, V)."""
    ra0, dec0 = phase_centre(ms)
    out = []
    for (l, m), (i, q, u) in zip([(0.0, 0.0), (0.02, -0.01), (-0.015, 0.03)],
                                 [(2.0, 0.7, -0.4), (1.0, -0.3, 0.5), (0.5, 0.2, 0.1)]):
        ra, dec = lm_to_radec(ra0, dec0, l, m)
        out.append((float(ra), float(dec), i, q, u, 0.0))
    return out


def _tabulated(sources, freq, rm=0.0):
    """PointSources on the channels ``freq``, Q + iU turned by exp(2i rm lambda^2)."""
    turn = np.exp(2j * rm * (C / freq) ** 2)
    iquv = []
    for _, _, i, q, u, v in sources:
        p = (q + 1j * u) * turn
        iquv.append(np.stack([np.full(freq.size, i), p.real, p.imag,
                              np.full(freq.size, v)], axis=-1))
    ra, dec = (np.array([s[k] for s in sources]) for k in (0, 1))
    return PointSources(ra=ra, dec=dec, freq=freq, stokes=np.array(iquv))


def _rm_table(path, rows):
    path.write_text("time,station,rm\n" + "".join(f"{t},{s},{r}\n" for t, s, r in rows))
    return path


def _constant(ms, tmp_path, rm):
    times = _times(ms)
    return _rm_table(tmp_path / "rm.csv", [(times[0], "*", rm), (times[-1], "*", rm)])


@pytest.mark.parametrize("beam", ["none", "dipole"])
def test_a_constant_rm_equals_the_turned_sky(ms, tmp_path, beam):
    freq, rm = channel_freqs(ms), 1.7
    sources = _sources(ms)
    turned = predict(ms, _tabulated(sources, freq, rm), column=None, beam=beam, double=True)
    iono = predict(ms, _tabulated(sources, freq), column=None, beam=beam, double=True,
                   ionosphere=_constant(ms, tmp_path, rm))
    plain = predict(ms, _tabulated(sources, freq), column=None, beam=beam, double=True)
    peak = np.abs(turned.values).max()
    np.testing.assert_allclose(iono.values, turned.values, rtol=0, atol=1e-12 * peak)
    assert np.abs(iono.values - plain.values).max() > 0.1 * peak   # the rotation is there


def test_rms_that_differ_between_stations(ms, tmp_path):
    """V_pq = R_p (sum_s B_s e^...) R_q^T without a beam, R_p = R(RM_p lambda^2)."""
    freq, times, names = channel_freqs(ms), _times(ms), _names(ms)
    rng = np.random.default_rng(4)
    table_rows, rm = [], {}
    for name in names:
        rm[name] = rng.uniform(-2.0, 2.0, times.size)
        table_rows += [(t, name, r) for t, r in zip(times, rm[name])]
    csv = _rm_table(tmp_path / "stations.csv", table_rows)
    sources = _sources(ms)
    got = predict(ms, _tabulated(sources, freq), column=None, beam="none", double=True,
                  ionosphere=csv)
    with table(ms) as t:
        a1, a2, time = t.getcol("ANTENNA1"), t.getcol("ANTENNA2"), t.getcol("TIME")
    sky = direct_dft(ms, sources).reshape(-1, freq.size, 2, 2)
    it = np.searchsorted(times, time)
    rm_rows = np.array([rm[n] for n in names])
    rot = faraday_rotation(rm_rows, freq)                 # (station, time, chan, 2, 2)
    expected = (rot[a1, it] @ sky @ np.swapaxes(rot[a2, it], -1, -2)).reshape(-1, freq.size, 4)
    order = got.coords["row"].values
    np.testing.assert_allclose(got.values, expected[order], rtol=0,
                               atol=1e-11 * np.abs(expected).max())


def test_degridded_pixel_sky_keeps_the_rotation(small_lofar_ms, tmp_path):
    from msleak.sky.cube import convert_units
    from msleak.sky.foreground import generate_foreground_cube

    freq = channel_freqs(small_lofar_ms)
    cube = convert_units(generate_foreground_cube(
        npix=48, fov_deg=6.0, freq_min_hz=float(freq[0]), nchan=freq.size,
        chan_width_hz=float(freq[1] - freq[0]), phase_centre=phase_centre(small_lofar_ms),
        seed=2), "Jy/pixel")
    csv = _constant(small_lofar_ms, tmp_path, -0.8)
    kw = dict(column=None, beam="dipole", double=True, ionosphere=csv)
    direct = predict(small_lofar_ms, cube, method="direct", **kw).values
    degrid = predict(small_lofar_ms, cube, method="degrid", epsilon=1e-6, **kw).values
    stokes_i = lambda v: 0.5 * (v[..., 0] + v[..., 3])                    # noqa: E731
    assert np.sqrt(np.mean(np.abs(degrid - direct) ** 2)) \
        <= 1e-6 * np.sqrt(np.mean(np.abs(direct) ** 2))
    assert np.sqrt(np.mean(np.abs(stokes_i(degrid) - stokes_i(direct)) ** 2)) \
        <= 1e-6 * np.sqrt(np.mean(np.abs(stokes_i(direct)) ** 2))


def test_random_screen_is_reproducible_and_as_stated(ms):
    times = np.arange(0.0, 3600.0, 10.0) + 5e9
    a, b = random_rm(times, 7), random_rm(times, 7)
    np.testing.assert_array_equal(a.rm, b.rm)
    assert not np.array_equal(a.rm, random_rm(times, 8).rm)
    series = a.at(["any"], times)[0]
    assert series.mean() == pytest.approx(RANDOM_RM_MEAN, abs=1e-12)
    assert series.std() == pytest.approx(RANDOM_RM_RMS, rel=1e-9)
    one = predict(ms, _tabulated(_sources(ms), channel_freqs(ms)), column=None,
                  beam="none", ionosphere="random:3")
    two = predict(ms, _tabulated(_sources(ms), channel_freqs(ms)), column=None,
                  beam="none", ionosphere="random:3")
    np.testing.assert_array_equal(one.values, two.values)


@pytest.mark.parametrize("content,message", [
    ("time,rm\n1,2\n", "no column station"),
    ("time,station,rm\n", "no rows below the header"),
    ("time,station,rm\nnoon,*,1\n", "time 'noon' is neither MJD seconds"),
    ("time,station,rm\n1,*,x\n", "rm 'x' is not a number"),
    ("time,station,rm\n1,*,1\n1,*,2\n", "has time 1.0 twice"),
    ("time,station,rm\n1,*,1\n2,*,2\n", "spans MJD 1.0-2.0 s; the observation runs"),
    ("time,station,rm\n{t0},Tile000,1\n{t1},Tile000,1\n", "no station 'Tile001'"),
])
def test_bad_tables_are_refused_in_one_line(ms, tmp_path, content, message):
    times = _times(ms)
    path = tmp_path / "bad.csv"
    path.write_text(content.format(t0=times[0], t1=times[-1]))
    with pytest.raises(InputError, match=message):
        predict(ms, _tabulated(_sources(ms), channel_freqs(ms)), column=None, beam="none",
                ionosphere=path)
    sky = tmp_path / "sky.skymodel"
    from ms_helpers import write_sky

    write_sky(sky, [s for s in _sources(ms)])
    result = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--beam", "none",
                                      "--column", "M_IONO", "--ionosphere", str(path)])
    assert message.split("'")[0] in one_error_line(result)


def test_the_ionosphere_setting_names_its_flag(ms, tmp_path):
    sky = tmp_path / "sky.skymodel"
    from ms_helpers import write_sky

    write_sky(sky, _sources(ms))
    result = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--beam", "none",
                                      "--column", "M_IONO", "--ionosphere", "random:x"])
    assert "--ionosphere 'random:x': give random:SEED" in one_error_line(result)


def test_one_screen_keeps_the_lofar_factors(small_lofar_ms, tmp_path):
    """With the same RM at every station the LOFAR model keeps its per-station factors,
    which multiply to the full Jones matrices of the rotated beam."""
    from msleak.adapters.beams import load_beam

    csv = _constant(small_lofar_ms, tmp_path, 0.9)
    beam = load_beam("everybeam", small_lofar_ms, ionosphere=csv)
    ra0, dec0 = beam.phase_centre
    ra, dec = ra0 + np.array([0.0, 0.03, -0.05]), dec0 + np.array([0.0, 0.02, 0.01])
    times, freq = _times(small_lofar_ms)[:2], channel_freqs(small_lofar_ms)
    factors = beam.jones_factors(times, freq, ra, dec)
    full = beam.jones(times, freq, ra, dec)
    assert factors is not None
    np.testing.assert_allclose(factors.full(), full, rtol=0, atol=1e-12 * np.abs(full).max())
    plain = load_beam("everybeam", small_lofar_ms).jones(times, freq, ra, dec)
    rot = faraday_rotation(np.full((full.shape[0], times.size), 0.9), freq)
    np.testing.assert_allclose(full, plain @ rot[:, :, :, None], rtol=0,
                               atol=1e-12 * np.abs(full).max())
