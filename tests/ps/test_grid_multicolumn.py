"""``msleak grid MS --column A --column B ...``: several columns gridded in one pass.

Known answers: each column's cube from the one-pass run is bit for bit the cube of that
column gridded on its own (same chunks); a column holding twice another grids to twice
its cube with the same weights; the errors of the option pair --column / -o and of the
columns leave nothing written.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from casa_ms import build_ms
from msleak.cli import cli
from msleak.errors import InputError
import msleak

COLUMNS = ("DATA", "MODEL_A", "MODEL_B", "MODEL_2A")
ENU = np.array([[0.0, 0.0, 0.0], [30.0, 5.0, 0.2], [-12.0, 41.0, -0.1], [55.0, -38.0, 0.3],
                [-47.0, -20.0, 0.0], [20.0, 60.0, 0.1], [-60.0, 35.0, 0.0]])
#: a uv range the 7-antenna layout fills at 150 MHz (baselines 14-115 m: 7-58 wavelengths)
UV = (5.0, 60.0)
CUBE_VARS = ("vis", "weight", "vis_a", "vis_b", "weight_a", "weight_b")


@pytest.fixture(scope="module")
def four_column_ms(tmp_path_factory):
    """Random DATA, MODEL_A, MODEL_B (one non-finite sample), MODEL_2A = 2 MODEL_A; random
    flags and weights."""
    import casacore.tables as pt

    ms = build_ms(tmp_path_factory.mktemp("multi") / "multi.ms", enu=ENU, ntime=6, nchan=5,
                  extra_columns=COLUMNS)
    rng = np.random.default_rng(7)
    with pt.table(str(ms), readonly=False, ack=False) as t:
        shape = (t.nrows(), 5, 4)
        for name in COLUMNS[:3]:
            t.putcol(name, (rng.normal(size=shape) + 1j * rng.normal(size=shape))
                     .astype(np.complex64))
        t.putcol("MODEL_2A", 2 * t.getcol("MODEL_A"))
        flags = rng.random(shape) < 0.1
        t.putcol("FLAG", flags)
        t.putcol("WEIGHT_SPECTRUM", rng.uniform(0.5, 2.0, shape).astype(np.float32))
        # an unflagged sample in the uv range (channel 2) drops out of MODEL_B's cube only
        uv = np.hypot(*t.getcol("UVW")[:, :2].T) * (150e6 + 2 * 195312.5) / 299_792_458.0
        row = np.flatnonzero((uv > UV[0] + 1) & (uv < UV[1] - 1) & ~flags[:, 2].any(-1))[0]
        b = t.getcol("MODEL_B")
        b[row, 2, 1] = np.nan
        t.putcol("MODEL_B", b)
    return ms


def _grid(ms, column, **kw):
    return msleak.grid(ms, column=column, uv_range=UV, chunk_rows=17, scheduler="sync",
                   beam_area_model="airy", **kw)


@pytest.mark.parametrize("gridder", ["cell", "wgrid"])
def test_one_pass_equals_each_column_alone(four_column_ms, gridder):
    cubes = _grid(four_column_ms, list(COLUMNS), gridder=gridder, split="even-odd")
    assert [c.attrs["column"] for c in cubes] == list(COLUMNS)
    alone = {name: _grid(four_column_ms, name, gridder=gridder, split="even-odd")
             for name in COLUMNS}
    for cube in cubes:
        ref = alone[cube.attrs["column"]]
        assert isinstance(ref, xr.Dataset) and ref.attrs["column"] == cube.attrs["column"]
        for var in CUBE_VARS:
            assert np.array_equal(cube[var].values, ref[var].values), (cube.attrs["column"], var)
        # every attribute equal but the record of the call (one pass names every column)
        made = ("command", "history")
        assert {k: str(v) for k, v in cube.attrs.items() if k not in made} == \
            {k: str(v) for k, v in ref.attrs.items() if k not in made}
        assert cube.attrs["history"].splitlines()[:-1] == ref.attrs["history"].splitlines()[:-1]
    by_name = dict(zip(COLUMNS, cubes))
    a, a2 = by_name["MODEL_A"], by_name["MODEL_2A"]
    # twice the visibilities, the same weights: twice the cube (scaling by 2 is exact in
    # the nearest-cell sums; ducc0's arithmetic is linear to rounding)
    assert np.array_equal(a2["weight"].values, a["weight"].values)
    np.testing.assert_allclose(a2["vis"].values, 2 * a["vis"].values, rtol=0,
                               atol=1e-12 * np.abs(a["vis"].values).max())
    # the non-finite MODEL_B sample is left out of MODEL_B's weights only
    w_a, w_b = a["weight"].values, by_name["MODEL_B"]["weight"].values
    assert (w_b <= w_a).all() and (w_b < w_a).any()
    assert np.array_equal(by_name["DATA"]["weight"].values, w_a)
    assert not np.array_equal(by_name["DATA"]["vis"].values, a["vis"].values)


def test_one_column_in_a_list_gives_a_list(four_column_ms):
    single = _grid(four_column_ms, "MODEL_A", gridder="cell")
    listed = _grid(four_column_ms, ("MODEL_A",), gridder="cell")
    assert isinstance(single, xr.Dataset) and isinstance(listed, list) and len(listed) == 1
    assert np.array_equal(listed[0]["vis"].values, single["vis"].values)


def test_cli_columns_match_separate_runs(four_column_ms, tmp_path):
    common = [str(four_column_ms), "--uv-range", "5,60", "--chunk-rows", "17",
              "--beam-area-model", "airy", "--scheduler", "threads", "--workers", "2"]
    outs = [tmp_path / f"{name}.h5" for name in COLUMNS[:3]]
    run = CliRunner().invoke(cli, ["grid", *common, *sum((["--column", n] for n in COLUMNS[:3]),
                                                        []),
                                   *sum((["-o", str(o)] for o in outs), [])])
    assert run.exit_code == 0, run.output
    lines = run.output.strip().splitlines()
    assert [ln.split(":")[0] for ln in lines] == [f"uv cube {o} ({n})"
                                                 for o, n in zip(outs, COLUMNS[:3])]
    for name, out in zip(COLUMNS[:3], outs):
        ref = tmp_path / f"alone_{name}.h5"
        run = CliRunner().invoke(cli, ["grid", *common, "--column", name, "-o", str(ref)])
        assert run.exit_code == 0, run.output
        with xr.open_dataset(out, engine="h5netcdf") as got, \
                xr.open_dataset(ref, engine="h5netcdf") as want:
            assert got.attrs["column"] == want.attrs["column"] == name
            for var in ("vis", "weight"):
                assert np.array_equal(got[var].values, want[var].values)


def _run_error(args):
    run = CliRunner().invoke(cli, ["grid", *map(str, args)])
    assert run.exit_code == 2, run.output
    lines = run.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("msleak: error: "), run.output
    return lines[0]


def test_cli_output_count_and_duplicates(four_column_ms, tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    ms = four_column_ms
    assert "2 --column but 1 -o/--output given" in _run_error(
        [ms, "--column", "DATA", "--column", "MODEL_A", "-o", a])
    assert "1 --column but 2 -o/--output given" in _run_error(
        [ms, "--column", "DATA", "-o", a, "-o", b])
    assert "1 --column but 2 -o/--output given" in _run_error([ms, "-o", a, "-o", b])
    assert f"-o {tmp_path}/./a.h5 is given twice" in _run_error(
        [ms, "--column", "DATA", "--column", "MODEL_A", "-o", a, "-o", f"{tmp_path}/./a.h5"])
    assert "column DATA is given twice" in _run_error(
        [ms, "--column", "DATA", "--column", "DATA", "-o", a, "-o", b])
    assert not a.exists() and not b.exists()


def test_missing_column_among_several_writes_nothing(four_column_ms, tmp_path):
    outs = [tmp_path / f"{k}.h5" for k in range(3)]
    message = _run_error([four_column_ms, "--column", "DATA", "--column", "MODEL_A",
                          "--column", "CORRECTED_DATA", *sum((["-o", o] for o in outs), [])])
    assert "no column 'CORRECTED_DATA' (data columns: DATA, MODEL_A, MODEL_B, MODEL_2A)" \
        in message
    assert not any(o.exists() for o in outs)


def test_incomplete_column_among_several_is_refused_before_gridding(four_column_ms, tmp_path,
                                                                    monkeypatch):
    import shutil

    import casacore.tables as pt

    from msleak.io.columns import RUN_KEYWORD
    from msleak.verbs import grid_tasks

    ms = tmp_path / "copy.ms"
    shutil.copytree(four_column_ms, ms)
    with pt.table(str(ms), readonly=False, ack=False) as t:
        t.putcolkeyword("MODEL_B", RUN_KEYWORD, {"complete": False, "rows_done": 40})
    outs = [tmp_path / f"{k}.h5" for k in range(3)]
    message = _run_error([ms, "--column", "DATA", "--column", "MODEL_B", "--column",
                          "MODEL_A", *sum((["-o", o] for o in outs), [])])
    assert "column MODEL_B is incomplete (msleak predict was interrupted after 40 rows)" \
        in message
    assert not any(o.exists() for o in outs)

    def no_gridding(*args, **kwargs):
        raise AssertionError("a chunk was gridded")

    monkeypatch.setattr(grid_tasks, "_grid_task", no_gridding)
    with pytest.raises(InputError, match="MODEL_B is incomplete"):
        _grid(ms, ["DATA", "MODEL_A", "MODEL_B"], gridder="cell")
    with pytest.raises(InputError, match="no column 'NOPE'"):
        _grid(ms, ["DATA", "NOPE"], gridder="cell")
