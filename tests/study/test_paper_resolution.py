"""msleak paper --resolution paper|observed: the commands of each plan against values
computed here from the definitions (the paper's 50 pixels of 0.3 deg and 30-180
wavelengths; for observed data, baselines up to 800 wavelengths and pixels of at most
1/(2 x 800) rad), one OUTDIR per resolution, and a tiny observed study end to end."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import click
import numpy as np
import pytest
import xarray as xr
from astropy.cosmology import Planck18
from astropy.io import fits
from click.testing import CliRunner

from msleak.cli import cli
from msleak.predict.gridsky import AUTO_MIN_PIXELS
from msleak.study.config import StudyConfig
from msleak.study.pipeline import STUDY_FILE, run_study, study_steps
from msleak.cli import run_command as run_msleak
from msleak.study.steps import StepRunner

#: the definitions: observed LOFAR baselines, the paper's sky and its crops
UV_MAX = 800.0
SKY_FOV = 15.0
PAPER_PIXEL = 0.3                                  # deg: 50 pixels over 15 deg
PAPER_CROPS = {"9deg": 28, "4deg": 16}             # the paper's pixel counts
F21 = 1420.405751768e6                             # Hz


def parsed(step) -> dict:
    """The parameters the step's msleak command runs with (defaults included), as click
    parses its command line."""
    cmd = cli.get_command(click.Context(cli), step.args[0])
    return cmd.make_context(step.args[0], [str(a) for a in step.args[1:]]).params


def nearest_same_parity(exact: float, parity: int) -> int:
    """The integer of ``parity`` (0 or 1) nearest to ``exact`` (by search)."""
    return min((n for n in range(parity or 2, int(exact) + 3, 2)),
               key=lambda n: abs(n - exact))


def observed_sky(fov: float) -> tuple[int, dict]:
    """Pixels a side of a ``fov``-deg sky resolving UV_MAX wavelengths, and its crops:
    the paper's crop angles scaled to ``fov``, at that pixel."""
    npix = math.ceil(2 * UV_MAX * math.radians(fov))
    pixel = fov / npix
    crops = {label: nearest_same_parity(n * PAPER_PIXEL * fov / SKY_FOV / pixel, npix % 2)
             for label, n in PAPER_CROPS.items()}
    return npix, crops


def k_perp(b_lambda: float, nchan: int) -> float:
    """k_perp (Mpc^-1) of a baseline at the centre of the study's band (astropy)."""
    centre = 150e6 + 0.5 * (nchan - 1) * 195312.5
    return 2 * math.pi * b_lambda / Planck18.comoving_distance(F21 / centre - 1).to_value("Mpc")


def plan(resolution: str, **kw) -> dict:
    cfg = StudyConfig(outdir=Path("/nonexistent/study"), resolution=resolution,
                      fields=("ncp",), **kw)
    return {step.name: step for step in study_steps(cfg)}


def test_observed_sky_pixel_resolves_800_wavelengths():
    npix, crops = observed_sky(SKY_FOV)
    pixel_rad = math.radians(SKY_FOV / npix)
    assert pixel_rad <= 1 / (2 * UV_MAX)                     # Nyquist at 800 wavelengths
    assert math.radians(SKY_FOV / (npix - 1)) > 1 / (2 * UV_MAX)   # and the fewest pixels
    for label, n in crops.items():                           # the paper's crop angles
        assert abs(n * SKY_FOV / npix - PAPER_CROPS[label] * PAPER_PIXEL) <= SKY_FOV / npix
    steps = plan("observed")
    sky = parsed(steps["sky"])
    assert (sky["npix"], sky["fov"]) == (npix, SKY_FOV)
    for label, n in crops.items():
        assert parsed(steps[f"sky-crop-{label}"])["crop_npix"] == n
    cfg = StudyConfig(outdir=Path("x"), resolution="observed")
    assert cfg.fields_of_view == (("15deg", npix), *crops.items())


@pytest.mark.parametrize("resolution", ["paper", "observed"])
def test_plan_of_each_resolution(resolution):
    """sky, crops, predict method, grid's uv range and cell, ps's k_perp range of the 1D
    PS, as msleak parses each command; the grid and ps of every field of view alike."""
    steps = plan(resolution)
    if resolution == "paper":
        npix, crops = round(SKY_FOV / PAPER_PIXEL), PAPER_CROPS
        uv, method, k1d = (30.0, 180.0), None, (0.02, 0.1)
    else:
        npix, crops = observed_sky(SKY_FOV)
        uv, method = (30.0, UV_MAX), "auto"
        k1d = (0.02, math.ceil(100 * k_perp(UV_MAX, 50)) / 100)
    assert parsed(steps["sky"])["npix"] == npix
    for label, n in crops.items():
        assert parsed(steps[f"sky-crop-{label}"])["crop_npix"] == n
    predict = parsed(steps["predict-ncp"])
    if resolution == "paper":
        # no --method: msleak predict's default, which sums skies this small directly
        assert "--method" not in steps["predict-ncp"].args
        assert predict["method"] == "direct" or (predict["method"] == "auto"
                                                 and npix ** 2 < AUTO_MIN_PIXELS)
    else:
        assert predict["method"] == method
        assert min(crops.values()) ** 2 >= AUTO_MIN_PIXELS       # every sky degridded
    assert [Path(s).name for s in predict["sky"]] == ["sky.fits", "sky_9deg.fits",
                                                      "sky_4deg.fits"]
    grid = parsed(steps["grid-ncp"])
    assert tuple(grid["uv_range"]) == uv and grid["cell"] == 16.0
    assert len(grid["columns"]) == len(grid["outputs"]) == 3
    for fov in ("15deg", "9deg", "4deg"):
        ps = parsed(steps[f"ps-ncp-{fov}"])
        if resolution == "paper":
            assert ps["kperp_1d"] is None                    # msleak ps's 0.02,0.1
        else:
            assert tuple(ps["kperp_1d"]) == pytest.approx(k1d)
            # the 1D PS takes every voxel: its upper end is past 800 wavelengths, within
            # the 0.01 Mpc^-1 it is rounded to
            assert k_perp(UV_MAX, 50) <= k1d[1] < k_perp(UV_MAX, 50) + 0.01
        assert parsed(steps[f"transform-ncp-{fov}"])["window"] == "blackman-harris"


def test_paper_resolution_runs_the_commands_it_always_ran():
    """The default plan passes none of the observed options, so an OUTDIR made before
    --resolution existed resumes without recomputing anything."""
    for step in plan("paper").values():
        assert not {"--uv-range", "--method", "--npix", "--kperp-1d"} & set(step.args)
    assert plan("paper").keys() == plan("observed").keys()


def test_quick_observed_is_small_and_reaches_800_wavelengths():
    """--quick with --resolution observed: 2 h at 600 s, 20 HBA fields (CS002-CS004 and
    the CS02x/CS03x ring) whose longest baseline is past 800 wavelengths at the top of the
    band, where the quick paper set of 18 fields is not."""
    from msleak.telescope.layouts import lofar_hba_core

    top = 150e6 + 49.5 * 195312.5
    longest = {}
    for resolution in ("paper", "observed"):
        sim = parsed(plan(resolution, quick=True)["simulate-ncp"])
        assert (sim["duration"], sim["interval"]) == (2.0, 600.0)
        pos = lofar_hba_core(sim["stations"]).positions
        dist = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
        longest[resolution] = (len(pos), dist.max() * top / 299792458.0)
    assert longest["observed"][0] == 20 and longest["observed"][1] > UV_MAX
    assert longest["paper"][1] < UV_MAX
    full = parsed(plan("observed")["simulate-ncp"])
    assert full["stations"] is None                         # all 48 fields


def test_a_changed_resolution_reuses_no_stale_step():
    """Between the two plans every step either runs another command or reads, through
    its inputs or the steps it follows, a product of one that does; only the resolution-
    free ones (the MS and its beam maps, given the same stations) are the same work."""
    paper, observed = plan("paper", stations="CS00[1-4]HBA*"), \
        plan("observed", stations="CS00[1-4]HBA*")
    changed = set()
    made_by = {str(o): name for name, s in observed.items() for o in s.outputs}
    for name, step in paper.items():
        ours = observed[name]
        upstream = {made_by.get(str(i)) for i in step.inputs} | set(step.after)
        if step.args != ours.args or upstream & changed:
            changed.add(name)
    assert set(paper) - changed == {"simulate-ncp", "beam-ncp"}


def test_another_resolution_in_the_same_outdir_is_refused(tmp_path):
    """One OUTDIR holds one resolution (the products have the same names): the other is
    refused in one line before any step runs, unless --overwrite; an OUTDIR made before
    msleak recorded the resolution is a paper one."""
    out = tmp_path / "study"
    out.mkdir()
    (out / ".msleak-steps.json").write_text("{}")
    runner = CliRunner()
    for made, asked in (("paper", "observed"), ("observed", "paper")):
        if made == "observed":
            (out / STUDY_FILE).write_text(json.dumps({"resolution": "observed"}))
        result = runner.invoke(cli, ["paper", str(out), "--resolution", asked, "--field",
                                     "ncp", "--workers", "1"])
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and f"holds a --resolution {made} study" in lines[0]
        assert "--overwrite" in lines[0]
        assert sorted(p.name for p in out.iterdir()) == sorted(
            [".msleak-steps.json"] + ([STUDY_FILE] if made == "observed" else []))


# -- a tiny observed study end to end -------------------------------------------------------

TINY_FOV = 6.0        # deg: 168 pixels; the 15 and 9 deg skies are degridded, 4 deg summed
TINY_NCHAN = 8


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_observed") / "study"
    cfg = StudyConfig(outdir=out, fields=("3c196",), beam="dipole", resolution="observed",
                      sky_fov_deg=TINY_FOV, stations="CS002HBA*,CS03[02]HBA*",
                      duration_h=0.34, interval_s=600.0, nchan=TINY_NCHAN)

    def invoke(args):
        assert run_msleak(["-q", *map(str, args)]) == 0, args

    run_study(cfg, invoke)
    return cfg


def test_tiny_observed_study_products(tiny):
    out = Path(tiny.outdir)
    npix, crops = observed_sky(TINY_FOV)
    for name, n in (("sky.fits", npix), ("sky_9deg.fits", crops["9deg"]),
                    ("sky_4deg.fits", crops["4deg"])):
        header = fits.getheader(out / "sky" / name)
        assert header["NAXIS1"] == header["NAXIS2"] == n
        assert abs(header["CDELT2"]) == pytest.approx(TINY_FOV / npix, rel=1e-9)
    k_max = k_perp(UV_MAX, TINY_NCHAN)
    k_180 = k_perp(180.0, TINY_NCHAN)
    for fov in ("15deg", "9deg", "4deg"):
        with xr.open_dataset(out / "3c196" / f"ps_{fov}.h5", engine="h5netcdf") as ps:
            assert (ps.attrs["uv_min_lambda"], ps.attrs["uv_max_lambda"]) == (30.0, UV_MAX)
            bounds = ps["k_perp_bounds"].values
            # k_perp of the outer edge (msleak ps, astropy's Planck18 D_c; 1e-6: the
            # agreement docs/ps.md states)
            assert bounds[-1, 1] == pytest.approx(k_max, rel=1e-6)
            # baselines past the paper's 180 wavelengths reach the power spectrum
            assert ps["counts"].values[:, bounds[:, 0] > k_180].sum() > 0
            assert ps.attrs["k_perp_max_1d"] >= bounds[-1, 1]
    with open(out / "3c196" / "leakage" / "stats.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["label"] for r in rows] == ["15deg", "9deg", "4deg"]
    assert all(np.isfinite(float(r["median"])) and float(r["median"]) > 0 for r in rows)
    report = (out / "report.md").read_text()
    assert "30-800 wavelengths" in report and "--method auto" in report
    assert json.loads((out / STUDY_FILE).read_text()) == {"resolution": "observed"}


def test_tiny_observed_study_resumes(tiny):
    """Run again: every step is up to date, nothing reruns."""
    out = Path(tiny.outdir)
    before = json.loads((out / ".msleak-steps.json").read_text())
    ran = []
    run_study(tiny, ran.append)
    assert ran == [] and json.loads((out / ".msleak-steps.json").read_text()) == before
    runner = StepRunner(out)
    assert all(runner.fingerprint(s) == before[s.name]["fingerprint"]
               for s in study_steps(tiny))
