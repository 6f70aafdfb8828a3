"""Stage ``allsky`` of scripts/bench: ``msleak predict`` of all-sky HEALPix skies, each run
one whole process under /usr/bin/time -v, and msleak against matvis on the same input.

Usage: scripts/bench_allsky.py --outdir DIR [--quick]  (prints one JSON object last)

(a) ``msleak predict MS --sky ALL.skyh5`` (defaults: complex64, the phase-centre
    correction, ``--scheduler threads``) of Q/U skies from ``msleak sky --healpix NSIDE``
    on the channels of the MS: the 48 LOFAR HBA core fields (NCP) at NSIDE 128 and 256,
    and the 48 innermost HERA dishes (EoR0, ``--beam uvbeam``) at NSIDE 128; 1 h of 120 s
    slots, 50 channels.
(b) The same HERA MS and beam file and a Stokes I sky at NSIDE 64 (random 1-3 K per pixel
    and channel, written as SkyH5): ``msleak predict --beam uvbeam --no-centre-correction``
    against :func:`matvis_run` in its own process (reads the MS and the SkyH5 file with
    casacore and pyradiosky, runs matvis on the CPU, writes a column), each at its default
    precision (complex64; matvis ``precision=1``).
(c) The relative rms of msleak's column against matvis's,
    sqrt(sum |msleak - matvis|^2 / sum |matvis|^2), over all correlations and for Stokes I
    (XX + YY): all-sky predict is the direct sum, so the peer is the check.

matvis's side maps its conventions onto msleak's as tests/peers/test_peer_healpix_matvis.py
does (docs/conventions.md, "Peer simulators"): the beam file divided at each file frequency
by its complex zenith value (what msleak does, docs/hera.md), msleak = 2 x matvis, matvis's
pair (p, q) on the MS row p-q, its feed ``y`` (North-South) msleak's X, its drift-scan
fringes phased to the MS phase centre. matvis keeps the sources above its horizon; msleak
the pixels above the horizon at each time.

--quick: NSIDE 16 and 32 (LOFAR), 16 (HERA) and 16 (against matvis), 8 stations, 4 slots,
8 channels: it checks that the stage runs and says little about the full scale. numba's
cache is warmed first, untimed, on the smallest sky.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

#: per size: LOFAR skies (NSIDE), HERA sky, the sky against matvis, stations, slots, channels
SIZES = {"full": {"lofar": (128, 256), "hera": (128,), "matvis": 64, "stations": 48,
                  "slots": 30, "nchan": 50},
         "quick": {"lofar": (16, 32), "hera": (16,), "matvis": 16, "stations": 8,
                   "slots": 4, "nchan": 8}}
INTERVAL_S = 120.0
#: the project's targets, reported against (nothing is tuned toward them)
GOALS = {"nside128_wall_s": 15 * 60.0, "nside128_peak_mib": 8 * 1024.0,
         "nside256_wall_s": 3600.0, "matvis_over_msleak_wall": 1.0}
COLUMN_MSLEAK, COLUMN_MATVIS = "BENCH_ALLSKY_MSLEAK", "BENCH_ALLSKY_MATVIS"


def simulate_ms(msleak: list, path: Path, telescope: str, size: dict) -> Path:
    """A fresh MS: the ``stations`` innermost of the telescope, ``slots`` x 120 s, ``nchan``
    channels (the telescope's own first frequency and 195.3125 kHz channels)."""
    from msleak.telescope.observation import telescope_layout

    names = telescope_layout(telescope).innermost(size["stations"]).names
    field = ["--field", "ncp"] if telescope == "lofar" else []
    subprocess.run([*msleak, "simulate", path, "--telescope", telescope, *field,
                    "--duration", repr(size["slots"] * INTERVAL_S / 3600), "--interval",
                    str(INTERVAL_S), "--nchan", str(size["nchan"]), "--stations",
                    ",".join(names), "--overwrite"], check=True, stdout=subprocess.DEVNULL)
    return path


def channel_freqs(ms: Path) -> np.ndarray:
    import casacore.tables as pt

    with pt.table(str(ms / "SPECTRAL_WINDOW"), ack=False) as t:
        return np.asarray(t.getcell("CHAN_FREQ", 0), dtype=float)


def stokes_i_sky(path: Path, nside: int, freqs: np.ndarray, seed: int = 64) -> Path:
    """A SkyH5 file of Stokes I on every pixel (RING, ICRS): uniform 1-3 K per pixel and
    channel, Q = U = V = 0."""
    from msleak.adapters.skyh5 import write_skyh5
    from msleak.sky.healpix import HealpixSky

    npix = 12 * nside**2
    stokes = np.zeros((4, freqs.size, npix))
    stokes[0] = np.random.default_rng(seed).uniform(1.0, 3.0, (freqs.size, npix))
    sky = HealpixSky(nside=nside, order="ring", pixels=np.arange(npix), freq_hz=freqs,
                     stokes=stokes)
    return write_skyh5(path, sky, history="scripts/bench_allsky.py Stokes I", overwrite=True)


def _zenith_normalised(beam):
    """The beam file divided at each file frequency by the complex value of its zenith
    component largest at the first frequency, keeping that frequency's phase (msleak's
    normalisation, docs/hera.md), so matvis interpolates the same beam between frequencies."""
    zenith = int(np.argmin(np.abs(np.asarray(beam.axis2_array, dtype=float))))
    at = beam.data_array[:, :, :, zenith, :]                    # (basis, feed, freq, az)
    b, f, a = np.unravel_index(np.argmax(np.abs(at[:, :, 0, :])), at[:, :, 0].shape)
    ref = at[b, f, :, a]
    out = beam.copy()
    out.data_array = beam.data_array / (np.abs(ref) * np.exp(1j * np.angle(ref / ref[0])))[
        None, None, :, None, None]
    return out


def matvis_run(ms: Path, sky: Path, column: str, beam_file: Path | None = None) -> None:
    """matvis on the CPU: every source of the SkyH5 ``sky`` (pixel centres, flux in Jy)
    through the UVBeam file (default msleak's, pyuvsim's HERA beam) for the antennas,
    times and channels of ``ms``; the visibilities, mapped to msleak's conventions, are
    written into ``column`` of ``ms`` (complex64, created if missing)."""
    import warnings

    import astropy.units as u
    import casacore.tables as pt
    from astropy.coordinates import AltAz, EarthLocation, SkyCoord
    from astropy.time import Time
    from matvis import simulate_vis
    from pyradiosky import SkyModel
    from pyuvdata import UVBeam
    from pyuvdata.utils import ENU_from_ECEF

    if beam_file is None:
        from msleak.io.uvbeam import default_beam_file

        beam_file = default_beam_file()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="The mount_type parameter must be set")
        beam = _zenith_normalised(UVBeam.from_file(str(beam_file)))
    with pt.table(str(ms / "ANTENNA"), ack=False) as t:
        positions = t.getcol("POSITION")
    with pt.table(str(ms / "FIELD"), ack=False) as t:
        ra0, dec0 = t.getcell("PHASE_DIR", 0).reshape(-1)[:2]
    freqs = channel_freqs(ms)
    with pt.table(str(ms), ack=False) as t:
        times = np.unique(t.getcol("TIME"))
    location = EarthLocation.from_geocentric(*positions.mean(axis=0), unit=u.m)
    enu = ENU_from_ECEF(positions, center_loc=location)
    model = SkyModel.from_file(str(sky))
    model.healpix_to_point(to_jy=True)
    model.at_frequencies(freqs * u.Hz)
    flux = np.asarray(model.stokes[0].to_value(u.Jy)).T          # (nsrc, nchan)
    obstime = Time(times / 86400.0, format="mjd", scale="utc")
    nant, ntime, nchan = len(enu), len(times), len(freqs)
    vis = simulate_vis(ants={i: enu[i] for i in range(nant)}, fluxes=flux,
                       ra=model.skycoord.icrs.ra.rad, dec=model.skycoord.icrs.dec.rad,
                       freqs=freqs, times=obstime, beams=[beam], telescope_loc=location,
                       polarized=True, precision=1)
    vis = vis.reshape(nchan, ntime, nant, nant, 2, 2)
    # phase centre s0 per time: drift-scan fringes exp(+2 pi i (x_q - x_p).s / lambda) times
    # exp(-2 pi i (x_q - x_p).s0 / lambda)
    altaz = SkyCoord(ra=ra0 * u.rad, dec=dec0 * u.rad, frame="fk5").transform_to(
        AltAz(obstime=obstime, location=location))
    alt, az = altaz.alt.rad, altaz.az.rad
    s0 = np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], -1)
    delay = s0 @ enu.T                                           # (ntime, nant) m
    ns = int(np.flatnonzero(np.asarray(beam.feed_array) == "y")[0])
    feeds = {"XX": (ns, ns), "XY": (ns, 1 - ns), "YX": (1 - ns, ns), "YY": (1 - ns, 1 - ns)}
    lam = 299792458.0 / freqs
    with pt.table(str(ms / "POLARIZATION"), ack=False) as t:
        corr = [{9: "XX", 10: "XY", 11: "YX", 12: "YY"}[int(c)] for c in t.getcell("CORR_TYPE", 0)]
    with pt.table(str(ms), readonly=False, ack=False) as t:
        if column not in t.colnames():
            desc = t.getcoldesc("DATA")
            desc["valueType"] = "complex"
            t.addcols(pt.maketabdesc(pt.makecoldesc(column, desc)))
        for start in range(0, t.nrows(), 50_000):
            n = min(50_000, t.nrows() - start)
            it = np.searchsorted(times, t.getcol("TIME", start, n))
            p, q = t.getcol("ANTENNA1", start, n), t.getcol("ANTENNA2", start, n)
            phase = np.exp(-2j * np.pi * (delay[it, q] - delay[it, p])[:, None] / lam)
            out = np.empty((n, nchan, len(corr)), np.complex64)
            for k, name in enumerate(corr):
                a, b = feeds[name]
                out[..., k] = 2 * vis[:, it, p, q, a, b].T * phase   # msleak = 2 x matvis
            t.putcol(column, out, start, n)


def _run(timed, name: str, cmd: list, out: Path, runs: dict, **extra) -> dict:
    print(f"bench_allsky: {name} ...", file=sys.stderr, flush=True)
    r = timed(cmd, out)
    r.pop("stdout", None)
    # short commands: the driver keeps only the last 4000 characters of this script's output
    r["command"] = r["command"].replace(f"{out}/", "").replace(sys.executable, "python")
    r["stderr"] = r["stderr"][-300:]
    r.update(extra)
    runs[name] = r
    print(f"bench_allsky: {name}: {r['wall_s']:.1f} s, CPU {r['cpu_s']} s, peak "
          f"{r['peak_rss_mib']} MiB" + (f", FAILED exit {r['exit']}: {r['stderr'][-300:]}"
                                        if r["exit"] else ""), file=sys.stderr, flush=True)
    return r


def _ratio(a, b):
    return round(a / b, 3) if a and b else None


def bench(out: Path, quick: bool, lofar: tuple | None = None) -> dict:
    from bench import timed
    from bench_degrid import rel_rms

    size = dict(SIZES["quick" if quick else "full"])
    if lofar:                       # fewer LOFAR skies than the size's (e.g. without 256)
        size["lofar"] = tuple(lofar)
    msleak = [sys.executable, "-m", "msleak", "-q"]
    work = out / "allsky"
    work.mkdir(parents=True, exist_ok=True)
    ms = {tel: simulate_ms(msleak, work / f"{tel}.ms", tel, size) for tel in ("lofar", "hera")}
    skies, runs = {}, {}
    for tel, nsides in (("lofar", size["lofar"]), ("hera", size["hera"])):
        f0 = float(channel_freqs(ms[tel])[0])
        for nside in nsides:
            skies[tel, nside] = work / f"qu_{tel}_{nside}.skyh5"
            _run(timed, f"sky_{tel}_nside{nside}",
                 [*msleak, "sky", skies[tel, nside], "--healpix", str(nside), "--seed", "1",
                  "--freq-min", repr(f0), "--nchan", str(size["nchan"]), "--overwrite"],
                 work, runs)
    sky_i = stokes_i_sky(work / f"stokes_i_{size['matvis']}.skyh5", size["matvis"],
                         channel_freqs(ms["hera"]))
    beams = {"lofar": [], "hera": ["--beam", "uvbeam"]}
    common = ["--no-progress", "--restart"]
    # numba's cache warmed, untimed, through both beams and both centre corrections, on an
    # NSIDE 8 sky and two stations (all the slots: pixels rise and set within a block)
    warm = {**size, "stations": 2}
    for tel in ("lofar", "hera"):
        warm_ms = simulate_ms(msleak, work / f"warm_{tel}.ms", tel, warm)
        warm_sky = work / f"warm_{tel}.skyh5"
        subprocess.run([*msleak, "sky", warm_sky, "--healpix", "8", "--seed", "1",
                        "--freq-min", repr(float(channel_freqs(warm_ms)[0])), "--nchan",
                        str(size["nchan"]), "--overwrite"], check=True,
                       stdout=subprocess.DEVNULL)
        for extra in ([], ["--no-centre-correction"]):
            subprocess.run([*msleak, "predict", warm_ms, "--sky", warm_sky, *beams[tel],
                            *extra, *common], check=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
        shutil.rmtree(warm_ms, ignore_errors=True)
    load_start = os.getloadavg()[0]
    for tel in ("lofar", "hera"):
        for nside in size[tel]:
            _run(timed, f"predict_{tel}_nside{nside}",
                 [*msleak, "predict", ms[tel], "--sky", skies[tel, nside], "--column",
                  f"BENCH_ALLSKY_{nside}", *beams[tel], *common], work, runs,
                 telescope=tel, nside=nside, pixels=12 * nside**2)
    nside = size["matvis"]
    m = _run(timed, f"msleak_vs_matvis_nside{nside}",
             [*msleak, "predict", ms["hera"], "--sky", sky_i, "--column", COLUMN_MSLEAK,
              "--beam", "uvbeam", "--no-centre-correction", *common], work, runs,
             nside=nside, pixels=12 * nside**2)
    v = _run(timed, f"matvis_nside{nside}",
             [sys.executable, Path(__file__).resolve(), "--matvis", ms["hera"], sky_i,
              COLUMN_MATVIS], work, runs, nside=nside, pixels=12 * nside**2)
    f = {"quick": quick, "stations": size["stations"], "slots": size["slots"],
         "interval_s": INTERVAL_S, "channels": size["nchan"],
         "load_avg_start_end": [round(load_start, 2), round(os.getloadavg()[0], 2)]}
    if not (m["exit"] or v["exit"]):
        f["matvis_over_msleak_wall"] = _ratio(v["wall_s"], m["wall_s"])
        f["matvis_over_msleak_cpu"] = _ratio(v["cpu_s"], m["cpu_s"])
        f["msleak_vs_matvis"] = rel_rms(ms["hera"], COLUMN_MSLEAK, COLUMN_MATVIS)
    if len(size["lofar"]) > 1:
        lo, hi = (runs.get(f"predict_lofar_nside{n}", {}) for n in size["lofar"][:2])
        f["lofar_wall_ratio"] = _ratio(hi.get("wall_s"), lo.get("wall_s"))
        f["lofar_cpu_ratio"] = _ratio(hi.get("cpu_s"), lo.get("cpu_s"))
    # the targets are set for the full sizes: a --quick run is not checked against them
    f["goals"] = {} if quick else goals(runs, size, f)
    return {"runs": runs, "figures": f}


def goals(runs: dict, size: dict, f: dict) -> dict:
    """Each target with its measured value and whether it is met (None: not measured)."""
    n_mid, n_big = (*size["lofar"], None)[:2]
    out = {}

    def check(key, what, value, goal_text, limit, above=False):
        ok = None if value is None else bool(value >= limit if above else value < limit)
        out[key] = {"what": what, "value": value, "goal": goal_text, "pass": ok}

    for tel, nside in (("lofar", n_mid), ("hera", size["hera"][0])):
        r = runs.get(f"predict_{tel}_nside{nside}", {})
        ok = r and not r["exit"]
        check(f"{tel}_wall", f"{tel} NSIDE {nside} wall (s)", r["wall_s"] if ok else None,
              "< 900 s", GOALS["nside128_wall_s"])
        check(f"{tel}_peak", f"{tel} NSIDE {nside} peak memory (MiB)",
              r["peak_rss_mib"] if ok else None, "< 8 GiB", GOALS["nside128_peak_mib"])
    r = runs.get(f"predict_lofar_nside{n_big}", {})   # {} when not run: not measured
    check("lofar_big_wall", f"lofar NSIDE {n_big} wall (s)",
          r["wall_s"] if r and not r["exit"] else None, "< 3600 s", GOALS["nside256_wall_s"])
    check("vs_matvis", f"matvis wall / msleak wall, NSIDE {size['matvis']}",
          f.get("matvis_over_msleak_wall"), ">= 1", GOALS["matvis_over_msleak_wall"],
          above=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--outdir", default="bench-output")
    ap.add_argument("--quick", action="store_true", help="small inputs (a couple of minutes)")
    ap.add_argument("--lofar", default=None, metavar="NSIDE[,NSIDE]",
                    help="the LOFAR skies' NSIDEs instead of the size's (e.g. 128 alone)")
    ap.add_argument("--matvis", nargs=3, metavar=("MS", "SKYH5", "COLUMN"),
                    help="run only the matvis driver (the process the bench times)")
    args = ap.parse_args()
    if args.matvis:
        matvis_run(Path(args.matvis[0]), Path(args.matvis[1]), args.matvis[2])
        return 0
    out = Path(args.outdir).resolve()
    result = bench(out, args.quick, tuple(int(n) for n in args.lofar.split(","))
                   if args.lofar else None)
    text = json.dumps(result, default=str, separators=(",", ":"))
    (out / "allsky" / "result.json").write_text(text + "\n")
    print(text)
    failed = [k for k, r in result["runs"].items() if r["exit"]]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
