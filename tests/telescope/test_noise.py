"""``msleak noise``: thermal noise by the radiometer equation, against answers known in
advance: the rms of each part equals SEFD / sqrt(2 dnu dt) within 2 % over 10^5 samples,
flags are honoured, and the even/odd cross power of pure noise is zero within 3 sigma while
its auto power is not."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from casa_ms import build_ms
from ms_helpers import one_error_line, table
import msleak
from msleak.cli import cli
from msleak.errors import InputError

SEFD = 2500.0
WIDTH = 195312.5
INTERVAL = 10.0


@pytest.fixture(scope="module")
def master(tmp_path_factory):
    return build_ms(tmp_path_factory.mktemp("noise") / "noise.ms", ntime=320, nchan=8,
                    interval_s=INTERVAL, chan_width_hz=WIDTH)


@pytest.fixture
def ms(master, tmp_path):
    import shutil

    return shutil.copytree(master, tmp_path / "noise.ms")


def _column(ms, name):
    with table(ms) as t:
        return t.getcol(name), t.getcol("EXPOSURE")


def test_rms_is_the_radiometer_equation(ms):
    result = msleak.noise(ms, sefd=SEFD, seed=1)
    values, exposure = _column(ms, "NOISE_DATA")
    expected = SEFD / np.sqrt(2 * WIDTH * exposure[0])
    assert np.all(exposure == exposure[0]) and values.size >= 1e5
    for part in (values.real, values.imag):
        assert np.std(part) == pytest.approx(expected, rel=0.02)
        assert abs(np.mean(part)) < 5 * expected / np.sqrt(part.size)
    assert result.sigma_jy == pytest.approx(expected, rel=1e-12)
    assert result.samples == values.size


def test_same_seed_same_noise_and_added_to_a_source_column(ms):
    msleak.noise(ms, sefd=SEFD, seed=3, column="N1")
    msleak.noise(ms, sefd=SEFD, seed=3, column="N2")
    msleak.noise(ms, sefd=SEFD, seed=4, column="N3")
    one, _ = _column(ms, "N1")
    np.testing.assert_array_equal(one, _column(ms, "N2")[0])
    assert not np.array_equal(one, _column(ms, "N3")[0])
    for _ in range(2):                                   # a rerun gives the same column
        msleak.noise(ms, sefd=SEFD, seed=3, source="N3", column="N4")
        np.testing.assert_allclose(_column(ms, "N4")[0], _column(ms, "N3")[0] + one,
                                   rtol=0, atol=1e-6 * np.abs(one).max())  # complex64


def test_flags_are_honoured(ms):
    with table(ms, readonly=False) as t:
        flags = t.getcol("FLAG")
        flags[::3, 2:5, :] = True
        t.putcol("FLAG", flags)
        flag_row = t.getcol("FLAG_ROW")
        flag_row[7] = True
        t.putcol("FLAG_ROW", flag_row)
    msleak.noise(ms, sefd=SEFD, seed=2, column="MODEL_DATA")
    values, _ = _column(ms, "MODEL_DATA")
    flagged = flags | flag_row[:, None, None]
    assert np.all(values[flagged] == 0) and np.all(values[~flagged] != 0)
    msleak.noise(ms, sefd=SEFD, seed=5, source="MODEL_DATA", column="NOISY")
    after, _ = _column(ms, "NOISY")
    np.testing.assert_array_equal(after[flagged], values[flagged])
    assert np.all(after[~flagged] != values[~flagged])


def test_even_odd_cross_power_of_noise_is_zero(ms, tmp_path):
    msleak.noise(ms, sefd=SEFD, seed=6)
    grid = msleak.grid(ms, column="NOISE_DATA", uv_range=(0.0, 400.0), cell=4.0,
                       split="even-odd", output=tmp_path / "grid.h5")
    delay = msleak.transform(grid, window="none")
    a, b = delay["vis_a"].sel(stokes="I").values, delay["vis_b"].sel(stokes="I").values
    used = np.isfinite(a) & np.isfinite(b) & (a != 0) & (b != 0)
    cross = (a[used] * np.conj(b[used])).real
    auto = np.abs(a[used]) ** 2
    assert cross.size >= 200
    error = cross.std() / np.sqrt(cross.size)
    assert abs(cross.mean()) < 3 * error
    assert auto.mean() > 5 * auto.std() / np.sqrt(auto.size)    # the bias cross power removes


def test_bad_sefd_and_missing_column_refused(ms):
    with pytest.raises(InputError, match=r"sefd must be positive \(Jy\), got -1"):
        msleak.noise(ms, sefd=-1.0)
    with pytest.raises(InputError, match="no column NOPE to add noise to"):
        msleak.noise(ms, sefd=SEFD, source="NOPE", column="X")
    with pytest.raises(InputError, match="noise is written next to its `source`"):
        msleak.noise(ms, sefd=SEFD, source="DATA", column="DATA", overwrite_data=True)
    with pytest.raises(InputError, match="refusing to overwrite the DATA column"):
        msleak.noise(ms, sefd=SEFD, column="DATA")
    result = CliRunner().invoke(cli, ["noise", str(ms), "--sefd", "-1"])
    assert "--sefd must be positive (Jy), got -1" in one_error_line(result)


def test_an_interrupted_run_resumes_and_grid_refuses_it_meanwhile(ms, monkeypatch, tmp_path):
    """A run killed after its first block: grid refuses the column, the rerun finishes it
    from where it stopped, equal to an uninterrupted run."""
    import msleak.verbs.noise as verb
    from msleak.io import columns as colio

    monkeypatch.setattr(verb, "NOISE_CHUNK_ROWS", 1000)
    msleak.noise(ms, sefd=SEFD, seed=8, column="WHOLE")
    calls = []
    original = colio.write_rows

    def dies_on_the_second_block(table, column, rows, values):
        calls.append(rows[0])
        if len(calls) == 2:
            raise KeyboardInterrupt
        original(table, column, rows, values)

    monkeypatch.setattr(colio, "write_rows", dies_on_the_second_block)
    with pytest.raises(KeyboardInterrupt):
        msleak.noise(ms, sefd=SEFD, seed=8, column="PART")
    monkeypatch.setattr(colio, "write_rows", original)
    with pytest.raises(InputError, match="msleak noise was interrupted after 1000 rows"):
        msleak.grid(ms, column="PART", uv_range=(0.0, 400.0), output=tmp_path / "g.h5")
    result = msleak.noise(ms, sefd=SEFD, seed=8, column="PART")
    assert result.rows_written == _column(ms, "PART")[0].shape[0] - 1000
    np.testing.assert_array_equal(_column(ms, "PART")[0], _column(ms, "WHOLE")[0])


# --- per-station SEFDs from a table, and predict's noise ------------------------------

def _sefd_table(path, ms, factor=1.0):
    """A CSV of per-station SEFDs: station k gets SEFD * (1 + k / 4) * factor."""
    with table(f"{ms}/ANTENNA") as t:
        names = [str(n) for n in t.getcol("NAME")]
    rows = ["station,sefd"] + [f"{n},{SEFD * (1 + k / 4) * factor:g}"
                               for k, n in enumerate(names)]
    path.write_text("\n".join(rows) + "\n")
    return path, {n: SEFD * (1 + k / 4) * factor for k, n in enumerate(names)}


def test_per_station_sefd_table_sets_each_baselines_rms(ms, tmp_path):
    csv, sefd = _sefd_table(tmp_path / "sefd.csv", ms)
    result = CliRunner().invoke(cli, ["noise", str(ms), "--sefd", str(csv), "--seed", "2"])
    assert result.exit_code == 0, result.output
    with table(ms) as t:
        values, a1, a2 = t.getcol("NOISE_DATA"), t.getcol("ANTENNA1"), t.getcol("ANTENNA2")
        exposure = t.getcol("EXPOSURE")[0]
    s = np.array(list(sefd.values()))
    pairs = {(p, q) for p, q in zip(a1, a2) if p != q}
    for p, q in sorted(pairs)[:6]:
        at = (a1 == p) & (a2 == q)
        expected = np.sqrt(s[p] * s[q] / (2 * WIDTH * exposure))
        part = values[at].real.ravel()
        # the standard deviation of n samples scatters by 1 / sqrt(2 n) relative
        assert np.std(part) == pytest.approx(expected, rel=4 / np.sqrt(2 * part.size))


@pytest.mark.parametrize("text, message", [
    ("nosuch.csv", "neither a number"),
    ("bad", "line 2"),
    ("cols", "give the columns 'station' and 'sefd'"),
])
def test_bad_sefd_tables_are_refused_in_one_line(ms, tmp_path, text, message):
    arg = text
    if text == "bad":
        (tmp_path / "bad.csv").write_text("station,sefd\nCS001,-3\n")
        arg = str(tmp_path / "bad.csv")
    elif text == "cols":
        (tmp_path / "cols.csv").write_text("name,value\nCS001,3\n")
        arg = str(tmp_path / "cols.csv")
    result = CliRunner().invoke(cli, ["noise", str(ms), "--sefd", arg])
    assert result.exit_code != 0
    assert message in one_error_line(result)


def _point_sky(ms):
    from ms_helpers import channel_freqs, phase_centre
    from msleak.sky.sources import PointSources

    ra0, dec0 = phase_centre(ms)
    freq = channel_freqs(ms)
    stokes = np.zeros((1, freq.size, 4))
    stokes[0, :, :] = (3.0, 1.0, -0.5, 0.0)
    return PointSources(ra=np.array([ra0 + 0.01]), dec=np.array([dec0 - 0.02]), freq=freq,
                        stokes=stokes)


def test_predict_noise_equals_predict_then_noise(ms):
    from msleak.verbs.predict import predict

    sky = _point_sky(ms)
    predict(ms, sky, column="MODEL_DATA", beam="none")
    msleak.noise(ms, sefd=SEFD, seed=5, source="MODEL_DATA", column="BY_HAND")
    result = predict(ms, sky, column="NOISY", beam="none", noise=SEFD, noise_seed=5)
    noisy, exposure = _column(ms, "NOISY")
    np.testing.assert_array_equal(noisy, _column(ms, "BY_HAND")[0])
    assert result.noise_sigma_jy == pytest.approx(SEFD / np.sqrt(2 * WIDTH * exposure[0]),
                                                  rel=1e-12)
    clean = _column(ms, "MODEL_DATA")[0]
    assert np.std((noisy - clean).real) == pytest.approx(result.noise_sigma_jy, rel=0.02)
    predict(ms, sky, column="NOISY", beam="none", noise=SEFD, noise_seed=5)  # a rerun
    np.testing.assert_array_equal(_column(ms, "NOISY")[0], noisy)        # adds it once


def test_predict_noise_is_refused_without_a_column_or_with_unknown_stations(ms, tmp_path):
    from msleak.verbs.predict import predict

    with pytest.raises(InputError, match="noise is added to the columns predict writes"):
        predict(ms, _point_sky(ms), column=None, beam="none", noise=SEFD)
    with pytest.raises(InputError, match="sefd has no value for station"):
        predict(ms, _point_sky(ms), column="NOISY", beam="none", noise={"CS999": 1.0})


def test_predict_noise_is_refused_with_a_field_selection_and_a_stale_record_is_dropped(ms):
    from msleak.io.columns import write_noise_state
    from msleak.verbs.predict import predict

    with pytest.raises(InputError, match="noise covers every row of the MS"):
        predict(ms, _point_sky(ms), column="NOISY", beam="none", noise=SEFD, field=0)
    predict(ms, _point_sky(ms), column="CLEAN", beam="none")
    with table(ms, readonly=False) as t:      # a noise run killed half way
        write_noise_state(t, "CLEAN", {"settings": "x", "rows_done": 10, "complete": False})
    predict(ms, _point_sky(ms), column="CLEAN", beam="none", restart=True)
    with table(ms) as t:
        assert "MSLEAK_NOISE" not in t.getcolkeywords("CLEAN")
    cube = msleak.grid(ms, column="CLEAN", cell=16.0)   # not refused as half written
    assert float(np.abs(cube["vis"]).max()) > 0
