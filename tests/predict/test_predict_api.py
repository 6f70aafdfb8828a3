"""The Python verb ``msleak.predict``: the same numbers as ``msleak predict`` (exactly),
``column=None`` returning what the CLI writes without touching the MS, in-memory skies
equal to their files, one MS HISTORY row per run (none for a refused run), and the
verb's own input errors."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from casa_ms import build_ms
from ms_helpers import channel_freqs, phase_centre, table, write_sky
from msleak.cli import cli
from msleak.errors import InputError
from msleak.verbs.predict import predict
from msleak.verbs.sky import make_sky

NTIME = 3


def _digests(ms: Path) -> dict:
    return {str(p.relative_to(ms)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(ms.rglob("*")) if p.is_file() and p.name != "table.lock"}


def _history_rows(ms: Path) -> list[tuple[str, str]]:
    with table(ms / "HISTORY") as t:
        if t.nrows() == 0:
            return []
        return [(t.getcell("MESSAGE", r), t.getcell("CLI_COMMAND", r)[0])
                for r in range(t.nrows())]


@pytest.fixture
def ms(tmp_path):
    return build_ms(tmp_path / "obs.ms", ntime=NTIME, autocorrelations=True)


@pytest.fixture
def sky(tmp_path, ms):
    ra0, dec0 = phase_centre(ms)
    return write_sky(tmp_path / "sky.skymodel",
                     [(ra0 + 0.03, dec0 + 0.01, 1.0, 0.4, -0.3, 0.05),
                      (ra0 - 0.02, dec0 - 0.04, 2.0, -0.2, 0.6, 0.0)])


def _cli(*args) -> None:
    r = CliRunner().invoke(cli, ["predict", *map(str, args)])
    assert r.exit_code == 0, r.output


def _col(ms, name):
    with table(ms) as t:
        return t.getcol(name)


@pytest.mark.parametrize("beam", ["none", "dipole"])
def test_verb_writes_the_cli_column(ms, sky, tmp_path, beam):
    copy = tmp_path / "copy.ms"
    shutil.copytree(ms, copy)
    _cli(ms, "--sky", sky, "--beam", beam, "--column", "M")
    res = predict(copy, sky, beam=beam, column="M")
    assert res.column == "M" and res.rows_written == _col(ms, "TIME").size
    np.testing.assert_array_equal(_col(copy, "M"), _col(ms, "M"))
    assert np.abs(_col(ms, "M")).max() > 0.1


def test_column_none_returns_the_cli_column_and_writes_nothing(ms, sky, tmp_path):
    before = _digests(ms)
    vis = predict(ms, sky, beam="dipole", column=None)
    assert _digests(ms) == before
    _cli(ms, "--sky", sky, "--beam", "dipole")
    with table(ms) as t:
        model, a1, a2, time = (t.getcol(c) for c in ("MODEL_DATA", "ANTENNA1", "ANTENNA2",
                                                      "TIME"))
    assert vis.dims == ("row", "chan", "corr") and vis.dtype == np.complex64
    np.testing.assert_array_equal(vis.values, model)
    np.testing.assert_array_equal(vis["row"], np.arange(model.shape[0]))
    np.testing.assert_array_equal(vis["antenna1"], a1)
    np.testing.assert_array_equal(vis["antenna2"], a2)
    np.testing.assert_array_equal(vis["time"], time)
    np.testing.assert_array_equal(vis["freq"], channel_freqs(ms))
    assert list(vis["corr"].values) == ["XX", "XY", "YX", "YY"]


def test_column_none_with_two_skies_gives_two_arrays(ms, sky, tmp_path):
    ra0, dec0 = phase_centre(ms)
    other = write_sky(tmp_path / "b.skymodel", [(ra0, dec0 + 0.02, 0.0, 1.0, 0.0, 0.0)])
    a, b = predict(ms, [sky, other], column=None, beam="none", scheduler="sync")
    alone = predict(ms, other, column=None, beam="none", scheduler="sync")
    np.testing.assert_array_equal(b.values, alone.values)
    # 1 Jy Q at (l, m) = (0, m): XX = -YY = exp(2 pi i v m' ...) with |XX| = 1 exactly
    np.testing.assert_allclose(np.abs(b.values[..., 0]), 1.0, rtol=1e-6)
    assert a.shape == b.shape


def test_in_memory_skies_equal_their_files(ms, sky, tmp_path):
    from msleak.adapters.sky_fits import read_cube
    from msleak.adapters.skymodel import read_skymodel

    from_file = predict(ms, sky, column=None, beam="dipole")
    from_memory = predict(ms, read_skymodel(sky), column=None, beam="dipole")
    np.testing.assert_array_equal(from_memory.values, from_file.values)

    ra0, dec0 = (np.degrees(x) for x in phase_centre(ms))
    freq = channel_freqs(ms)
    cube_path = tmp_path / "sky.fits"
    ds = make_sky(cube_path, fov=4.0, npix=8, nchan=freq.size, freq_min=freq[0],
                         chan_width=freq[1] - freq[0], seed=3, phase_centre=(ra0, dec0))
    from_fits = predict(ms, cube_path, column=None, beam="dipole", fov=2.0)
    from_ds = predict(ms, ds, column=None, beam="dipole", fov=2.0)
    from_cube = predict(ms, read_cube(cube_path), column=None, beam="dipole", fov=2.0)
    assert np.abs(from_fits.values).max() > 0
    np.testing.assert_array_equal(from_ds.values, from_fits.values)
    np.testing.assert_array_equal(from_cube.values, from_fits.values)


def test_history_row_per_run_and_none_when_refused(ms, sky):
    assert _history_rows(ms) == []
    r = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--beam", "none",
                                 "--column", "M1"])
    assert r.exit_code == 0, r.output
    rows = _history_rows(ms)
    assert len(rows) == 1
    message, command = rows[0]
    assert f"{sky} -> M1" in message and "beam none" in message
    assert command and not command.startswith("msleak.predict(")  # the process's argv
    refused = CliRunner().invoke(cli, ["predict", str(ms), "--sky", str(sky), "--column",
                                       "FLAG"])
    assert refused.exit_code == 2
    assert len(_history_rows(ms)) == 1
    predict(ms, [sky, sky], column=["M2", "M3"], beam="none", fov=[None, 3.0])
    rows = _history_rows(ms)
    assert len(rows) == 2 and f"{sky} -> M2; {sky} -> M3" in rows[1][0]
    assert rows[1][1] == (f"msleak.predict({str(ms)!r}, [{str(sky)!r}, {str(sky)!r}], "
                          "column=['M2', 'M3'], fov=[None, 3.0], beam='none')")


@pytest.mark.parametrize("kwargs,message", [
    (dict(column=None, two_ms=True), "column=None returns the visibilities of one Measurement"),
    (dict(column=["M", None], two_skies=True), "give every sky a column, or none"),
    (dict(memory_limit="lots"), "'lots' is not a memory size"),
    (dict(memory_limit=0), "memory_limit must be positive"),
    (dict(not_a_sky=True), "sky must be a path, a sky Dataset"),
    (dict(diameter=4.0), "diameter applies to beam 'dipole' only, not beam 'none'"),
])
def test_verb_errors(ms, sky, tmp_path, kwargs, message):
    before = _digests(ms)
    kw = dict(kwargs)
    target = [ms, build_ms(tmp_path / "two.ms", ntime=1)] if kw.pop("two_ms", False) else ms
    given = [sky, sky] if kw.pop("two_skies", False) else sky
    if kw.pop("not_a_sky", False):
        given = 42
    with pytest.raises(InputError, match=message):
        predict(target, given, beam="none", **kw)
    assert _digests(ms) == before


def test_column_none_refuses_rows_on_two_channel_axes(tmp_path, sky):
    import casacore.tables as pt

    ms = build_ms(tmp_path / "obs.ms", ntime=2)
    with pt.table(f"{ms}/SPECTRAL_WINDOW", readonly=False, ack=False) as t:
        t.copyrows(t, startrowin=0, nrow=1)
        t.putcell("CHAN_FREQ", 1, t.getcell("CHAN_FREQ", 0) + 10e6)
        t.putcell("NAME", 1, "SPW1")
    with pt.table(f"{ms}/DATA_DESCRIPTION", readonly=False, ack=False) as t:
        t.copyrows(t, startrowin=0, nrow=1)
        t.putcell("SPECTRAL_WINDOW_ID", 1, 1)
    with pt.table(str(ms), readonly=False, ack=False) as t:
        ddid = t.getcol("DATA_DESC_ID")
        ddid[1::2] = 1
        t.putcol("DATA_DESC_ID", ddid)
    with pytest.raises(InputError, match="select one spectral window with spw="):
        predict(ms, sky, column=None, beam="none")
    one = predict(ms, sky, column=None, beam="none", spw=1)
    np.testing.assert_array_equal(one["row"], np.flatnonzero(ddid == 1))


def test_cli_metavars_name_units():
    from msleak.cli.predict import predict as command

    opts = {p.name: p for p in command.params}
    assert opts["fov"].metavar == "DEG" and opts["diameter"].metavar == "M"
    assert opts["field"].metavar == "ID|NAME" and opts["spw"].metavar == "ID"
    assert opts["memory_limit"].type.name == "SIZE" and opts["workers"].metavar == "N"
