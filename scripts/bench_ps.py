#!/usr/bin/env python
"""Benchmark `msleak grid` + `transform` + `ps` at the paper's scale, and compare with ps_eor.

1. Visibility path: a 13 h NCP Measurement Set of the 48 LOFAR HBA core fields (1128
   baselines, 390 slots of 120 s, 50 channels, 4 correlations) made by `msleak simulate`,
   DATA filled (in row chunks) with three point sources plus Gaussian noise. Each stage
   runs as its own process; wall time and peak resident memory (ru_maxrss of that
   process) are reported. Targets: grid + transform + ps < 60 s, peak < 2 GB.
2. Image path vs ps_eor (PyPI ``ps-eor``, if importable): one K image cube (128^2 pixels of
   2 arcmin, 50 channels, a smooth-spectrum Gaussian random sky) through
   `msleak grid --image` + `transform` + `ps`, and through ps_eor's CartImageCube ->
   CartDataCube -> PowerSpectraCart.get_ps2d with the same uv range, |b| annuli, delay
   grid, (symmetric) window and cosmology (Planck18, no primary beam), ps_eor's power
   converted from its (N-1) dnu bandwidth to msleak's N dnu (docs/ps.md "Comparison with
   ps_eor"). Reported: both times, the k_perp and k_par axes (ps_eor's h Mpc^-1 converted
   to Mpc^-1) and the ratio of the 2D powers.

Usage: scripts/bench_ps.py [--workdir DIR | --outdir DIR] [--quick] [--json OUT.json]
                           [--skip-ms] [--skip-image]

The results are printed last as one JSON line (``scripts/bench`` reads it); ``--outdir DIR``
works in DIR/ps and writes DIR/bench_ps.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _vm_hwm_kb(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def run_stage(args: list[str]) -> dict:
    """Run a command; return its wall time (s) and peak RSS (MB).

    The peak is the process's VmHWM polled from /proc every 20 ms (ru_maxrss would
    include the memory of this parent process at fork time).
    """
    t0 = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, _vm_hwm_kb(proc.pid))
        time.sleep(0.02)
    out = proc.stdout.read().decode()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"failed: {' '.join(args)}\n{out}")
    return {"wall_s": round(wall, 2), "peak_mb": round(peak / 1024, 1)}


def msleak_cmd(*args) -> list[str]:
    return [sys.executable, "-m", "msleak", "-q", *map(str, args)]


def fill_data(ms: Path, seed: int = 1, chunk: int = 50_000) -> None:
    """DATA = three point sources (I, Q, U) + noise, written in row chunks."""
    import casacore.tables as pt

    from msleak.conventions import stokes_to_correlations

    rng = np.random.default_rng(seed)
    with pt.table(str(ms / "SPECTRAL_WINDOW"), ack=False) as t:
        freq = t.getcell("CHAN_FREQ", 0)
    sources = [  # l, m (rad), I, Q, U, V, spectral phase rate of Q/U (rad per channel)
        (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0),
        (0.01, -0.015, 0.5, 0.1, 0.05, 0.0, 0.4),
        (-0.02, 0.01, 0.3, 0.05, -0.08, 0.0, 1.1),
    ]
    with pt.table(str(ms), readonly=False, ack=False) as t:
        for start in range(0, t.nrows(), chunk):
            n = min(chunk, t.nrows() - start)
            uvw = t.getcol("UVW", start, n)
            data = np.zeros((n, freq.size, 4), np.complex128)
            for l, m, i, q, u, v, rate in sources:
                nn = np.sqrt(1 - l * l - m * m) - 1
                phase = np.exp(-2j * np.pi * (uvw[:, :1] * l + uvw[:, 1:2] * m + uvw[:, 2:] * nn)
                               * freq[None, :] / 299792458.0)
                rot = np.exp(1j * rate * np.arange(freq.size))
                p = (q + 1j * u) * rot
                iquv = np.stack(np.broadcast_arrays(i, p.real, p.imag, v), -1)  # (chan, 4)
                data += phase[..., None] * stokes_to_correlations(iquv)[None]
            data += 0.5 * (rng.standard_normal(data.shape) + 1j * rng.standard_normal(data.shape))
            t.putcol("DATA", data.astype(np.complex64), start, n)


def bench_ms(work: Path, quick: bool) -> dict:
    ms = work / ("bench_quick.ms" if quick else "bench_paper.ms")
    result: dict = {}
    if not (ms / "table.dat").exists():
        t0 = time.perf_counter()
        sim = ["simulate", ms, "--field", "ncp", "--overwrite"]
        if quick:
            sim += ["--duration", "1", "--stations", "CS00[1-7]HBA*", "--nchan", "20"]
        subprocess.run(msleak_cmd(*sim), check=True, stdout=subprocess.DEVNULL)
        fill_data(ms)
        result["build_s"] = round(time.perf_counter() - t0, 1)
    import casacore.tables as pt

    with pt.table(str(ms), ack=False) as t:
        result["rows"] = t.nrows()
        result["shape"] = list(t.getcell("DATA", 0).shape)
    stages = {
        "grid": msleak_cmd("grid", ms, "-o", work / "grid.h5", "--threads", "2",
                           "--overwrite"),
        "transform": msleak_cmd("transform", work / "grid.h5", "-o", work / "delay.h5",
                                "--overwrite"),
        "ps": msleak_cmd("ps", work / "delay.h5", "-o", work / "ps.h5",
                         "--plot", work / "ps.png", "--overwrite"),
    }
    for name, cmd in stages.items():
        result[name] = run_stage(cmd)
        print(f"  {name:10s} {result[name]['wall_s']:7.2f} s  peak {result[name]['peak_mb']:7.1f} MB",
              flush=True)
    result["total_s"] = round(sum(result[s]["wall_s"] for s in stages), 2)
    result["max_peak_mb"] = max(result[s]["peak_mb"] for s in stages)
    return result


def make_image_cube(path: Path, n: int = 128, pix_arcmin: float = 2.0, nchan: int = 50,
                    seed: int = 3) -> None:
    """A K cube: power-law Gaussian random field, smooth spectrum plus a fluctuating part."""
    from astropy.io import fits

    rng = np.random.default_rng(seed)
    k = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n)))
    k[0, 0] = 1
    base = np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) * k ** -1.2).real
    fluct = np.fft.ifft2(np.fft.fft2(rng.standard_normal((nchan, n, n)), axes=(1, 2))
                         * k ** -1.0, axes=(1, 2)).real
    freq = 150e6 + 195312.5 * np.arange(nchan)
    cube = base[None] * (freq[:, None, None] / 150e6) ** -2.55 + 0.05 * fluct
    cube *= 1.0 / cube.std()  # ~1 K rms
    hdr = fits.Header()
    d = pix_arcmin / 60
    for i, (ct, crval, cdelt) in enumerate((("RA---SIN", 0.0, -d), ("DEC--SIN", 90.0, d)), 1):
        hdr[f"CTYPE{i}"], hdr[f"CRPIX{i}"], hdr[f"CRVAL{i}"], hdr[f"CDELT{i}"] = ct, n / 2 + 1, crval, cdelt
    hdr["CTYPE3"], hdr["CRPIX3"], hdr["CRVAL3"], hdr["CDELT3"] = "FREQ", 1, freq[0], 195312.5
    hdr["BUNIT"] = "K"
    fits.PrimaryHDU(cube.astype(np.float64), header=hdr).writeto(path, overwrite=True)


def bench_image(work: Path, uv=(30.0, 180.0)) -> dict:
    import xarray as xr

    cube_path = work / "image_cube.fits"
    make_image_cube(cube_path)
    out: dict = {}
    t0 = time.perf_counter()
    run_stage(msleak_cmd("grid", "--image", cube_path, "--uv-range", f"{uv[0]},{uv[1]}",
                         "-o", work / "img_grid.h5", "--overwrite"))
    run_stage(msleak_cmd("transform", work / "img_grid.h5", "-o", work / "img_delay.h5",
                         "--window", "blackman-harris", "--partial", "zero", "--overwrite"))
    cell = float(xr.open_dataset(work / "img_grid.h5", engine="h5netcdf").attrs["cell_lambda"])
    run_stage(msleak_cmd("ps", work / "img_delay.h5", "-o", work / "img_ps.h5",
                         "--bin-width", cell, "--overwrite"))
    out["msleak_s"] = round(time.perf_counter() - t0, 2)
    ours = xr.open_dataset(work / "img_ps.h5", engine="h5netcdf").load()
    try:
        import ps_eor  # noqa: F401
    except ImportError:
        out["ps_eor"] = "not installed (pip install ps-eor)"
        return out
    cell = ours.attrs["cell_lambda"]
    t0 = time.perf_counter()
    theirs = _ps_eor_ps2d(cube_path, uv, cell, ours["k_perp"].size)
    out["ps_eor_s"] = round(time.perf_counter() - t0, 2)
    from astropy.cosmology import Planck18

    h = Planck18.h
    kper_e = np.asarray(theirs["k_per"]) * h
    kpar_e = np.asarray(theirs["k_par"]) * h
    # both are now bin centres of the same annuli and the same FFT delays
    kper_m, kpar_m = ours["k_perp"].values, ours["k_par"].values[1:]  # ps_eor has no k_par=0
    out["k_perp_msleak"] = np.round(kper_m, 5).tolist()
    out["k_perp_ps_eor"] = np.round(kper_e, 5).tolist()
    out["k_par_msleak_first"] = np.round(kpar_m[:4], 5).tolist()
    out["k_par_ps_eor_first"] = np.round(kpar_e[:4], 5).tolist()
    n = min(kper_m.size, kper_e.size)
    out["k_perp_max_rel_diff"] = float(np.max(np.abs(kper_m[:n] / kper_e[:n] - 1)))
    m = min(kpar_m.size, kpar_e.size)  # ps_eor drops the Nyquist delay when folding
    nz = slice(0, m)
    out["k_par_max_rel_diff"] = float(np.max(np.abs(kpar_m[nz] / kpar_e[nz] - 1)))
    nchan = theirs["nchan"]
    p_ours = ours["power"].sel(stokes="I").values[1:m + 1, :n]  # mK^2 Mpc^3
    # K^2 h^-3 Mpc^3 -> mK^2 Mpc^3, and ps_eor's bandwidth (N - 1) dnu -> msleak's N dnu
    p_theirs = np.asarray(theirs["ps2d"])[:m, :n] * 1e6 / h ** 3 * (nchan - 1) / nchan
    out["ps_eor_bandwidth_factor_applied"] = (nchan - 1) / nchan
    ratio = p_ours / p_theirs
    ok = np.isfinite(ratio) & (ratio > 0)
    out["power_ratio_median"] = float(np.median(ratio[ok]))
    out["power_ratio_p16_p84"] = [float(np.percentile(ratio[ok], 16)),
                                  float(np.percentile(ratio[ok], 84))]
    out["power_ratio_min_max"] = [float(ratio[ok].min()), float(ratio[ok].max())]
    out["power_ratio_low_kpar_median"] = float(np.median(ratio[:5][ok[:5]]))
    out["power_ratio_per_kperp"] = np.round(np.nanmedian(np.where(ok, ratio, np.nan), axis=0),
                                            3).tolist()
    out["power_ratio_per_kpar"] = np.round(np.nanmedian(np.where(ok, ratio, np.nan), axis=1),
                                           3).tolist()
    return out


def _ps_eor_ps2d(cube_path: Path, uv, du, nbin: int) -> dict:
    """ps_eor's cylindrical PS of the same cube (K), put on msleak's conventions.

    Same uv cells, cosmology and spectral window, and three settings that make the two
    estimators compute the same voxels (docs/ps.md "Comparison with ps_eor"):

    * k_perp bins: ps_eor's default bins are *centred* on its ``el`` values (edges at the
      midpoints), so ``el = 2 pi * arange(umin, umax, du)`` is half a bin below msleak's
      ``[umin + i du, umin + (i + 1) du]``; here ``uniform_u_bins`` with ``el`` at msleak's
      bin centres gives the same annuli.
    * delay grid: ps_eor uses ``M = round((nu_last - nu_first) / dnu) = N - 1`` delay modes
      (a 2 % different k_par axis); here ``M = N``, msleak's FFT delays.
    * window: ps_eor takes scipy's periodic window (``fftbins=True``), msleak the
      symmetric one; here ps_eor gets the symmetric Blackman-Harris too.

    The remaining difference, ps_eor's bandwidth ``(N - 1) dnu`` against msleak's
    ``N dnu`` in the normalisation, is left in the returned power (the caller converts).
    """
    from astropy.cosmology import Planck18
    from astropy.io import fits
    from astropy.wcs import WCS
    from ps_eor import datacube, pspec, psutil
    from scipy.signal import get_window

    class _SymmetricWindowPS(pspec.PowerSpectraCart):
        def get_window_fct(self, data_cube):
            return get_window(self.config.window_fct, len(data_cube.freqs), fftbins=False)[:, None]

    psutil.set_cosmology(Planck18)
    with fits.open(cube_path) as hdul:
        data = hdul[0].data.astype(float)
        wcs = WCS(hdul[0].header)
        freqs = hdul[0].header["CRVAL3"] + hdul[0].header["CDELT3"] * np.arange(data.shape[0])
    meta = datacube.ImageMetaData(wcs, data.shape[1:])
    img = datacube.CartImageCube(data, freqs, meta)
    cube = img.ft(uv[0], uv[1])
    config = pspec.PowerSpectraConfig(window_fct="blackmanharris")
    config.set("umin", uv[0])
    config.set("umax", uv[1])
    config.set("du", du)
    config.set("primary_beam", "no_pb")
    config.set("weights_by_default", False)
    config.set("uniform_u_bins", True)
    config.el = 2 * np.pi * (uv[0] + du * (np.arange(nbin) + 0.5))
    eor = pspec.EorBin(0, freqs, freqs, M=freqs.size)
    gen = _SymmetricWindowPS(eor, config, datacube.PrimaryBeam.from_name("no_pb"))
    ps2d = gen.get_ps2d(cube)
    return {"k_per": ps2d.k_per, "k_par": ps2d.k_par, "ps2d": ps2d.data, "nchan": freqs.size}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", default=os.environ.get("MSLEAK_BENCH_DIR", "/tmp/msleak-bench-ps"))
    ap.add_argument("--quick", action="store_true", help="small MS (for a smoke test)")
    ap.add_argument("--json", default=None, help="also write the results as JSON")
    ap.add_argument("--skip-ms", action="store_true")
    ap.add_argument("--skip-image", action="store_true")
    ap.add_argument("--outdir", default=None, help="work in DIR/ps, write DIR/bench_ps.json")
    args = ap.parse_args()
    if args.outdir:
        args.workdir = str(Path(args.outdir) / "ps")
        args.json = args.json or str(Path(args.outdir) / "bench_ps.json")
    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    if not args.skip_ms:
        print("msleak grid + transform + ps on the paper-size MS:", flush=True)
        results["ms"] = bench_ms(work, args.quick)
        r = results["ms"]
        verdict = "OK" if r["total_s"] < 60 and r["max_peak_mb"] < 2048 else "MISSED"
        print(f"  total {r['total_s']} s (target < 60), peak {r['max_peak_mb']} MB "
              f"(target < 2048): {verdict}")
    if not args.skip_image:
        print("image cube: msleak vs ps_eor:", flush=True)
        results["image"] = bench_image(work)
        for k, v in results["image"].items():
            print(f"  {k}: {v}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    print(json.dumps(results))


if __name__ == "__main__":
    main()
