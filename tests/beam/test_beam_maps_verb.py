"""``msleak.beam_maps`` (the Python verb) against ``msleak beam``, the outputs the command
refuses or replaces, ``--field`` and the FIELD/LOFAR readers of msleak.io.

Known answers: the CLI's product (the verb must give the same numbers, exactly); the
FIELD directions written into the MS by the test; the phase-centre identities of a
corrected beam (identity Mueller matrix, zero leakage at the centre pixel).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

import msleak
from msleak.cli import cli
from msleak.io.products import open_product

pt = pytest.importorskip("casacore.tables")
pytest.importorskip("everybeam")

MAP = ["--npix", "5", "--fov", "8", "--hour-angles", "-1,0.5"]


def _run(*args):
    return CliRunner().invoke(cli, ["beam", *map(str, args)])


def _two_fields(ms, ddec_deg: float = 1.0):
    """FIELD row 1 = row 0 moved ``ddec_deg`` north (every direction column), named OTHER;
    the second half of the rows observe it."""
    with pt.table(f"{ms}/FIELD", readonly=False, ack=False) as t:
        t.addrows(1)
        for col in t.colnames():
            t.putcell(col, 1, t.getcell(col, 0))
        for col in ("PHASE_DIR", "DELAY_DIR", "REFERENCE_DIR", "LOFAR_TILE_BEAM_DIR"):
            d = t.getcell(col, 1)
            d[..., 1] += np.radians(ddec_deg)
            t.putcell(col, 1, d)
        t.putcell("NAME", 1, "OTHER")
    with pt.table(str(ms), readonly=False, ack=False) as t:
        f = t.getcol("FIELD_ID")
        f[f.size // 2:] = 1
        t.putcol("FIELD_ID", f)


@pytest.mark.parametrize("beam", ["dipole", "everybeam"])
def test_verb_equals_cli_product(small_lofar_ms, tmp_path, beam):
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", "--beam", beam, *MAP)
    assert result.exit_code == 0, result.output
    cli_ds = open_product(tmp_path / "b.h5", "beam")
    ds = msleak.beam_maps(small_lofar_ms, npix=5, fov=8.0, hour_angles=[-1, 0.5], beam=beam)
    assert set(ds.data_vars) == set(cli_ds.data_vars)
    # the same code on the same input; casacore keeps series coefficients between
    # conversions in one process (below 1e-13 rad, docs/beam.md): float64 tolerance
    for name in list(ds.data_vars) + ["hour_angle", "time", "l", "m", "ra", "dec"]:
        np.testing.assert_allclose(ds[name].values, cli_ds[name].values, rtol=1e-9, atol=1e-12,
                                   err_msg=name)
        assert ds[name].attrs.get("units") == cli_ds[name].attrs.get("units")
    for key in ("beam", "freq_hz", "stations", "qu_basis", "field_name", "source"):
        assert ds.attrs[key] == cli_ds.attrs[key]
    assert ds.attrs["field_id"] == cli_ds.attrs["field_id"] == 0
    assert "HISTORY msleak" in cli_ds.attrs["history"]  # the MS's simulate row
    np.testing.assert_allclose(ds["mueller"].values[:, 2, 2], np.broadcast_to(np.eye(4),
                               (2, 4, 4)), atol=1e-9)


def test_verb_output_refused_then_overwritten(small_lofar_ms, tmp_path):
    out = tmp_path / "maps.h5"
    ds = msleak.beam_maps(small_lofar_ms, npix=3, hour_angles=[0], beam="dipole", output=out)
    written = open_product(out, "beam")
    np.testing.assert_array_equal(written["mueller"].values, ds["mueller"].values)
    with pytest.raises(msleak.InputError, match="exists; choose another name or pass "
                                                "overwrite"):
        msleak.beam_maps(small_lofar_ms, npix=3, beam="dipole", output=out)
    again = msleak.beam_maps(small_lofar_ms, npix=3, hour_angles=[0], beam="dipole",
                             output=out, overwrite=True)
    np.testing.assert_array_equal(again["mueller"].values, ds["mueller"].values)


@pytest.mark.parametrize("existing", ["b.png", "b.pdf", "b.h5"])
def test_cli_refuses_existing_outputs_before_any_work(small_lofar_ms, tmp_path, existing):
    (tmp_path / existing).write_text("mine")
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", "--beam", "dipole", *MAP)
    assert result.exit_code == 2, result.output
    assert f"{tmp_path / existing} exists; choose another name or pass --overwrite" in \
        result.output
    assert len(result.output.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".ms") == [existing]
    assert (tmp_path / existing).read_text() == "mine"
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", "--beam", "dipole", *MAP,
                  "--overwrite")
    assert result.exit_code == 0, result.output
    assert all((tmp_path / n).stat().st_size > 1000 for n in ("b.png", "b.pdf", "b.h5"))


def test_no_pdf(small_lofar_ms, tmp_path):
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", "--beam", "dipole", *MAP,
                  "--no-pdf")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "b.png").exists() and not (tmp_path / "b.pdf").exists()


@pytest.mark.parametrize("beam", ["dipole", "everybeam"])
def test_field_selects_pointing_and_rows(small_lofar_ms, tmp_path, beam):
    from msleak.adapters.beams import load_beam

    ms = small_lofar_ms
    with pt.table(f"{ms}/FIELD", ack=False) as t:
        ra0, dec0 = t.getcell("PHASE_DIR", 0)[0]
        delay0 = t.getcell("DELAY_DIR", 0)[0]
    _two_fields(ms)
    by_name = msleak.beam_maps(ms, npix=5, fov=8.0, hour_angles=[0.5], beam=beam,
                               field="OTHER")
    result = _run(ms, "-o", tmp_path / "b.png", "--beam", beam, "--field", "1", "--npix", 5,
                  "--fov", 8, "--hour-angles", "0.5")
    assert result.exit_code == 0, result.output
    by_id = open_product(tmp_path / "b.h5", "beam")
    np.testing.assert_array_equal(by_name["mueller"].values, by_id["mueller"].values)
    assert by_id.attrs["field_id"] == 1 and by_id.attrs["field_name"] == "OTHER"
    assert by_id.attrs["phase_centre_dec_deg"] == pytest.approx(np.degrees(dec0) + 1, abs=1e-9)
    assert by_id.attrs["phase_centre_ra_deg"] == pytest.approx(np.degrees(ra0) % 360, abs=1e-9)
    np.testing.assert_allclose(by_id["mueller"].values[0, 2, 2], np.eye(4), atol=1e-9)
    # the beam is steered at field 1's DELAY_DIR, not row 0's
    model = load_beam(beam, ms, field_id=1)
    pointing = model.pointing if beam == "dipole" else model.array.delay_dir
    np.testing.assert_allclose(pointing, (delay0[0], delay0[1] + np.radians(1.0)),
                               rtol=0, atol=1e-12)
    # field 0 maps differ (another phase centre)
    field0 = msleak.beam_maps(ms, npix=5, fov=8.0, hour_angles=[0.5], beam=beam)
    assert np.abs(field0["dec"].values - by_id["dec"].values).min() > 0.9


@pytest.mark.parametrize("args, message", [
    (["--field", "NOPE"], "'NOPE'"),
    (["--field", "7"], "give --field ID or NAME"),
    (["--npix", "3000"], "--npix must be an integer between 2 and 2049, got 3000"),
    (["--fov", "180"], "--fov must be between 0 and 180 degrees, got 180.0"),
])
def test_new_option_errors(small_lofar_ms, tmp_path, args, message):
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", "--beam", "dipole", *args)
    assert result.exit_code == 2, result.output
    assert message in result.output
    if args[0] == "--field":
        assert args[1] in result.output and "give --field ID or NAME" in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not list(tmp_path.glob("b.*"))


@pytest.mark.parametrize("kwargs, message", [
    (dict(fov=0.0), "fov must be between 0 and 180 degrees"),
    (dict(npix=4.5), "npix must be an integer"),
    (dict(freq=-5.0), "freq must be positive"),
    (dict(beam="none"), "unknown beam 'none'"),
    (dict(beam="everybeam", diameter=30.0), "diameter applies to beam 'dipole' only"),
    (dict(basis="sky"), "unknown Q,U basis 'sky'"),
    (dict(station="CS999HBA0"), "station 'CS999HBA0' is not an antenna"),
])
def test_verb_errors(small_lofar_ms, kwargs, message):
    with pytest.raises(msleak.InputError, match=message):
        msleak.beam_maps(small_lofar_ms, **{"npix": 3, "beam": "dipole", **kwargs})


def test_read_beam_directions_fallback(tmp_path):
    """DELAY_DIR as written; without LOFAR_TILE_BEAM_DIR the tile direction is DELAY_DIR;
    without DELAY_DIR both are the phase centre."""
    from casa_ms import build_ms
    from msleak.io.ms import read_beam_directions

    ms = build_ms(tmp_path / "casa.ms", ra_deg=30.0, dec_deg=-20.0)
    delay = np.radians([[31.0, -21.0]])
    with pt.table(f"{ms}/FIELD", readonly=False, ack=False) as t:
        t.putcell("DELAY_DIR", 0, delay)
        assert "LOFAR_TILE_BEAM_DIR" not in t.colnames()
    d = read_beam_directions(ms)
    np.testing.assert_allclose(d.phase, np.radians([30.0, -20.0]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(d.delay, delay[0], rtol=0, atol=1e-12)
    assert d.tile == d.delay
    with pt.table(f"{ms}/FIELD", readonly=False, ack=False) as t:
        t.removecols("DELAY_DIR")
    d = read_beam_directions(ms)
    assert d.delay == d.phase and d.tile == d.phase
    with pytest.raises(msleak.InputError, match="no FIELD_ID 1"):
        read_beam_directions(ms, 1)


def test_lofar_readers_return_what_simulate_wrote(small_lofar_ms):
    from msleak.io.lofar import read_lofar_antenna_fields, read_lofar_phase_references
    from msleak.io.ms import read_antennas
    from msleak.telescope.layouts import lofar_hba_core

    layout = lofar_hba_core("CS00[1-3]HBA*")
    rows = read_lofar_antenna_fields(small_lofar_ms)
    assert [r.antenna_id for r in rows] == list(range(6))
    assert [r.name for r in rows] == [n[-4:] for n in layout.names]
    for row, field in zip(rows, layout.fields):
        np.testing.assert_allclose(row.axes, field.axes, atol=1e-12)
        np.testing.assert_allclose(row.element_offsets, field.element_offsets, atol=1e-9)
        np.testing.assert_allclose(row.tile_element_offsets, field.tile_offsets, atol=1e-9)
        assert row.element_flags.shape == (24, 2) and not row.element_flags.any()
    np.testing.assert_allclose(read_lofar_phase_references(small_lofar_ms),
                               read_antennas(small_lofar_ms).positions, atol=1e-9)


def test_lofar_array_refusals(tmp_path, small_lofar_ms):
    """The LOFAR layout is refused with the dipole remedy when tables or rows are missing."""
    from casa_ms import build_ms
    from msleak.adapters.beams import read_lofar_array
    from msleak.beam import BeamUnavailable
    from msleak.beam.lofar_array import lofar_array
    from msleak.io.lofar import read_lofar_antenna_fields, read_lofar_phase_references
    from msleak.io.ms import read_antennas, read_beam_directions

    mwa = build_ms(tmp_path / "mwa.ms")
    with pytest.raises(BeamUnavailable, match="no LOFAR_ANTENNA_FIELD table .*use `beam="
                                              "'dipole'`"):
        read_lofar_array(mwa)
    names = read_antennas(small_lofar_ms).names
    rows = read_lofar_antenna_fields(small_lofar_ms)
    refs = read_lofar_phase_references(small_lofar_ms)
    dirs = read_beam_directions(small_lofar_ms)
    array = lofar_array(names, rows, refs, dirs)
    assert [len(s.fields) for s in array.stations] == [1] * 6
    assert array.delay_dir == dirs.delay and array.phase_centre == dirs.phase
    with pytest.raises(BeamUnavailable, match="stations CS003HBA1 have no LOFAR_ANTENNA_FIELD"):
        lofar_array(names, rows[:-1], refs, dirs)
    with pytest.raises(BeamUnavailable, match="no TILE_ELEMENT_OFFSET column"):
        lofar_array(names, [replace(rows[0], tile_element_offsets=None)] + rows[1:], refs, dirs)
