"""``msleak leakage --observed``: the predicted leakage beside the observed Stokes I power,
against answers known in advance: an observation equal to the prediction gives the ratio 1
in every bin and window; one with 4 times the Stokes I power gives 1/4; the EoR-window
sums are those of the bins above the horizon wedge, weighted by their cells."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner

import msleak
from msleak.cli import cli
from msleak.errors import InputError
from msleak.leakage.compare import compare_observed
from msleak.leakage.fraction import stokes_power

from test_leakage_helpers import gaussian_voxels, make_ps_dataset, rotated_leakage, write_ps

SHAPE = (20, 60)


@pytest.fixture(scope="module")
def model():
    rng = np.random.default_rng(7)
    v_p = gaussian_voxels(SHAPE, 2.0, rng)
    return make_ps_dataset(rotated_leakage(v_p, 0.02, rng), v_p)


def _scaled_i(ds, factor):
    out = ds.copy(deep=True)
    labels = [str(s) for s in out["stokes"].values]
    power = out["power"].values
    power[labels.index("I")] *= factor
    return out


def test_same_power_gives_one_everywhere(model):
    c = compare_observed(model, model)
    ok = np.isfinite(c["ratio"].values)
    assert ok.sum() > 0
    np.testing.assert_allclose(c["ratio"].values[ok], 1.0, rtol=1e-12)
    assert c.attrs["window_ratio"] == pytest.approx(1.0, rel=1e-12)
    assert c.attrs["total_ratio"] == pytest.approx(1.0, rel=1e-12)


def test_four_times_the_observed_power_gives_a_quarter(model):
    c = compare_observed(model, _scaled_i(model, 4.0))
    ok = np.isfinite(c["ratio"].values)
    np.testing.assert_allclose(c["ratio"].values[ok], 0.25, rtol=1e-12)
    assert c.attrs["window_ratio"] == pytest.approx(0.25, rel=1e-12)


def test_window_sums_are_above_the_horizon_wedge(model):
    c = compare_observed(model, _scaled_i(model, 2.0))
    slope = float(model.attrs["wedge_slope_horizon"])
    k_par, k_perp = model["k_par"].values[:, None], model["k_perp"].values[None, :]
    counts = model["counts"].transpose("k_par", "k_perp").values
    p_i = stokes_power(model, "power", "I").transpose("k_par", "k_perp").values
    inside = (k_par > slope * k_perp) & (counts > 0) & np.isfinite(p_i) & (p_i > 0)
    assert 0 < inside.sum() < (counts > 0).sum()
    assert c.attrs["window_leak"] == pytest.approx(float(np.sum(counts[inside] * p_i[inside])),
                                                   rel=1e-12)
    assert c.attrs["window_observed"] == pytest.approx(2 * c.attrs["window_leak"], rel=1e-12)


def test_command_writes_the_table_and_figure(model, tmp_path):
    ps = write_ps(tmp_path / "model.h5", model)
    obs = write_ps(tmp_path / "obs.h5", _scaled_i(model, 4.0))
    out = tmp_path / "leak"
    result = CliRunner().invoke(cli, ["leakage", str(ps), "--labels", "15deg", "--observed",
                                      str(obs), "-o", str(out)])
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader(open(out / "observed.csv")))
    assert rows[0]["label"] == "15deg"
    assert float(rows[0]["window_ratio"]) == pytest.approx(0.25, rel=1e-5)
    assert (out / "observed.png").stat().st_size > 10_000


def test_other_bins_refused(model, tmp_path):
    other = model.isel(k_perp=slice(0, -1))
    with pytest.raises(InputError, match="different .k_par, k_perp. bins"):
        compare_observed(model, other)
    ps = write_ps(tmp_path / "m.h5", model)
    with pytest.raises(InputError, match="give them a directory"):
        msleak.leakage(ps, observed=ps)


def test_other_units_and_counts_refused(model, tmp_path):
    other = model.copy(deep=True)
    other["power"].attrs["units"] = "Jy^2"
    with pytest.raises(InputError, match="make both with the same ps options"):
        compare_observed(model, other)
    ps = write_ps(tmp_path / "m.h5", model)
    with pytest.raises(InputError, match="2 observed PS for 3 inputs"):
        msleak.leakage([ps, ps, ps], labels=["a", "b", "c"], observed=[ps, ps],
                       output=tmp_path / "out")
