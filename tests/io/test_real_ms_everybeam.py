"""The default (EveryBeam) beam on MSs from other telescopes, built by tests/casa_ms.py:
every EveryBeam failure is a one-line exit-2 error naming `--beam dipole` (or, for the
MWA, the MWA_BEAM_FILE setting its coefficients need), and nothing is written into the MS.
The telescopes msleak accepts are checked against what EveryBeam's own ``load_telescope``
accepts.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from casa_ms import build_ms
from ms_helpers import phase_centre, write_sky, one_error_line
from msleak._everybeam import everybeam_telescope, import_everybeam
from msleak.cli import cli
from msleak.io.ms import column_names

PLACEHOLDERS = ("unused", "flagged", "origin")
#: TELESCOPE_NAMEs with no EveryBeam beam from an MS in msleak's environment
REFUSED = ("MWA", "HERA", "VLA", "OVRO_MMA", "UNKNOWN", "LOFAR")


def _invoke(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _sky(ms, path):
    ra, dec = phase_centre(ms)
    return write_sky(path, [(ra + 0.02, dec + 0.01, 1.0, 0.3, 0.2, 0.0)])


@pytest.fixture(autouse=True)
def _no_mwa_beam_file(monkeypatch):
    monkeypatch.delenv("MWA_BEAM_FILE", raising=False)


@pytest.mark.parametrize("telescope", REFUSED)
@pytest.mark.parametrize("beam", [None, "everybeam", "everybeam-direct"])
def test_beam_and_predict_refused_with_dipole_remedy(tmp_path, telescope, beam):
    ms = build_ms(tmp_path / "obs.ms", telescope=telescope, placeholders=PLACEHOLDERS)
    option = [] if beam is None else ["--beam", beam]
    line = one_error_line(_invoke(["beam", ms, "-o", tmp_path / "b.png", *option]))
    assert "`--beam dipole`" in line
    assert not (tmp_path / "b.png").exists() and not (tmp_path / "b.h5").exists()
    before = column_names(ms)
    line = one_error_line(_invoke(["predict", ms, "--sky", _sky(ms, tmp_path / "s.skymodel"),
                                    *option]))
    assert "`--beam dipole`" in line
    assert column_names(ms) == before


def test_unknown_telescope_message_names_the_known_ones(tmp_path):
    ms = build_ms(tmp_path / "hera.ms", telescope="HERA")
    line = one_error_line(_invoke(["beam", ms, "-o", tmp_path / "b.png"]))
    assert "TELESCOPE_NAME 'HERA'" in line
    assert "AARTFAAC, LOFAR, MID, MWA, OSKAR*, SKA-LOW" in line


def test_mwa_tile_pointing_and_coefficients(tmp_path, monkeypatch):
    """Without MWA_TILE_POINTING EveryBeam has no dipole delays; with it, the MWA FEE
    coefficients file (EveryBeam's "Missing path for MWA coefficients h5 file") is asked
    for through MWA_BEAM_FILE, checked, and EveryBeam's own complaint passed on."""
    import h5py

    bare = build_ms(tmp_path / "bare.ms", telescope="MWA")
    line = one_error_line(_invoke(["beam", bare, "-o", tmp_path / "b.png"]))
    assert "MWA_TILE_POINTING" in line and "`--beam dipole`" in line

    ms = build_ms(tmp_path / "mwa.ms", telescope="MWA", mwa_tile_pointing=True,
                  placeholders=PLACEHOLDERS)
    sky = _sky(ms, tmp_path / "s.skymodel")
    before = column_names(ms)
    not_hdf5 = tmp_path / "coefficients.txt"
    not_hdf5.write_text("not HDF5\n")
    wrong_hdf5 = tmp_path / "other.h5"
    with h5py.File(wrong_hdf5, "w") as f:
        f["x"] = np.arange(3)
    cases = [(None, "MWA_BEAM_FILE is not set"),
             (tmp_path / "missing.h5", "cannot read it"),
             (not_hdf5, "not an HDF5 file"),
             (wrong_hdf5, "EveryBeam cannot make a beam for this MS")]
    for path, reason in cases:
        if path is not None:
            monkeypatch.setenv("MWA_BEAM_FILE", str(path))
        for args in (["beam", ms, "-o", tmp_path / "b.png"], ["predict", ms, "--sky", sky]):
            line = one_error_line(_invoke(args))
            assert reason in line, line
            assert ("set MWA_BEAM_FILE to the path of mwa_full_embedded_element_pattern.h5, "
                    "or use `--beam hyperbeam` (the MWA tile; analytic without any file) or "
                    "`--beam dipole`") in line
    assert column_names(ms) == before


def test_grid_names_its_own_remedies(tmp_path):
    ms = build_ms(tmp_path / "hera.ms", telescope="HERA")
    line = one_error_line(_invoke(["grid", ms, "--beam-area-model", "everybeam",
                                    "--uv-range", "1,200", "-o", tmp_path / "g.h5"]))
    assert "`--beam-area-model dipole`" in line and "`--beam-area SR`" in line
    assert "`--beam dipole`" not in line
    assert not (tmp_path / "g.h5").exists()


NAMES = ("LOFAR", "AARTFAAC", "MWA", "mwa", "OSKAR", "OSKAR_SIM", "SKA-LOW", "MID",
         "SKA-MID", "MEERKAT", "EVLA", "VLA", "ATCA", "GMRT", "ALMA", "OVRO_LWA", "OVRO_MMA",
         "DSA_110", "HERA", "UNKNOWN")


def test_known_telescopes_are_those_everybeam_loads(tmp_path):
    """everybeam_telescope(name) is None exactly when EveryBeam's load_telescope refuses
    the TELESCOPE_NAME (other failures, e.g. missing LOFAR tables, mean it was accepted)."""
    eb = import_everybeam()
    for name in NAMES:
        ms = build_ms(tmp_path / f"{name}.ms", telescope=name, ntime=1, nchan=1)
        try:
            eb.load_telescope(str(ms), use_differential_beam=False,
                              element_response_model="default")
            refused = False
        except (RuntimeError, ValueError) as err:
            refused = "python bindings only support" in str(err)
        assert (everybeam_telescope(name) is None) == refused, name
