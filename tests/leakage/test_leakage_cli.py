"""``msleak leakage`` end to end on synthetic PS products, and its error paths."""

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from msleak.cli import cli
from msleak.io.products import open_product

from test_leakage_helpers import (gaussian_voxels, make_ps_dataset, rotated_leakage,
                                  write_ps)

EPS = {"15deg": 0.02, "9deg": 0.01, "4deg": 0.004}
SHAPE = (20, 60)


@pytest.fixture(scope="module")
def products(tmp_path_factory):
    """Three 'fields of view' with exact leakage eps, and one observed product."""
    d = tmp_path_factory.mktemp("ps")
    rng = np.random.default_rng(30)
    paths = {}
    for label, eps in EPS.items():
        v_p = gaussian_voxels(SHAPE, 2.0, rng)
        paths[label] = write_ps(d / f"ps_{label}.h5",
                                make_ps_dataset(rotated_leakage(v_p, eps, rng), v_p))
    v_p = gaussian_voxels(SHAPE, 4.0, rng)
    paths["obs"] = write_ps(d / "obs.h5", make_ps_dataset(gaussian_voxels(SHAPE, 1.0, rng),
                                                          v_p))
    return paths


def run(*args):
    return CliRunner().invoke(cli, ["leakage", *map(str, args)])


def test_three_fields_of_view(products, tmp_path):
    out = tmp_path / "out"
    r = run(products["15deg"], products["9deg"], products["4deg"], "--labels",
            "15deg,9deg,4deg", "--field-name", "NCP", "-o", out, "--expected", products["obs"],
            "--expected-model", "field", "--correct", products["obs"])
    assert r.exit_code == 0, r.output + r.stderr
    for name in ("stats.csv", "stats.md", "leakage.h5", "leakage_maps.png", "leakage_maps.pdf",
                 "leakage_hist.png", "expected_obs.h5", "expected_leakage.png",
                 "corrected_obs.h5", "corrected.png"):
        assert (out / name).stat().st_size > 0, name
    with open(out / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:7] == ["input", "label", "mean", "median", "std", "peak",
                                 "pareto_median"]
    assert {"n_voxels", "n_masked"} <= set(rows[0])
    for row, (label, eps) in zip(rows, EPS.items()):
        assert row["label"] == label
        for col in ("mean", "median", "pareto_median"):
            assert float(row[col]) == pytest.approx(100 * eps, rel=1e-5)
        # two voxels, (u, tau) and (-u, -tau), per cell and delay
        assert int(row["n_voxels"]) == 2 * SHAPE[0] * SHAPE[1] and int(row["n_masked"]) == 0
    field = np.mean([100 * e for e in EPS.values()])
    md = (out / "stats.md").read_text()
    assert "| 9deg |" in md and f"**{field:.4g} %**" in md
    res = open_product(out / "leakage.h5", "leakage")
    assert res["L_I"].dims == ("input", "k_par", "k_perp")
    assert res["L_I"].attrs["units"] == "percent"
    for j, eps in enumerate(EPS.values()):
        np.testing.assert_allclose(res["L_I"].values[j], 100 * eps, rtol=1e-10)
    for ds in (res, open_product(out / "corrected_obs.h5", "leakage_corrected")):
        for name, var in ds.data_vars.items():
            if np.issubdtype(var.dtype, np.number):
                assert np.isfinite(var.values).all(), name
    exp = open_product(out / "expected_obs.h5", "leakage_expected")
    obs = open_product(products["obs"], "ps")
    np.testing.assert_allclose(exp["power_leak"].values,
                               obs["power"].sel(stokes="P").values * (field / 100) ** 2,
                               rtol=1e-5)
    cor = open_product(out / "corrected_obs.h5", "leakage_corrected")
    np.testing.assert_allclose(cor["power_I_corrected"].values,
                               obs["power"].sel(stokes="I").values - exp["power_leak"].values,
                               rtol=1e-10, atol=1e-12)
    assert "Per-field estimate" in r.output


def test_default_labels_and_bins_statistics(products, tmp_path):
    r = run(products["9deg"], "-o", tmp_path, "--no-figures", "--stats-from", "bins",
            "--negative", "clip", "--bins", "50")
    assert r.exit_code == 0, r.output + r.stderr
    row = next(csv.DictReader(open(tmp_path / "stats.csv")))
    assert row["label"] == "ps_9deg"
    assert float(row["median"]) == pytest.approx(1.0, rel=1e-6)
    assert not (tmp_path / "leakage_maps.png").exists()


def test_zero_polarized_power_masked_counted_reported(tmp_path):
    rng = np.random.default_rng(31)
    v_p = gaussian_voxels(SHAPE, 1.0, rng)
    v_i = rotated_leakage(v_p, 0.05, rng)
    p_p, p_i = np.abs(v_p) ** 2, np.abs(v_i) ** 2
    p_p[:, :5] = 0.0
    p_i[:, :5] = 0.0
    path = write_ps(tmp_path / "zero.h5", make_ps_dataset(v_i, v_p, power3d_i=p_i,
                                                          power3d_p=p_p))
    r = run(path, "-o", tmp_path / "o", "--no-figures")
    assert r.exit_code == 0, r.output + r.stderr
    # 100 cell-delays with zero P power in both voxels (u, tau) and (-u, -tau)
    assert "masked 200 of 2400 voxels (nonpositive_pp: 200)" in r.stderr
    row = next(csv.DictReader(open(tmp_path / "o" / "stats.csv")))
    assert int(row["n_masked"]) == 200 and int(row["n_voxels"]) == 2200
    assert float(row["median"]) == pytest.approx(5.0, rel=1e-9)
    assert "200 |" in (tmp_path / "o" / "stats.md").read_text()


@pytest.mark.parametrize("drop", ["I", "P"])
def test_missing_stokes_exit_2(tmp_path, drop):
    rng = np.random.default_rng(32)
    v = gaussian_voxels(SHAPE, 1.0, rng)
    path = write_ps(tmp_path / "bad.h5", make_ps_dataset(v, v, drop_stokes=drop))
    r = run(path, "-o", tmp_path / "o")
    assert r.exit_code == 2
    assert f"no Stokes {drop}" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_product_without_mirror_voxels_exit_2(tmp_path):
    """A PS product without power3d_P_mirror has only half of the P voxels: refused for
    voxel statistics with the two remedies, accepted with --stats-from bins."""
    rng = np.random.default_rng(33)
    v = gaussian_voxels(SHAPE, 1.0, rng)
    path = write_ps(tmp_path / "half.h5", make_ps_dataset(0.1 * v, v, with_mirror=False))
    r = run(path, "-o", tmp_path / "o", "--no-figures")
    assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1
    assert ("no 'power3d_P_mirror'" in r.stderr and "rerun `msleak ps`" in r.stderr
            and "--stats-from bins" in r.stderr)
    r = run(path, "-o", tmp_path / "o", "--no-figures", "--stats-from", "bins")
    assert r.exit_code == 0, r.output + r.stderr


def test_all_polarized_power_zero_exit_2(tmp_path):
    v = np.zeros(SHAPE, complex)
    path = write_ps(tmp_path / "dead.h5", make_ps_dataset(v, v))
    r = run(path, "-o", tmp_path / "o", "--no-figures")
    assert r.exit_code == 2 and "P_P is zero or negative" in r.stderr


@pytest.mark.parametrize("extra, msg", [
    (["--labels", "a,b,c"], "3 labels for 2 PS inputs"),
    (["--labels", "a,a"], "labels must be unique"),
    (["--k-par-range", "0.5,0.1"], "MIN < MAX"),
    (["--k-perp-range", "x,1"], "comma-separated list of numbers"),
    (["--bins", "1"], "'--bins'"),
    (["--expected-model", "median", "--expected", "OBS", "--expected", "OBS", "--expected",
      "OBS"], "give 2 observed PS"),
])
def test_usage_errors_exit_2(products, tmp_path, extra, msg):
    extra = [e.replace("OBS", str(products["obs"])) for e in extra]
    r = run(products["9deg"], products["4deg"], "-o", tmp_path / "o", "--no-figures", *extra)
    assert r.exit_code == 2, r.output + r.stderr
    # click usage errors end with one "Error: ..." line; input errors are one line
    assert msg in r.stderr.strip().splitlines()[-1], r.stderr


def test_bad_files_exit_2(products, tmp_path):
    r = run(tmp_path / "nope.h5", "-o", tmp_path / "o")
    assert r.exit_code == 2 and "nope.h5 does not exist" in r.stderr
    out = tmp_path / "o"
    assert run(products["9deg"], "-o", out, "--no-figures").exit_code == 0
    r = run(out / "leakage.h5", "-o", tmp_path / "o2")
    assert r.exit_code == 2 and "is a leakage product, not a power-spectrum product" in r.stderr
    r = run(products["9deg"], "-o", tmp_path / "o3", "--expected", products["obs"],
            "--expected", products["obs"], "--correct", products["obs"], "--no-figures")
    assert r.exit_code == 2 and "pairs one to one" in r.stderr


def test_realisations_give_mean_and_scatter(tmp_path):
    """Three sky realisations of two fields of view each, with exact leakage eps: each
    realisation's estimate is the mean of its two 100 eps, and the field estimate is
    their mean with the standard deviation (ddof 1) over realisations."""
    rng = np.random.default_rng(31)
    eps = {2018: (0.010, 0.006), 2019: (0.012, 0.008), 2020: (0.004, 0.002)}
    paths, labels, reals = [], [], []
    for seed, pair in eps.items():
        for label, e in zip(("15deg", "4deg"), pair):
            v_p = gaussian_voxels(SHAPE, 2.0, rng)
            paths.append(write_ps(tmp_path / f"ps_{label}_{seed}.h5",
                                  make_ps_dataset(rotated_leakage(v_p, e, rng), v_p)))
            labels.append(label)
            reals.append(str(seed))
    out = tmp_path / "out"
    r = run(*paths, "--labels", ",".join(labels), "--realisations", ",".join(reals),
            "--no-figures", "--n-boot", "20", "-o", out)
    assert r.exit_code == 0, r.output
    with open(out / "estimates.csv") as fh:
        rows = list(csv.DictReader(fh))
    per = {int(r["realisation"]): float(r["estimate"]) for r in rows[:-1]}
    expected = {s: 100 * np.mean(p) for s, p in eps.items()}
    assert per.keys() == expected.keys()
    for s in per:
        assert per[s] == pytest.approx(expected[s], rel=1e-5)
    values = np.array(list(expected.values()))
    assert rows[-1]["realisation"] == "all"
    assert float(rows[-1]["estimate"]) == pytest.approx(values.mean(), rel=1e-5)
    assert float(rows[-1]["realisation_std"]) == pytest.approx(values.std(ddof=1), rel=1e-4)
    assert float(rows[-1]["estimate_data"]) == pytest.approx(values.mean(), rel=1e-5)
    with open(out / "stats.csv") as fh:
        assert [int(r["realisation"]) for r in csv.DictReader(fh)] == [int(s) for s in reals]
    md = (out / "stats.md").read_text()
    assert "over 3 sky realisations" in md
    assert f"{values.mean():.4g} ± {values.std(ddof=1):.2g} %" in md
    assert f"{values.mean():.4g} ± {values.std(ddof=1):.2g} %" in r.output


@pytest.mark.parametrize("args, message", [
    (["--realisations", "1,2"], "2 realisations for 3 PS inputs"),
    (["--realisations", "1,x,2"], "expected comma-separated integers"),
    (["--labels", "a,a,b", "--realisations", "1,1,2"], "unique within a realisation"),
])
def test_realisation_errors(products, tmp_path, args, message):
    r = run(products["15deg"], products["9deg"], products["4deg"], *args, "-o", tmp_path / "o")
    assert r.exit_code == 2
    assert message in r.output


def test_maps_figure_shows_the_first_realisation(tmp_path, monkeypatch):
    """Two realisations of two fields of view: the maps figure gets the two inputs of the
    first realisation given (2019 here), in order; the histograms get all four."""
    from msleak.plot import leakage as plots

    rng = np.random.default_rng(32)
    paths, labels, reals = [], [], []
    for seed in (2019, 2018):
        for label in ("15deg", "4deg"):
            v_p = gaussian_voxels(SHAPE, 2.0, rng)
            paths.append(write_ps(tmp_path / f"ps_{label}_{seed}.h5",
                                  make_ps_dataset(rotated_leakage(v_p, 0.01, rng), v_p)))
            labels.append(label)
            reals.append(str(seed))
    shown = {}
    for name in ("plot_leakage_maps", "plot_leakage_histograms"):
        monkeypatch.setattr(plots, name, lambda result, path, pdf=True, _n=name:
                            shown.setdefault(_n, result) and path)
    r = run(*paths, "--labels", ",".join(labels), "--realisations", ",".join(reals),
            "--n-boot", "20", "--no-pdf", "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output
    maps = shown["plot_leakage_maps"]
    assert maps["realisation"].values.tolist() == [2019, 2019]
    assert maps["label"].values.tolist() == ["15deg", "4deg"]
    assert shown["plot_leakage_histograms"].sizes["input"] == 4
