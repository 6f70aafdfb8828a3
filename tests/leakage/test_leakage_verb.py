"""The Python verb ``msleak.leakage`` against the command, its checks, ``--overwrite``,
provenance (``history``) and the figure titles."""

import csv

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

import msleak
from msleak.cli import cli
from msleak.errors import InputError
from msleak.io.products import history_lines, open_product
from msleak.leakage import STAT_COLUMNS
from msleak.plot.leakage import field_title, input_title
from msleak.verbs.leakage import leakage
from msleak.verbs.leakage_files import estimate_summary

from test_leakage_helpers import gaussian_voxels, make_ps_dataset, rotated_leakage, write_ps

SHAPE = (20, 60)
EPS = {"a": 0.02, "b": 0.005}
CHAINS = {"a": ["2026-01-01 msleak 0.1.0: msleak grid x.ms", "2026-01-01 ps a"],
          "b": ["2026-01-02 msleak 0.1.0: msleak grid y.ms"]}


def _dataset(eps, rng, **attrs):
    v_p = gaussian_voxels(SHAPE, 2.0, rng)
    ds = make_ps_dataset(rotated_leakage(v_p, eps, rng), v_p)
    ds.attrs.update(attrs)
    return ds


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Two PS products with exact leakage eps and a known history chain each (the chain
    written is the given one plus the line of the write that made the file)."""
    d = tmp_path_factory.mktemp("verb")
    rng = np.random.default_rng(40)
    paths = {}
    for label, eps in EPS.items():
        ds = _dataset(eps, rng, column=f"MODEL_{label.upper()}", fov_deg=5.2,
                      source=f"/data/{label}.ms")
        paths[label] = write_ps(d / f"ps_{label}.h5", ds.assign_attrs(
            history="\n".join(CHAINS[label])))
    rng = np.random.default_rng(41)
    paths["obs"] = write_ps(d / "obs.h5", _dataset(0.01, rng))
    return paths


def test_verb_equals_command(inputs, tmp_path):
    """The same inputs and options through the verb (paths, or Datasets in memory) and
    through the CLI give identical statistics, maps and tables."""
    args = dict(labels=["a", "b"], field_name="F", n_boot=20, bootstrap_block=1, seed=3,
                k_par_range=(0.0, 10.0))
    r = CliRunner().invoke(cli, ["leakage", str(inputs["a"]), str(inputs["b"]), "-o",
                                 str(tmp_path / "cli"), "--labels", "a,b", "--field-name",
                                 "F", "--n-boot", "20", "--bootstrap-block", "1", "--seed",
                                 "3", "--k-par-range", "0,10", "--no-figures"])
    assert r.exit_code == 0, r.output + r.stderr
    cli_res = open_product(tmp_path / "cli" / "leakage.h5", "leakage")
    from_paths = leakage([inputs["a"], inputs["b"]], **args)
    in_memory = leakage([open_product(inputs[k], "ps") for k in "ab"], **args)
    for res in (from_paths, in_memory):
        for name in (*STAT_COLUMNS, "L_I", "mask", "hist_counts", "hist_edges",
                     "realisation_estimate"):
            np.testing.assert_array_equal(res[name].values, cli_res[name].values, name)
        assert res.attrs["field_estimate"] == cli_res.attrs["field_estimate"]
    for j, eps in enumerate(EPS.values()):
        assert from_paths["pareto_median"].values[j] == pytest.approx(100 * eps, rel=1e-9)
    assert from_paths["L_I"].attrs["units"] == "percent"
    assert from_paths["median"].attrs["units"] == "percent"
    assert estimate_summary(from_paths) in r.output
    # the verb with an output writes the same table as the command
    leakage([inputs["a"], inputs["b"]], output=tmp_path / "py", figures=False, **args)
    rows = [list(csv.reader(open(tmp_path / d / "stats.csv"))) for d in ("cli", "py")]
    assert rows[0] == rows[1]
    table = from_paths[list(STAT_COLUMNS)].to_dataframe()
    assert list(table.index) == [0, 1]
    assert table["n_voxels"].tolist() == [2 * SHAPE[0] * SHAPE[1]] * 2


def test_package_is_callable_as_the_verb(inputs):
    """``msleak.leakage(...)`` is the verb whether ``msleak.leakage`` resolves to the
    function or to the (already imported) package."""
    res = msleak.leakage(inputs["a"], n_boot=0)
    again = msleak.leakage(inputs["a"], n_boot=0)
    assert float(res["median"][0]) == pytest.approx(100 * EPS["a"], rel=1e-9)
    # equal but for the time stamp of their own history line
    xr.testing.assert_identical(res.assign_attrs(history=""), again.assign_attrs(history=""))


def test_history_keeps_the_input_chains(inputs, tmp_path):
    """One input: its chain, then this command. Several: each input's chain prefixed by
    its label, then this command; expected_<label>.h5 adds the observed chain."""
    written = {k: history_lines(open_product(inputs[k], "ps").attrs) for k in "ab"}
    for k in "ab":
        assert written[k][:-1] == CHAINS[k]
    leakage(inputs["a"], output=tmp_path / "one", n_boot=0, figures=False)
    one = history_lines(open_product(tmp_path / "one" / "leakage.h5", "leakage").attrs)
    assert one[:-1] == written["a"] and len(one) == len(written["a"]) + 1
    assert f"msleak {msleak.__version__}: " in one[-1]
    res = leakage([inputs["a"], inputs["b"]], labels=["A", "B"], output=tmp_path / "two",
                  n_boot=0, figures=False, expected=inputs["obs"], expected_labels=["o"])
    chain = [f"[A] {x}" for x in written["a"]] + [f"[B] {x}" for x in written["b"]]
    assert history_lines(res.attrs)[:-1] == chain
    assert ": msleak.leakage([" in history_lines(res.attrs)[-1]
    two = open_product(tmp_path / "two" / "leakage.h5", "leakage")
    assert history_lines(two.attrs)[:-1] == chain
    assert two.attrs["Conventions"].startswith("CF-")
    obs_chain = history_lines(open_product(inputs["obs"], "ps").attrs)
    exp = open_product(tmp_path / "two" / "expected_o.h5", "leakage_expected")
    assert history_lines(exp.attrs)[:-1] == chain + [f"[observed o] {x}" for x in obs_chain]


def test_existing_output_refused_before_any_work(inputs, tmp_path):
    out = tmp_path / "out"
    run = CliRunner().invoke
    assert run(cli, ["leakage", str(inputs["a"]), "-o", str(out), "--no-figures",
                     "--n-boot", "10"]).exit_code == 0
    before = (out / "stats.csv").stat().st_mtime_ns
    # refused even with a missing input: nothing is read before the check
    r = run(cli, ["leakage", str(tmp_path / "none.h5"), "-o", str(out)])
    assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "holds leakage products (leakage.h5, stats.csv, estimates.csv, stats.md)" in r.stderr
    assert "choose another -o/--output or pass --overwrite" in r.stderr
    assert (out / "stats.csv").stat().st_mtime_ns == before
    r = run(cli, ["leakage", str(inputs["b"]), "-o", str(out), "--no-figures", "--overwrite",
                  "--n-boot", "10"])
    assert r.exit_code == 0, r.output + r.stderr
    res = open_product(out / "leakage.h5", "leakage")
    assert float(res["median"][0]) == pytest.approx(100 * EPS["b"], rel=1e-9)
    with pytest.raises(InputError, match="pass overwrite"):
        leakage(inputs["a"], output=out)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="exists and is not a directory"):
        leakage(inputs["a"], output=tmp_path / "file")


@pytest.mark.parametrize("kwargs, message", [
    (dict(labels=["x"]), "1 labels for 2 PS inputs; give one label per input"),
    (dict(realisations=[1]), "1 realisations for 2 PS inputs"),
    (dict(labels=["x", "x"]), "labels must be unique within a realisation"),
    (dict(k_perp_range=(0.3, 0.1)), "k_perp_range needs 0 <= MIN < MAX, got 0.3,0.1"),
    (dict(hist_quantile=0.2), "hist_quantile must be in [0.5, 1], got 0.2"),
    (dict(expected="OBS"), "give them a directory (output)"),
    (dict(expected="OBS", expected_labels=["p", "q"], output="OUT"),
     "2 expected_labels for 1 observed PS products"),
])
def test_verb_errors(inputs, tmp_path, kwargs, message):
    kwargs = {k: (inputs["obs"] if v == "OBS" else tmp_path / "o" if v == "OUT" else v)
              for k, v in kwargs.items()}
    with pytest.raises(InputError) as err:
        leakage([inputs["a"], inputs["b"]], **kwargs)
    assert message in str(err.value)
    assert not (tmp_path / "o").exists()


def test_dataset_without_power_refused(inputs):
    ds = open_product(inputs["a"], "ps").drop_vars("power")
    with pytest.raises(InputError, match="has no 'power'; give a ps product"):
        leakage(ds)


def test_figure_titles_name_field_column_and_uv_cell(inputs):
    """Inputs are named by label, column and uv cell size with the field 1/cell it is the
    Fourier dual of (degrees(1/16) = 3.58), not by the gridder's half-power width."""
    cubes = [open_product(inputs[k], "ps").assign_attrs(cell_lambda=16.0) for k in "ab"]
    res = leakage(cubes, labels=["15deg", "4deg"], n_boot=0)
    assert input_title(res, 0) == "15deg: MODEL_A, uv cell 16 λ (field 1/cell = 3.58°)"
    assert input_title(res, 1) == "4deg: MODEL_B, uv cell 16 λ (field 1/cell = 3.58°)"
    assert input_title(res, 0, sep="\n") == "15deg: MODEL_A\nuv cell 16 λ (field 1/cell = 3.58°)"
    assert res["cell_lambda"].values.tolist() == [16.0, 16.0]
    assert field_title(res) == "a.ms, b.ms"
    named = leakage(inputs["a"], field_name="NCP", n_boot=0)
    assert field_title(named) == "NCP"
    bare = leakage(inputs["obs"], labels=["obs"], n_boot=0)
    assert input_title(bare, 0) == "obs" and field_title(bare) == ""


def test_every_numeric_variable_has_units(inputs):
    res = leakage([inputs["a"], inputs["b"]], n_boot=0)
    for name, var in res.data_vars.items():
        if name == "mask":
            assert var.attrs["flag_meanings"].split() == [
                "valid", "empty", "nonfinite", "nonpositive_pp", "negative_pi", "not_in_grid"]
            assert list(var.attrs["flag_values"]) == [0, 1, 2, 3, 4, 5]
        elif np.issubdtype(var.dtype, np.number):
            assert var.attrs.get("units"), name
    assert res["n_voxels"].attrs["units"] == "1" and res["power_I"].attrs["units"] == "mK^2 Mpc^3"


def test_pdf_beside_png_has_the_png_layout(tmp_path):
    """save_figure lays a constrained-layout figure out once: the PDF is drawn with the
    axes where the PNG's layout put them (not where they were before it), and the PNG
    keeps the figure's size."""
    import matplotlib.image

    from msleak.plot import new_figure, save_figure

    fig, axes = new_figure(2, 2, figsize=(4.0, 3.0), constrained_layout=True)
    for ax in axes.flat:
        ax.set_ylabel("a long label\nover two lines")
    before = [ax.get_position().bounds for ax in axes.flat]
    drawn = []
    fig.canvas.mpl_connect("draw_event",
                           lambda event: drawn.append([ax.get_position().bounds
                                                       for ax in axes.flat]))
    out = save_figure(fig, tmp_path / "f.png", pdf=True)
    assert out.stat().st_size > 0 and (tmp_path / "f.pdf").stat().st_size > 0
    assert len(drawn) >= 2 and drawn[0] != before
    assert all(positions == drawn[0] for positions in drawn[1:])
    assert matplotlib.image.imread(out).shape[:2] == (3 * 130, 4 * 130)


def test_histogram_view_to_the_95th_percentile(inputs, monkeypatch):
    """The figure's x axis ends at the 0.95 quantile of the voxel L_I and says how many
    voxels lie beyond; the statistics are those of all voxels; the KS p-value is labelled
    as the one for n_eff voxels."""
    import msleak.plot.leakage as plot_leakage
    from msleak.leakage.fraction import leakage_voxels

    rng = np.random.default_rng(7)
    # independent I and P: W = |I~|^2 / |P~|^2 a ratio of exponentials, a Pareto tail
    ds = make_ps_dataset(gaussian_voxels(SHAPE, 0.02, rng), gaussian_voxels(SHAPE, 2.0, rng))
    res = leakage(ds, labels=["a"], n_boot=20)
    L = leakage_voxels(ds, "voxels", "mask", None, None, "a").L
    r = res.isel(input=0)
    edges, beyond = r["hist_view_edges"].values, int(r["n_beyond_hist_view"])
    assert edges[-1] == pytest.approx(np.quantile(L, 0.95), rel=1e-12)
    assert beyond == np.count_nonzero(L > edges[-1]) and beyond > 0.04 * L.size
    assert int(r["hist_view_counts"].sum()) + beyond == L.size == int(r["n_voxels"])
    assert float(r["median"]) == pytest.approx(np.median(L), rel=1e-12)
    assert float(r["mean"]) == pytest.approx(L.mean(), rel=1e-12)
    figures = []
    monkeypatch.setattr(plot_leakage, "save_figure",
                        lambda fig, path, pdf=True: figures.append(fig))
    plot_leakage.plot_leakage_histograms(res, "unused.png")
    ax = figures[0].axes[0]
    assert ax.get_xlim() == pytest.approx((0.0, edges[-1]), rel=1e-12)
    assert ax.get_xlabel().endswith(
        f"(x axis to the 95th percentile; {beyond} of {L.size} voxels beyond)")
    box = [t.get_text() for t in ax.texts if "KS D" in t.get_text()]
    assert len(box) == 1 and box[0].endswith(
        f"KS D = {float(r['ks_d']):.3f}, p = {float(r['ks_p_eff']):.2g}\n"
        f"(p for n_eff = {float(r['n_eff']):.0f} effective voxels)")
