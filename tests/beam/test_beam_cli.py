"""``msleak beam``: figure and product, and every user error as one line with exit status 2."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.io.products import open_product

pytest.importorskip("everybeam")


def _run(*args):
    return CliRunner().invoke(cli, ["beam", *map(str, args)])


def test_beam_maps_figure_and_product(small_lofar_ms, tmp_path):
    png = tmp_path / "beam.png"
    result = _run(small_lofar_ms, "-o", png, "--npix", 9, "--fov", 12,
                  "--hour-angles", "-1,0,1.5")
    assert result.exit_code == 0, result.output
    assert png.stat().st_size > 10_000
    ds = open_product(tmp_path / "beam.h5", "beam")
    assert ds["polarized_beam_db"].shape == (3, 9, 9)
    np.testing.assert_allclose(ds["hour_angle"].values, [-1, 0, 1.5])
    # normalised to the phase centre: 0 dB polarized beam and no leakage at the centre pixel
    assert np.abs(ds["polarized_beam_db"].values[:, 4, 4]).max() < 1e-6
    assert ds["leakage"].values[:, 4, 4].max() < 1e-6
    assert np.nanmax(ds["leakage"].values) > 1e-3
    np.testing.assert_allclose(ds["mueller"].values[:, 4, 4], np.broadcast_to(np.eye(4),
                               (3, 4, 4)), atol=1e-9)
    assert ds.attrs["beam"] == "everybeam"


def test_default_hour_angles_span_the_observation(small_lofar_ms, tmp_path):
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", "--npix", 5, "--beam", "dipole",
                  "--product", tmp_path / "maps.h5")
    assert result.exit_code == 0, result.output
    ds = open_product(tmp_path / "maps.h5", "beam")
    assert ds.sizes["hour_angle"] == 5
    ha = ds["hour_angle"].values
    assert np.all(np.diff(ha) > 0) and (ha[-1] - ha[0]) * 3600 == pytest.approx(
        3 * 120 * 1.0027379, rel=1e-3)


def test_everybeam_on_ms_without_lofar_tables(make_ms, tmp_path):
    layout = tmp_path / "array.txt"
    layout.write_text("frame = enu\ntelescope = MYARRAY\nA 0 0 0\nB 100 20 0\nC -50 80 0\n")
    ms = make_ms("custom.ms", layout=str(layout), stations=None)
    result = _run(ms, "-o", tmp_path / "b.png")
    assert result.exit_code == 2
    assert "--beam dipole" in result.output
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.parametrize("args, message", [
    (["--fov", "0"], "--fov"),
    (["--npix", "1"], "--npix"),
    (["--freq", "-5"], "--freq"),
    (["--station", "CS999HBA0"], "--station"),
    (["--diameter", "30"], "--diameter"),
    (["--hour-angles", "a,b"], "comma-separated"),
])
def test_bad_options(small_lofar_ms, tmp_path, args, message):
    result = _run(small_lofar_ms, "-o", tmp_path / "b.png", *args)
    assert result.exit_code == 2
    assert message in result.output


def test_missing_ms(tmp_path):
    result = _run(tmp_path / "nope.ms", "-o", tmp_path / "b.png")
    assert result.exit_code == 2
    assert "no such Measurement Set" in result.output
    assert len(result.output.strip().splitlines()) == 1
