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


def test_same_seed_same_noise_and_added_to_a_column(ms):
    msleak.noise(ms, sefd=SEFD, seed=3, column="N1")
    msleak.noise(ms, sefd=SEFD, seed=3, column="N2")
    msleak.noise(ms, sefd=SEFD, seed=4, column="N3")
    one, _ = _column(ms, "N1")
    np.testing.assert_array_equal(one, _column(ms, "N2")[0])
    assert not np.array_equal(one, _column(ms, "N3")[0])
    msleak.noise(ms, sefd=SEFD, seed=3, column="N2", add=True)
    np.testing.assert_allclose(_column(ms, "N2")[0], 2 * one, rtol=1e-6)


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
    before = values.copy()
    msleak.noise(ms, sefd=SEFD, seed=5, column="MODEL_DATA", add=True)
    after, _ = _column(ms, "MODEL_DATA")
    np.testing.assert_array_equal(after[flagged], before[flagged])


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
        msleak.noise(ms, sefd=SEFD, column="NOPE", add=True)
    with pytest.raises(InputError, match="refusing to overwrite the DATA column"):
        msleak.noise(ms, sefd=SEFD, column="DATA")
    result = CliRunner().invoke(cli, ["noise", str(ms), "--sefd", "-1"])
    assert "--sefd must be positive (Jy), got -1" in one_error_line(result)
