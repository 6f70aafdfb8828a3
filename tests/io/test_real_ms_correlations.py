"""Correlation layouts of real writers: circular feeds, any order of the four products,
two correlations; beam maps on circular feeds; what grid products record.

Every MS here is built with tests/casa_ms.py (casacore's own MS definition, filled the way
CASA, cotter and pyuvdata do), independently of ``msleak simulate``.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from casa_ms import CIRCULAR, LINEAR, build_ms
from msleak.cli import cli
from msleak.conventions import correlation_layout
from msleak.errors import InputError
from ms_helpers import phase_centre, table, write_sky

CODE = {"RR": 5, "RL": 6, "LR": 7, "LL": 8, "XX": 9, "XY": 10, "YX": 11, "YY": 12}
#: (R, L) = C (X, Y): the circular feeds of docs/conventions.md
C_FEEDS = np.array([[1, 1j], [1, -1j]]) / np.sqrt(2)
#: polarized test sources: (dl, dm) offsets (rad) from the phase centre and I, Q, U, V (Jy)
#: phase centre at hour angle ~0 at the MWA site at the casa_ms default times (63.5 deg
#: elevation), so that the dipole beam sees it
FIELD = dict(ra_deg=253.0, dec_deg=0.0)
SOURCES = [((0.0, 0.0), (1.0, 0.4, -0.3, 0.05)),
           ((0.03, -0.02), (0.0, 1.0, 0.5, 0.0)),
           ((-0.05, 0.04), (2.0, -0.6, 0.8, 0.1))]


# ----------------------------------------------------------------------------- helpers
def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _ok(*args):
    res = _invoke(*args)
    assert res.exit_code == 0, (args, res.output, res.exception)
    return res


def _one_line_error(res, pattern):
    assert res.exit_code == 2, (res.output, res.exception)
    last = res.output.strip().splitlines()[-1]
    assert last.startswith("msleak: error:"), res.output
    assert "Traceback" not in res.output
    assert pattern in last, last
    return last


def _col(ms, name):
    with table(ms) as t:
        return t.getcol(name)


def _put(ms, name, values):
    with table(ms, readonly=False) as t:
        t.putcol(name, values)


def _sky(path, ms, sources=SOURCES):
    ra0, dec0 = phase_centre(ms)
    rows = []
    for (dl, dm), iquv in sources:
        n = np.sqrt(1 - dl * dl - dm * dm)
        dec = np.arcsin(dm * np.cos(dec0) + n * np.sin(dec0))
        ra = ra0 + np.arctan2(dl, n * np.cos(dec0) - dm * np.sin(dec0))
        rows.append((ra, dec, *iquv))
    return write_sky(path, rows)


def _products(iquv, names):
    """Correlations of sky Stokes (I, Q, U, V) seen without a beam, written out from the
    brightness matrices of docs/conventions.md, in the order ``names``."""
    i, q, u, v = iquv
    value = {"XX": i + q, "XY": u + 1j * v, "YX": u - 1j * v, "YY": i - q,
             "RR": i + v, "RL": q + 1j * u, "LR": q - 1j * u, "LL": i - v}
    return np.array([value[n] for n in names])


def _grid(ms, out, *extra, column="DATA", beam_area=("--beam-area", "1e-3")):
    _ok("grid", ms, "--column", column, "--uv-range", "5,100", "--cell", "8", *beam_area,
        *extra, "-o", out)
    return xr.open_dataset(out, engine="h5netcdf")


# ------------------------------------------------------------------ layouts in conventions
@pytest.mark.parametrize("canon", [LINEAR, CIRCULAR])
def test_every_order_of_the_four_products_is_understood(canon):
    corr = np.arange(4) + 1j * np.arange(4, 8)
    for perm in itertools.permutations(range(4)):
        names = tuple(canon[k] for k in perm)
        layout = correlation_layout([CODE[n] for n in names])
        assert layout.names == names and layout.full and layout.stokes_missing == ()
        assert layout.feed == ("linear" if canon == LINEAR else "circular")
        stored = layout.from_canonical(corr)
        np.testing.assert_array_equal(stored, corr[list(perm)])
        np.testing.assert_array_equal(layout.to_canonical(stored), corr)


@pytest.mark.parametrize("names,feed,missing", [(("XX", "YY"), "linear", ("U", "V", "P")),
                                                (("YY", "XX"), "linear", ("U", "V", "P")),
                                                (("RR", "LL"), "circular", ("Q", "U", "P"))])
def test_two_parallel_hands_are_understood(names, feed, missing):
    layout = correlation_layout([CODE[n] for n in names])
    assert (layout.feed, layout.names, layout.full, layout.stokes_missing) == (
        feed, names, False, missing)
    canon = layout.to_canonical(np.array([3.0 + 1j, 5.0 - 2j]))
    slot = {"XX": 0, "YY": 3, "RR": 0, "LL": 3}
    expect = np.zeros(4, complex)
    expect[slot[names[0]]], expect[slot[names[1]]] = 3.0 + 1j, 5.0 - 2j
    np.testing.assert_array_equal(canon, expect)


@pytest.mark.parametrize("codes", [[1, 2, 3, 4], [9, 10, 11, 8], [9], [9, 10], [9, 12, 12, 9],
                                   [5, 12], [9, 10, 11, 12, 5]])
def test_other_correlation_sets_are_refused(codes):
    with pytest.raises(InputError, match=r"unsupported CORR_TYPE") as err:
        correlation_layout(codes)
    assert "\n" not in str(err.value)


def test_circular_feed_basis_is_the_one_predict_uses():
    """C of the beam maps turns the linear brightness matrix into the circular one, and
    kron(C, conj C) is predict's conversion of linear visibilities."""
    from msleak.conventions import LINEAR_TO_CIRCULAR_FEEDS, stokes_to_correlations_matrix
    from msleak.predict.kernels import LINEAR_TO_CIRCULAR

    np.testing.assert_allclose(LINEAR_TO_CIRCULAR_FEEDS, C_FEEDS, rtol=0, atol=1e-16)
    k = np.kron(C_FEEDS, C_FEEDS.conj())
    np.testing.assert_allclose(k @ stokes_to_correlations_matrix("linear"),
                               stokes_to_correlations_matrix("circular"), atol=1e-15)
    np.testing.assert_allclose(LINEAR_TO_CIRCULAR, k, rtol=0, atol=1e-16)


# -------------------------------------------------------------- grid reads the right slot
@pytest.mark.parametrize("names", [("XX", "YY", "XY", "YX"), ("YY", "YX", "XY", "XX"),
                                   ("RR", "LL", "RL", "LR"), ("LL", "RL", "LR", "RR"),
                                   ("XX", "YY"), ("YY", "XX"), ("RR", "LL")])
def test_grid_reads_every_product_from_its_slot(tmp_path, names):
    """DATA of a 'point source at the phase centre' (the same correlations in every row)
    with I, Q, U, V = 2, 0.5, -0.3, 0.1 grids, with the nearest-cell gridder, into exactly
    those Stokes values in every cell with data; Stokes the MS cannot give are NaN."""
    iquv = (2.0, 0.5, -0.3, 0.1)
    ms = build_ms(tmp_path / "c.ms", corr=names, **FIELD)
    data = _col(ms, "DATA")
    data[:] = _products(iquv, names)
    _put(ms, "DATA", data)
    ds = _grid(ms, tmp_path / "g.h5", "--gridder", "cell")
    has = ds["weight"].values > 0
    assert has.sum() > 20
    circular = names[0] in ("RR", "LL")
    missing = [] if len(names) == 4 else (["Q", "U", "P"] if circular else ["U", "V", "P"])
    expect = dict(zip("IQUV", iquv), P=iquv[1] + 1j * iquv[2])
    for s in "IQUVP":
        vis = ds["vis"].sel(stokes=s).values
        if s in missing:
            assert np.isnan(vis).all(), s
        else:
            np.testing.assert_allclose(vis[has], expect[s], rtol=0, atol=1e-6, err_msg=s)
    assert ds.attrs["stokes_missing"] == ",".join(missing)
    assert ds.attrs["correlations"] == ",".join(names)
    assert ds.attrs["feed_type"] == ("circular" if circular else "linear")


# -------------------------------------------------------------------- circular feeds
@pytest.mark.parametrize("beam", ["none", "dipole"])
@pytest.mark.parametrize("iquv,expect", [((0.0, 1.0, 0.0, 0.0), (0, 1, 1, 0)),
                                         ((0.0, 0.0, 1.0, 0.0), (0, 1j, -1j, 0))])
def test_circular_feeds_predict_q_and_u_at_the_phase_centre(tmp_path, beam, iquv, expect):
    """Pure Q at the phase centre: RL = LR = Q, RR = LL = 0; pure U: RL = iU, LR = -iU
    (B = [[I+V, Q+iU], [Q-iU, I-V]]); the centre-corrected beam is the identity there."""
    ms = build_ms(tmp_path / "c.ms", corr=CIRCULAR, **FIELD)
    sky = _sky(tmp_path / "s.skymodel", ms, [((0.0, 0.0), iquv)])
    _ok("predict", ms, "--sky", sky, "--beam", beam, "--double")
    model = _col(ms, "MODEL_DATA")
    np.testing.assert_allclose(model, np.broadcast_to(np.array(expect), model.shape),
                               rtol=0, atol=1e-6)


def test_circular_and_linear_feeds_give_the_same_stokes(tmp_path):
    """The same sky through the same dipole beams: the circular MS's MODEL_DATA is C V C^H
    of the linear MS's (C written out here), and both grid to the same Stokes."""
    lin = build_ms(tmp_path / "lin.ms", corr=LINEAR, **FIELD)
    circ = build_ms(tmp_path / "circ.ms", corr=CIRCULAR, **FIELD)
    sky = _sky(tmp_path / "s.skymodel", lin)
    for ms in (lin, circ):
        _ok("predict", ms, "--sky", sky, "--beam", "dipole", "--double")
    v_lin = _col(lin, "MODEL_DATA").reshape(-1, 4, 2, 2)
    expect = (C_FEEDS @ v_lin @ C_FEEDS.conj().T).reshape(-1, 4, 4)
    v_circ = _col(circ, "MODEL_DATA")
    scale = np.abs(v_lin).max()
    np.testing.assert_allclose(v_circ, expect, rtol=0, atol=1e-6 * scale)
    g_lin = _grid(lin, tmp_path / "l.h5", column="MODEL_DATA")
    g_circ = _grid(circ, tmp_path / "c.h5", column="MODEL_DATA")
    np.testing.assert_array_equal(g_lin["weight"].values, g_circ["weight"].values)
    np.testing.assert_allclose(g_circ["vis"].values, g_lin["vis"].values, rtol=0,
                               atol=1e-6 * np.nanmax(np.abs(g_lin["vis"].values)))


def test_beam_maps_of_circular_feeds(tmp_path):
    """`msleak beam` on a circular-feed MS (phase centre at 63 deg elevation): 0 dB
    polarized beam and the identity Mueller matrix at the centre, and the same Mueller
    maps as a linear-feed MS of the same array."""
    maps = {}
    for corr in (LINEAR, CIRCULAR):
        ms = build_ms(tmp_path / f"{corr[0]}.ms", corr=corr, **FIELD)
        out = tmp_path / f"{corr[0]}.png"
        _ok("beam", ms, "--beam", "dipole", "-o", out, "--hour-angles", "0", "--npix", "21",
            "--fov", "20")
        maps[corr[0]] = xr.open_dataset(out.with_suffix(".h5"), engine="h5netcdf")
    circ, lin = maps["RR"], maps["XX"]
    assert circ.attrs["feed"] == "circular" and lin.attrs["feed"] == "linear"
    i, j = (int(x) for x in circ.attrs["centre_pixel"].split(","))
    assert abs(circ["polarized_beam_db"].values[0, i, j]) < 1e-9
    np.testing.assert_allclose(circ["mueller"].values[0, i, j], np.eye(4), atol=1e-9)
    # towards the zenith (North of the centre) the dipoles gain 0.02 dB; nothing like the
    # +144 dB of a Mueller matrix with M11 = M22 = 0 at the centre
    assert np.isfinite(circ["polarized_beam_db"].values).all()
    assert np.max(circ["polarized_beam_db"].values) < 0.1
    np.testing.assert_allclose(circ["mueller"].values, lin["mueller"].values, rtol=0,
                               atol=1e-12)


# ------------------------------------------------------------ any order of the products
@pytest.mark.parametrize("beam", ["none", "dipole"])
@pytest.mark.parametrize("std,perm", [(LINEAR, ("XX", "YY", "XY", "YX")),
                                      (CIRCULAR, ("LL", "RL", "RR", "LR"))])
def test_permuted_products_predict_and_grid_identically(tmp_path, beam, std, perm):
    """The same MS written with the products in another order: predict puts each product
    in its slot (MODEL_DATA equal after permuting, exactly) and grid reads each from its
    slot (equal cubes, exactly)."""
    a = build_ms(tmp_path / "std.ms", corr=std, **FIELD)
    b = build_ms(tmp_path / "perm.ms", corr=perm, **FIELD)
    sky = _sky(tmp_path / "s.skymodel", a)
    for ms in (a, b):
        _ok("predict", ms, "--sky", sky, "--beam", beam, "--double")
    va, vb = _col(a, "MODEL_DATA"), _col(b, "MODEL_DATA")
    assert np.abs(va).max() > 0.1
    np.testing.assert_array_equal(vb, va[..., [std.index(n) for n in perm]])
    ga = _grid(a, tmp_path / "a.h5", column="MODEL_DATA")
    gb = _grid(b, tmp_path / "b.h5", column="MODEL_DATA")
    assert np.isfinite(ga["vis"].values).all() and (ga["weight"].values > 0).sum() > 20
    np.testing.assert_array_equal(gb["vis"].values, ga["vis"].values)
    np.testing.assert_array_equal(gb["weight"].values, ga["weight"].values)


# ------------------------------------------------------------------- two correlations
@pytest.mark.parametrize("pair,full", [(("XX", "YY"), LINEAR), (("RR", "LL"), CIRCULAR)])
def test_two_correlations_grid_like_the_four(tmp_path, pair, full):
    """Known random XX, YY (RR, LL) in a 2-correlation MS grid to exactly the I and Q
    (I and V) of the 4-correlation MS holding the same parallel hands; the cross-hand
    Stokes and P are NaN, and the weights are the same."""
    rng = np.random.default_rng(3)
    four = build_ms(tmp_path / "four.ms", corr=full, **FIELD)
    two = build_ms(tmp_path / "two.ms", corr=pair, **FIELD)
    data = _col(four, "DATA")
    data[:] = rng.normal(size=data.shape) + 1j * rng.normal(size=data.shape)
    _put(four, "DATA", data)
    _put(two, "DATA", data[..., [0, 3]])
    g4 = _grid(four, tmp_path / "g4.h5")
    g2 = _grid(two, tmp_path / "g2.h5")
    present = ["I", "Q"] if pair[0] == "XX" else ["I", "V"]
    np.testing.assert_array_equal(g2["vis"].sel(stokes=present).values,
                                  g4["vis"].sel(stokes=present).values)
    np.testing.assert_array_equal(g2["weight"].values, g4["weight"].values)
    gone = [s for s in "IQUVP" if s not in present]
    assert np.isnan(g2["vis"].sel(stokes=gone).values).all()
    assert np.isfinite(g4["vis"].values).all()
    assert g2.attrs["stokes_missing"] == ",".join(gone) and g4.attrs["stokes_missing"] == ""


def test_two_correlations_downstream(tmp_path):
    """transform and ps run on a 2-correlation cube (I and Q finite, P NaN); the plot of
    the default panels works; leakage says in one line that P needs four correlations."""
    rng = np.random.default_rng(5)
    ms = build_ms(tmp_path / "two.ms", corr=("XX", "YY"), nchan=8, ntime=6, **FIELD)
    data = _col(ms, "DATA")
    data[:] = rng.normal(size=data.shape) + 1j * rng.normal(size=data.shape)
    _put(ms, "DATA", data)
    _grid(ms, tmp_path / "g.h5", "--split", "even-odd")
    _ok("transform", tmp_path / "g.h5", "-o", tmp_path / "d.h5")
    _ok("ps", tmp_path / "d.h5", "-o", tmp_path / "ps.h5", "--plot", tmp_path / "ps.png")
    ps = xr.open_dataset(tmp_path / "ps.h5", engine="h5netcdf")
    assert (tmp_path / "ps.png").stat().st_size > 1000
    power = ps["power3d"]
    for s in "IQ":
        assert np.isfinite(power.sel(stokes=s).values).all() and (power.sel(stokes=s) != 0).any()
    for s in "UVP":
        assert np.isnan(power.sel(stokes=s).values).all()
    assert ps.attrs["stokes_missing"] == "U,V,P" and ps.attrs["correlations"] == "XX,YY"
    res = _invoke("leakage", tmp_path / "ps.h5", "-o", tmp_path / "leak", "--no-figures")
    last = _one_line_error(res, "Stokes P was not measured")
    assert "P needs four correlations" in last and "XX,YY" in last


@pytest.mark.parametrize("beam", ["none", "dipole"])
def test_predict_into_two_correlations_keeps_the_parallel_hands(tmp_path, beam):
    """A 2-correlation MS gets the XX, YY of the full prediction (equal to those of a
    4-correlation MS, exactly) and predict says the cross hands are not stored."""
    four = build_ms(tmp_path / "four.ms", corr=LINEAR, **FIELD)
    two = build_ms(tmp_path / "two.ms", corr=("YY", "XX"), **FIELD)
    sky = _sky(tmp_path / "s.skymodel", four)
    _ok("predict", four, "--sky", sky, "--beam", beam, "--double")
    res = _ok("predict", two, "--sky", sky, "--beam", beam, "--double")
    assert "only the correlations YY,XX" in res.output
    assert "cross hands are not stored" in res.output
    v4, v2 = _col(four, "MODEL_DATA"), _col(two, "MODEL_DATA")
    assert v2.shape == v4.shape[:2] + (2,)
    np.testing.assert_array_equal(v2, v4[..., [3, 0]])


# -------------------------------------------------------- what a grid product records
def test_grid_records_the_beam_model_it_used(tmp_path):
    """MWA MS (EveryBeam cannot load it, no LOFAR tables): auto falls back to the dipole
    beam and says so; with no dish diameter the dipole beam is unusable and the record
    says Airy."""
    ms = build_ms(tmp_path / "mwa.ms", **FIELD)
    auto = _grid(ms, tmp_path / "auto.h5", "--beam-area-model", "auto", beam_area=())
    dip = _grid(ms, tmp_path / "dip.h5", "--beam-area-model", "dipole", beam_area=())
    assert auto.attrs["beam_area_model"] == "dipole"
    assert auto.attrs["primary_beam_model"].startswith("dipole station beam of the MS")
    assert "dipole station power beam" in auto.attrs["beam_area_source"]
    assert auto.attrs["beam_area_sr"] == dip.attrs["beam_area_sr"]
    flat = build_ms(tmp_path / "nodish.ms", dish_diameter=0.0, **FIELD)
    fallback = _grid(flat, tmp_path / "fb.h5", "--beam-area-model", "auto", beam_area=())
    airy = _grid(flat, tmp_path / "airy.h5", "--beam-area-model", "airy", beam_area=())
    assert fallback.attrs["beam_area_model"] == "airy"
    assert fallback.attrs["primary_beam_model"].startswith("Airy disc")
    assert fallback.attrs["beam_area_sr"] == airy.attrs["beam_area_sr"]
    assert fallback.attrs["beam_area_sr"] != auto.attrs["beam_area_sr"]


def test_missing_column_lists_every_data_column(tmp_path):
    ms = build_ms(tmp_path / "cols.ms", extra_columns=("DATA", "MODEL_DATA", "MODEL_4DEG"))
    res = _invoke("grid", ms, "--column", "CORRECTED_DATA", "-o", tmp_path / "g.h5")
    last = _one_line_error(res, "no column 'CORRECTED_DATA'")
    assert last.endswith("(data columns: DATA, MODEL_DATA, MODEL_4DEG)"), last
    assert not (tmp_path / "g.h5").exists()
