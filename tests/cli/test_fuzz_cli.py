"""CLI fuzz: random option values and random input-file contents for every command.

Whatever the input, a command must end with exit status 0, or 2 with a one-line
``msleak: error:`` / click ``Error:`` message; never a traceback and never status 1
(an unexpected failure). The cases are drawn from a seeded generator (set
MSLEAK_FUZZ_SEED to reproduce or vary; the seed is printed on failure) and the loop
stops after a time budget so the test stays bounded (< 60 s).
"""

from __future__ import annotations

import os
import random
import shutil
import time

import pytest
from click.testing import CliRunner

from msleak.cli import cli

BUDGET_S = float(os.environ.get("MSLEAK_FUZZ_BUDGET", "30"))

BAD = ["", " ", "abc", "-1", "0", "nan", "inf", "-inf", "1e308", "-1e308", "1,2", ",", "1,,2",
       "0x10", "1;2", "\u00e9\u00e9", "-0", "3.5.1", "9" * 40]
FLOATS = BAD + ["1", "2.5", "0.5"]
INTS = BAD + ["1", "2", "3"]
PAIRS = BAD + ["30,180", "1,200", "180,30", "0,0", "1,2,3", "nan,1", "-5,5"]
WORDS = BAD + ["I", "Q,U", "DATA", "MODEL_DATA", "Planck18", "x"]

# option -> value pool, per command; "flag" options are toggled
OPTIONS = {
    "simulate": {"--field": ["ncp", "3c196", "moon", ""], "--phase-centre": PAIRS,
                 "--start": ["2013-01-01T00:00:00", "yesterday", "2013-13-45", ""],
                 "--duration": FLOATS, "--interval": FLOATS, "--freq-min": FLOATS,
                 "--nchan": INTS, "--chan-width": FLOATS,
                 "--stations": ["CS001HBA*", "XYZ*", "", "[", "CS00[1-2]HBA0"],
                 "--autocorrelations": "flag", "--overwrite": "flag"},
    "sky": {"--fov": FLOATS, "--npix": INTS, "--freq-min": FLOATS, "--nchan": INTS,
            "--chan-width": FLOATS, "--seed": INTS, "--phase-centre": PAIRS,
            "--units": ["K", "Jy/pixel", "mK"], "--depth-pc": FLOATS, "--ncells-los": INTS,
            "--b-regular": PAIRS + ["1,1,1"], "--b-random-rms": FLOATS, "--ne-mean": FLOATS,
            "--ne-sigma": FLOATS, "--electron-index": FLOATS, "--outer-scale-pc": FLOATS,
            "--p-rms": FLOATS, "--ref-freq": FLOATS, "--crop-npix": INTS,
            "--skymodel-channel": INTS, "--plot-channel": INTS, "--plot-pixel": PAIRS},
    "beam": {"--fov": FLOATS, "--npix": INTS, "--hour-angles": PAIRS, "--freq": FLOATS,
             "--beam": ["dipole", "everybeam", "none"], "--station": ["CS001HBA0", "XX", ""],
             "--diameter": FLOATS},
    "predict": {"--fov": FLOATS, "--beam": ["none", "dipole", "magic"], "--column": WORDS,
                "--memory-limit": BAD + ["1KB", "2GB", "1.5M"], "--field": WORDS + ["0"],
                "--spw": WORDS + ["0"], "--interpolate-frequency": "flag", "--double": "flag",
                "--double-column": "flag",
                "--restart": "flag", "--no-centre-correction": "flag",
                "--workers": INTS},
    "grid": {"--column": WORDS, "--cell": FLOATS, "--uv-range": PAIRS,
             "--gridder": ["wgrid", "cell", "fft"], "--split": ["even-odd", "first-second", "x"],
             "--field": WORDS + ["0"], "--spw": INTS, "--beam-area": FLOATS,
             "--chunk-rows": INTS, "--epsilon": FLOATS, "--threads": INTS},
    "transform": {"--window": ["blackman-harris", "hann", "none", "boxcar", ""],
                  "--partial": ["drop", "zero", "x"]},
    "ps": {"--cosmology": WORDS + ["WMAP9"], "--bins": INTS, "--bin-width": FLOATS,
           "--log-bins": "flag", "--sph-bins": INTS, "--kperp-1d": PAIRS,
           "--primary-theta": FLOATS, "--beam-area": FLOATS, "--cross": "flag",
           "--stokes": WORDS, "--h0": FLOATS, "--om0": FLOATS, "--ob0": FLOATS,
           "--tcmb0": FLOATS, "--little-h": "flag"},
    "leakage": {"--labels": WORDS + ["a,a", "a,b"], "--stats-from": ["voxels", "bins", "x"],
                "--negative": ["mask", "clip", "x"], "--bins": INTS, "--hist-quantile": FLOATS,
                "--k-par-range": PAIRS, "--k-perp-range": PAIRS, "--expected-model":
                ["auto", "map", "median", "field", "x"], "--leakage-rel-error": FLOATS,
                "--no-figures": "flag"},
    "paper": {"--seed": INTS, "--field": ["ncp", "3c196", "x"], "--beam": ["dipole", "x"],
              "--observed": ["ncp=a.fits,b.fits", "x", "ncp=", "moon=a,b", ""]},
}


def _random_bytes(rng, n):
    return bytes(rng.getrandbits(8) for _ in range(n))


@pytest.fixture(scope="module")
def world(tmp_path_factory, _small_lofar_ms_master):
    """Valid inputs of every kind, made once: MS, sky cube, sky model, products."""
    from msleak.adapters.sky_fits import write_cube
    from msleak.io.products import open_product, save_product
    from msleak.verbs.power import power_spectrum
    from msleak.verbs.transform import transform
    import msleak
    from msleak.sky.foreground import generate_foreground_cube

    d = tmp_path_factory.mktemp("fuzz")
    import casacore.tables as pt

    with pt.table(str(_small_lofar_ms_master / "FIELD"), ack=False) as t:
        ra, dec = (float(x) for x in t.getcell("PHASE_DIR", 0).reshape(-1)[:2])
    cube = generate_foreground_cube(npix=6, fov_deg=2.0, freq_min_hz=150e6, nchan=4,
                                    chan_width_hz=195312.5, phase_centre=(ra, dec), seed=2)
    write_cube(cube, d / "sky.fits", overwrite=True)
    (d / "sky.skymodel").write_text(f"format = Name, Type, Ra, Dec, I, Q, U, V\n"
                                    f"a, POINT, {ra!r}, {dec!r}, 1, 0.2, 0.1, 0\n")
    uv = msleak.grid(_small_lofar_ms_master, uv_range=(1.0, 200.0), gridder="cell")
    save_product(uv, d / "uv.h5", "uvcube", overwrite=False)
    save_product(transform(open_product(d / "uv.h5")), d / "delay.h5", "delay", overwrite=False)
    save_product(power_spectrum(open_product(d / "delay.h5")), d / "ps.h5", "ps", overwrite=False)
    return dict(dir=d, ms=_small_lofar_ms_master)


def _input_file(rng, world, kind, work):
    """A valid input of ``kind``, or (sometimes) a damaged or missing one."""
    d = world["dir"]
    src = {"fits": d / "sky.fits", "skymodel": d / "sky.skymodel", "uv": d / "uv.h5",
           "delay": d / "delay.h5", "ps": d / "ps.h5"}[kind]
    choice = rng.random()
    dst = work / f"in_{rng.randrange(10**9)}{src.suffix}"
    if choice < 0.6:
        return src
    if choice < 0.7:
        dst.write_bytes(b"")
    elif choice < 0.8:
        dst.write_bytes(_random_bytes(rng, rng.randrange(1, 4000)))
    elif choice < 0.9:
        data = src.read_bytes()
        dst.write_bytes(data[:rng.randrange(1, len(data))])
    elif choice < 0.95:
        data = bytearray(src.read_bytes())
        for _ in range(rng.randrange(1, 20)):
            data[rng.randrange(len(data))] = rng.getrandbits(8)
        dst.write_bytes(bytes(data))
    else:
        return work / "missing" / src.name
    return dst


def _base_args(rng, command, world, work):
    if command == "simulate":
        return ["simulate", work / f"s{rng.randrange(10**6)}.ms", "--stations", "CS001HBA*",
                "--duration", "0.05", "--interval", "60", "--nchan", "2"]
    if command == "sky":
        if rng.random() < 0.5:
            return ["sky", work / "out.fits", "--npix", "6", "--nchan", "2", "--ncells-los", "8",
                    "--overwrite"]
        return ["sky", "--crop", _input_file(rng, world, "fits", work), work / "crop.fits",
                "--overwrite"]
    if command in ("beam", "predict", "grid"):
        ms = work / "ms.ms"
        if not ms.exists():
            shutil.copytree(world["ms"], ms)
        if command == "beam":
            return ["beam", ms, "-o", work / "b.png", "--npix", "8", "--beam", "dipole",
                    "--hour-angles", "0"]
        if command == "predict":
            sky = _input_file(rng, world, rng.choice(["fits", "skymodel"]), work)
            return ["predict", ms, "--sky", sky, "--beam", "none", "--column", "MODEL_FUZZ"]
        return ["grid", ms, "-o", work / "g.h5", "--uv-range", "1,200", "--gridder", "cell"]
    if command == "transform":
        return ["transform", _input_file(rng, world, "uv", work), "-o", work / "d.h5"]
    if command == "ps":
        return ["ps", _input_file(rng, world, "delay", work), "-o", work / "p.h5"]
    if command == "leakage":
        return ["leakage", _input_file(rng, world, "ps", work), "-o", work / "leak",
                "--no-figures"]
    if command == "paper":
        return ["paper", work / "study", "--observed", "ncp=none_q.fits,none_u.fits"]
    raise AssertionError(command)


def _mutate(rng, command, args):
    opts = OPTIONS[command]
    for _ in range(rng.randrange(0, 3)):
        name = rng.choice(sorted(opts))
        pool = opts[name]
        args = args + ([name] if pool == "flag" else [name, rng.choice(pool)])
    return args


def test_cli_fuzz_never_tracebacks(world, tmp_path):
    seed = int(os.environ.get("MSLEAK_FUZZ_SEED", "20240610"))
    rng = random.Random(seed)
    runner = CliRunner()
    commands = sorted(OPTIONS)
    start = time.monotonic()
    counts = {c: [0, 0] for c in commands}   # [exit 0, exit 2]
    failures = []
    k = 0
    while time.monotonic() - start < BUDGET_S or min(sum(v) for v in counts.values()) < 3:
        if time.monotonic() - start > 2.5 * BUDGET_S:
            break
        command = commands[k % len(commands)]
        k += 1
        work = tmp_path / f"c{k}"
        work.mkdir()
        args = [str(a) for a in _mutate(rng, command, _base_args(rng, command, world, work))]
        result = runner.invoke(cli, args)
        out = result.output.strip()
        lines = out.splitlines()
        ok = result.exit_code in (0, 2) and "Traceback" not in out
        if result.exit_code == 2:
            ok = ok and bool(lines) and lines[-1].startswith(("msleak: error:", "Error:"))
        if not ok:
            failures.append((result.exit_code, args, lines[-1] if lines else repr(result.exception)))
        else:
            counts[command][result.exit_code // 2] += 1
        shutil.rmtree(work, ignore_errors=True)
    print(f"fuzz seed {seed}: {k} cases in {time.monotonic() - start:.0f} s; "
          f"(exit 0, exit 2) per command: {counts}")
    assert not failures, f"seed {seed}: " + "\n".join(map(str, failures[:10]))
