"""The CLI's contract with its users: what -q, the default, -v and -vv print; library
warnings never break the one-line error; every option an error message names exists; the
README's examples run as written; the package imports nothing it relies on by accident."""

from __future__ import annotations

import ast
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import click
import numpy as np
import pytest
import xarray as xr
from astropy.io import fits
from click.testing import CliRunner

from msleak import __version__
from msleak.cli import COMMANDS, cli
from ms_helpers import split_qu_cube

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "msleak"
TINY_SKY = ["--seed", "1", "--npix", "8", "--nchan", "2"]
LOG_LINE = re.compile(r"^\d\d:\d\d:\d\d msleak[\w.]* (DEBUG|INFO|WARNING|ERROR): ")


def msleak(*args) -> subprocess.CompletedProcess:
    """``python -m msleak ARGS`` in a fresh process (real stderr, no pytest warning capture)."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, "-m", "msleak", *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=300)


# -- verbosity -------------------------------------------------------------------------

@pytest.mark.parametrize("flags", [[], ["-q"]])
def test_default_and_quiet_print_only_the_result(tmp_path, flags):
    run = msleak(*flags, "sky", tmp_path / "sky.fits", *TINY_SKY)
    assert run.returncode == 0, run.stderr
    assert run.stderr == ""
    assert run.stdout.splitlines()[0].startswith(f"wrote {tmp_path / 'sky.fits'}: Q,U x 2")
    assert len(run.stdout.splitlines()) == 1


def test_verbose_adds_info_and_double_verbose_adds_debug(tmp_path):
    info = msleak("-v", "sky", tmp_path / "a.fits", *TINY_SKY)
    debug = msleak("-vv", "sky", tmp_path / "b.fits", *TINY_SKY)
    assert info.returncode == 0 and debug.returncode == 0, info.stderr + debug.stderr
    for run in (info, debug):
        lines = run.stderr.splitlines()
        assert lines and all(LOG_LINE.match(line) for line in lines), run.stderr
        assert any("msleak.sky.foreground INFO: foreground cube: rms |P| = 3 K" in line
                   for line in lines)
    assert " DEBUG: " not in info.stderr
    debug_lines = [ln for ln in debug.stderr.splitlines() if " DEBUG: " in ln]
    assert any(f"msleak {__version__} from {PACKAGE}" in ln for ln in debug_lines), \
        debug.stderr


def test_paper_shows_each_step_by_default_and_not_with_quiet(tmp_path):
    """The study's first steps run, then simulate fails on a station pattern that matches
    nothing: by default each step's command is shown as it starts; -q shows only errors,
    the failing step's own line named by the step when steps run in worker processes."""
    args = ["paper", tmp_path / "study", "--field", "3c196", "--stations", "NOPE*",
            "--nchan", "8"]
    default = msleak(*args, "--workers", "1")
    assert default.returncode == 2
    steps = [ln for ln in default.stderr.splitlines() if " msleak.study.steps INFO: run  " in ln]
    assert [ln.split("run  ")[1].split(":")[0] for ln in steps] == [
        "sky", "sky-crop-9deg", "sky-crop-4deg", "simulate-3c196"]
    assert "msleak simulate " in steps[-1] and "--stations 'NOPE*'" in steps[-1]
    for workers in ("1", "2"):                      # the sky steps are up to date now
        quiet = msleak("-q", *args, "--workers", workers)
        assert quiet.returncode == 2
        lines = quiet.stderr.splitlines()
        first = "msleak: error: " if workers == "1" else "[simulate-3c196] msleak: error: "
        assert len(lines) == 2, lines
        assert lines[0].startswith(first) and "'NOPE*'" in lines[0], lines
        assert lines[1].startswith("msleak: error: ") and "rerun `msleak paper`" in lines[1]


# -- library warnings and the one-line error -------------------------------------------

def _truncated_fits(tmp_path, where: str) -> Path:
    """A valid Q,U cube written by astropy, then cut inside its header or its data."""
    header = fits.Header()
    for key, value in [("CTYPE1", "RA---SIN"), ("CRVAL1", 123.4), ("CDELT1", -1.0),
                       ("CRPIX1", 4.5), ("CUNIT1", "deg"), ("CTYPE2", "DEC--SIN"),
                       ("CRVAL2", 48.2), ("CDELT2", 1.0), ("CRPIX2", 4.5), ("CUNIT2", "deg"),
                       ("CTYPE3", "FREQ"), ("CRVAL3", 150e6), ("CDELT3", 195312.5),
                       ("CRPIX3", 1.0), ("CUNIT3", "Hz"), ("CTYPE4", "STOKES"),
                       ("CRVAL4", 2.0), ("CDELT4", 1.0), ("CRPIX4", 1.0), ("BUNIT", "K")]:
        header[key] = value
    data = np.ones((2, 4, 8, 8), np.float32)
    path = tmp_path / f"cut_{where}.fits"
    fits.PrimaryHDU(data, header).writeto(path)
    header_bytes = len(fits.PrimaryHDU(data, header).header.tostring())
    assert header_bytes % 2880 == 0 and fits.getdata(path).shape == data.shape
    cut = header_bytes - 1000 if where == "header" else header_bytes + data.nbytes // 2
    path.write_bytes(path.read_bytes()[:cut])
    return path


def _command(kind: str, cube: Path, ms: Path) -> list:
    if kind == "predict":
        return ["predict", ms, "--sky", cube]
    return ["grid", "--image", cube, "-o", cube.with_suffix(".h5")]


@pytest.mark.parametrize("where", ["header", "data"])
@pytest.mark.parametrize("kind", ["predict", "grid"])
def test_truncated_fits_is_exactly_one_line(tmp_path, small_lofar_ms, kind, where):
    cube = _truncated_fits(tmp_path, where)
    run = msleak(*_command(kind, cube, small_lofar_ms))
    assert run.returncode == 2
    lines = run.stderr.splitlines()
    assert len(lines) == 1, run.stderr
    assert lines[0].startswith("msleak: error: ") and cube.name in lines[0]
    assert run.stdout == ""


@pytest.mark.parametrize("kind", ["predict", "grid"])
def test_verbose_shows_each_library_warning_as_one_line(tmp_path, small_lofar_ms, kind):
    cube = _truncated_fits(tmp_path, "header")
    run = msleak("-v", *_command(kind, cube, small_lofar_ms))
    assert run.returncode == 2
    lines = run.stderr.splitlines()
    assert lines[-1].startswith("msleak: error: ") and cube.name in lines[-1]
    assert all(LOG_LINE.match(line) for line in lines[:-1]), run.stderr
    assert any("msleak.warnings INFO: VerifyWarning: " in line and "2880" in line
               for line in lines[:-1]), run.stderr


# -- every option an error message names exists ----------------------------------------

OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
#: "msleak <command> ..." up to a quote, bracket, comma, semicolon or line end
MENTION = re.compile(r"\bmsleak (" + "|".join(COMMANDS) + r")\b([^`'\"(),;\n]*)")


def _options(command: click.Command) -> set[str]:
    params = command.get_params(click.Context(command))
    return {opt for p in params for opt in (*p.opts, *p.secondary_opts)}


def _attributed_options(text: str, own: str | None) -> list[tuple[str | None, str]]:
    """(command, option) of every ``--option`` in ``text``: options written right after
    ``msleak <command>`` belong to that command, the others to ``own``."""
    found = [(m.group(1), opt) for m in MENTION.finditer(text)
             for opt in OPTION.findall(m.group(2))]
    rest = MENTION.sub(" ", text)
    return found + [(own, opt) for opt in OPTION.findall(rest)]


def _string_literals(path: Path):
    """(line, text) of every str literal of ``path``, the constant parts of f-strings too."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            yield node.lineno, node.value


def test_error_remedies_exist():
    """Every ``--option`` in a string of msleak/ is an option of the msleak group or of a
    command: of the command written just before it (``msleak grid --cell``), else of the
    command whose module holds the string (msleak/cli/<cmd>.py), else of any command."""
    ctx = click.Context(cli)
    group = _options(cli)
    per_command = {name: _options(cli.get_command(ctx, name)) for name in COMMANDS}
    any_command = set().union(*per_command.values())
    wrong, checked = [], 0
    for path in sorted(PACKAGE.rglob("*.py")):
        own = path.stem if path.parent.name == "cli" and path.stem in COMMANDS else None
        for lineno, text in _string_literals(path):
            for owner, option in _attributed_options(text, own):
                checked += 1
                if option not in group | (per_command[owner] if owner else any_command):
                    wrong.append(f"{path.relative_to(ROOT)}:{lineno}: {option} "
                                 f"(msleak {owner or '<any command>'})")
    assert checked > 50            # the scan sees the messages (there are hundreds)
    assert not wrong, "options that do not exist:\n" + "\n".join(wrong)


def test_remedy_scan_attributes_options_to_their_command():
    text = ("no sky; pass --sky FILE (see msleak predict --sky --fov) or `msleak ps`, "
            "--cell")
    assert _attributed_options(text, "grid") == [
        ("predict", "--sky"), ("predict", "--fov"), ("grid", "--sky"), ("grid", "--cell")]
    grid = _options(cli.get_command(click.Context(cli), "grid"))
    assert "--sky" not in grid and "--cell" in grid


# -- every command answers --help; README examples run -----------------------------------

def test_every_command_is_listed_and_has_help():
    top = CliRunner().invoke(cli, ["--help"])
    assert top.exit_code == 0
    listed = top.output.split("Commands:")[1].split()
    for name in COMMANDS:
        assert name in listed
        result = CliRunner().invoke(cli, [name, "--help"], prog_name="msleak")
        assert result.exit_code == 0, result.output
        assert result.output.startswith(f"Usage: msleak {name} "), result.output


def _readme_command(prefix: str) -> list[str]:
    lines = [ln.strip() for ln in (ROOT / "README.md").read_text().splitlines()
             if ln.strip().startswith(prefix)]
    assert len(lines) == 1, lines
    return shlex.split(lines[0].split("#")[0])[1:]


def test_readme_grid_image_example_runs_as_written(tmp_path, monkeypatch):
    """The README's ``msleak grid --image obs_Q.fits --image obs_U.fits ...`` on Q and U
    cubes without a STOKES axis (split from one msleak sky cube) gives the same uv cube as
    gridding the Q,U cube itself."""
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    assert runner.invoke(cli, ["sky", "sky.fits", "--seed", "1", "--npix", "16",
                               "--nchan", "4"]).exit_code == 0
    split_qu_cube("sky.fits", "obs_")
    args = _readme_command("msleak grid --image obs_Q.fits")
    result = runner.invoke(cli, args)
    assert result.exit_code == 0, result.output
    out = args[args.index("-o") + 1]
    reference = runner.invoke(cli, ["grid", "--image", "sky.fits",
                                    *args[args.index("--fov"):args.index("--fov") + 2],
                                    "-o", "reference.h5"])
    assert reference.exit_code == 0, reference.output
    split = xr.open_dataset(out, engine="h5netcdf")
    whole = xr.open_dataset("reference.h5", engine="h5netcdf")
    for stokes in "QU":
        a, b = split["vis"].sel(stokes=stokes).values, whole["vis"].sel(stokes=stokes).values
        assert np.abs(b).max() > 0
        np.testing.assert_array_equal(a, b)


# -- the package relies on no import made elsewhere ------------------------------------

def _submodule_uses(path: Path) -> dict[str, int]:
    """``pkg.sub`` (a submodule) used as an attribute in ``path`` without being imported
    there: name -> first line."""
    import importlib.util

    tree = ast.parse(path.read_text(), str(path))
    bound, imported = {}, set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                bound[alias.asname or parts[0]] = alias.name if alias.asname else parts[0]
                imported.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            parts = node.module.split(".")
            imported.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
            imported.update(f"{node.module}.{alias.name}" for alias in node.names)
    uses = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in bound:
            name = f"{bound[node.value.id]}.{node.attr}"
            if name in imported or name in uses:
                continue
            try:
                found = importlib.util.find_spec(name) is not None
            except (ImportError, ValueError):
                found = False
            if found:
                uses[name] = node.lineno
    return uses


def test_submodule_scan_finds_a_missing_import(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("import importlib\nimport os.path\nimport numpy as np\n"
                      "x = importlib.util, os.path, np.fft, np.float64\n")
    assert _submodule_uses(source) == {"importlib.util": 4, "numpy.fft": 4}


def test_submodules_used_are_imported_or_loaded_by_their_package():
    """``import importlib`` then ``importlib.util`` works only if something else imported
    importlib.util first (an editable install's .pth file does; a wheel install does not).
    Each such use must be imported in its module or be loaded by a bare ``import pkg`` in
    a fresh interpreter without site hooks (python -S)."""
    uses = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for name, line in _submodule_uses(path).items():
            uses.setdefault(name, f"{path.relative_to(ROOT)}:{line}")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    missing = []
    for name, where in sorted(uses.items()):
        package, attr = name.rsplit(".", 1)
        probe = subprocess.run([sys.executable, "-S", "-c",
                                f"import {package}; {package}.{attr}"],
                               env=env, capture_output=True, text=True, timeout=120)
        if probe.returncode != 0:
            missing.append(f"{where}: {name} ({probe.stderr.strip().splitlines()[-1]})")
    assert not missing, "import these explicitly:\n" + "\n".join(missing)
