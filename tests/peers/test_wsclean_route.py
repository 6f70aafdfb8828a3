"""The WSClean image route against the visibility route (docs/grid.md, "The image route
and the visibility route").

A tiny LOFAR MS (7 core stations, 14 antennas, 8 x 120 s, 8 channels) holds two columns
predicted without a beam: MODEL_C, a polarized source at the phase centre with a
power-law I spectrum and Faraday rotation, and MODEL_OFF, the same source off centre.
WSClean images them per channel in I, Q, U with natural weighting and no cleaning, on 64
pixels of 1/1024 rad (cells of 16 wavelengths, msleak's default). The tests check
WSClean's images against the direct Fourier sum of the MS's visibilities (convention and
accuracy), the uv cubes ``msleak grid --image`` makes of them against the transform of
that sum (units, stacking, FFT), and the power spectrum of the image route against the
visibility route's.
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from ms_helpers import C, channel_freqs, lm_to_radec
from peers import require_executable

NPIX = 64
PIXEL_DEG = math.degrees(1.0 / 1024)   # 64 pixels of 1/1024 rad: cells of 16 wavelengths
NCHAN = 8
RA0, DEC0 = 123.4, 48.2                # the 3c196 preset's phase centre, deg
I0, Q0, U0, ALPHA, RM = 2.0, 0.6, -0.4, -0.7, 40.0   # Jy at NU0; rad m^-2
NU0 = 150e6
OFF_LM = (math.radians(0.5), math.radians(0.3))      # MODEL_OFF's source (l East, m North)
# WSClean's default -wgridder-accuracy: ducc0's wgridder accuracy, the L2 norm of an
# image's error relative to the L2 norm of the image (ducc0.misc.l2error)
WGRIDDER_ACCURACY = 1e-4


def _skymodel(path: Path, ra_deg: float, dec_deg: float) -> Path:
    path.write_text("format = Name, Type, Ra, Dec, I, Q, U, V, ReferenceFrequency, "
                    "SpectralIndex='[]', RotationMeasure\n"
                    f"s0, POINT, {ra_deg!r}deg, {dec_deg!r}deg, {I0}, {Q0}, {U0}, 0, "
                    f"{NU0}, [{ALPHA}], {RM}\n")
    return path


def _msleak(*args) -> None:
    subprocess.run(["msleak", "-q", *map(str, args)], check=True)


def _wsclean(ms: Path, column: str, name: Path, work: Path) -> None:
    """The documented command: per-channel I, Q, U dirty images and PSFs, natural weights.
    WSClean runs in, and keeps its temporary files in, ``work``."""
    done = subprocess.run(["wsclean", "-quiet", "-j", "1", "-name", str(name),
                           "-temp-dir", str(work),
                           "-size", str(NPIX), str(NPIX), "-scale", repr(PIXEL_DEG),
                           "-pol", "IQU", "-channels-out", str(NCHAN), "-data-column", column,
                           "-weight", "natural", "-niter", "0", "-make-psf",
                           "-use-wgridder", "-no-small-inversion", str(ms)],
                          cwd=work, capture_output=True, text=True)
    if done.returncode != 0:
        pytest.fail(f"wsclean exited with status {done.returncode} on {column}:\n"
                    f"{done.stderr}{done.stdout}", pytrace=False)


@pytest.fixture(scope="module")
def route(tmp_path_factory) -> dict:
    """The MS, its WSClean images and the uv cubes of both routes."""
    import msleak

    require_executable("wsclean", "wsclean is not installed (apt-get install wsclean)")
    d = tmp_path_factory.mktemp("wsclean")
    ms = msleak.simulate(d / "obs.ms", field="3c196", duration=8 * 120 / 3600,
                         interval=120.0, nchan=NCHAN, stations="CS00[1-7]HBA*")
    off = lm_to_radec(math.radians(RA0), math.radians(DEC0), *OFF_LM)
    msleak.predict(ms, [_skymodel(d / "c.skymodel", RA0, DEC0),
                        _skymodel(d / "off.skymodel", *(math.degrees(x) for x in off))],
                   column=["MODEL_C", "MODEL_OFF"], beam="none")
    img = d / "img"
    img.mkdir()
    work = d / "wsclean-tmp"
    work.mkdir()
    _wsclean(ms, "MODEL_C", img / "c", work)
    _wsclean(ms, "MODEL_OFF", img / "off", work)
    fov = repr(NPIX * PIXEL_DEG)
    # the glob also matches WSClean's MFS images of the whole band: they are left out
    _msleak("grid", "--image", img / "c-*-[IQU]-image.fits", "--fov", fov,
            "-o", d / "grid_image.h5")
    _msleak("grid", ms, "--column", "MODEL_C", "-o", d / "grid_vis.h5")
    return {"ms": ms, "img": img,
            "image": xr.load_dataset(d / "grid_image.h5", engine="h5netcdf"),
            "vis": xr.load_dataset(d / "grid_vis.h5", engine="h5netcdf"),
            "psf": msleak.grid(image=str(img / "c-*-psf.fits"), fov=float(fov)),
            "off": msleak.grid(image=str(img / "off-*-[IQU]-image.fits"), fov=float(fov))}


def _ms_samples(ms: Path, column: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """UVW (row, 3) m, weights (row, chan), Stokes I, Q, U (3, row, chan), freq (chan,) Hz."""
    import casacore.tables as pt

    with pt.table(str(ms), ack=False) as t:
        uvw, weight = t.getcol("UVW"), t.getcol("WEIGHT_SPECTRUM")[..., 0]
        xx, xy, yx, yy = np.moveaxis(t.getcol(column), -1, 0)
    return (uvw, weight, np.stack([(xx + yy) / 2, (xx - yy) / 2, (xy + yx) / 2]),
            channel_freqs(ms))


def _pixel_lmn(header) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(l, m, n - 1) of every pixel (y, x) of a RA---SIN/DEC--SIN image.

    The SIN projection's intermediate coordinates are l (East) and m (North) themselves:
    l = CDELT1 (x + 1 - CRPIX1), m = CDELT2 (y + 1 - CRPIX2), in radians.
    """
    lx = (np.arange(NPIX) + 1 - header["CRPIX1"]) * math.radians(header["CDELT1"])
    my = (np.arange(NPIX) + 1 - header["CRPIX2"]) * math.radians(header["CDELT2"])
    m, l = np.meshgrid(my, lx, indexing="ij")
    return l, m, np.sqrt(1 - l * l - m * m) - 1


def _direct_image(uvw_lambda: np.ndarray, weight: np.ndarray, vis: np.ndarray,
                  lmn: tuple) -> np.ndarray:
    """Natural-weighted dirty image (y, x), Jy/beam, by the direct Fourier sum

    D(l, m) = sum_k w_k Re[V_k exp(-2 pi i (u_k l + v_k m + w_k (n - 1)))] / sum_k w_k

    with (u, v, w) = UVW / lambda: the inverse of the MS's phase convention
    V = sum_s B_s exp(+2 pi i (u l + v m + w (n - 1))) (docs/conventions.md), normalised
    so that unit visibilities (the PSF) peak at 1, as WSClean normalises.
    """
    l, m, n1 = (a.ravel() for a in lmn)
    u, v, w = uvw_lambda.T
    phase = -2 * np.pi * (np.outer(u, l) + np.outer(v, m) + np.outer(w, n1))
    image = (weight[:, None] * (vis[:, None] * np.exp(1j * phase)).real).sum(0)
    return (image / weight.sum()).reshape(NPIX, NPIX)


def _fits(path: Path) -> tuple[np.ndarray, dict]:
    from astropy.io import fits

    with fits.open(path) as hdul:
        return np.asarray(hdul[0].data[0, 0], dtype=np.float64), dict(hdul[0].header)


@pytest.fixture(scope="module")
def images(route) -> list[dict]:
    """Per channel and image: WSClean's pixels, the direct sum, the FITS header, and
    which uv cube of ``route`` holds it under which Stokes parameter."""
    uvw, weight, stokes, freq = _ms_samples(route["ms"], "MODEL_OFF")
    found = []
    for chan in range(NCHAN):
        uvw_lambda = uvw * freq[chan] / C
        pairs = [("psf", "I", f"c-{chan:04d}-psf.fits", np.ones(len(uvw)))]
        pairs += [("off", name, f"off-{chan:04d}-{name}-image.fits", stokes[k][:, chan])
                  for k, name in enumerate("IQU")]
        for cube, name, fname, vis in pairs:
            pixels, header = _fits(route["img"] / fname)
            direct = _direct_image(uvw_lambda, weight[:, chan], vis, _pixel_lmn(header))
            found.append({"chan": chan, "cube": cube, "stokes": name, "pixels": pixels,
                          "direct": direct, "header": header})
    return found


def _source_spectrum(freq: np.ndarray) -> np.ndarray:
    """Stokes I, Q, U (3, chan) Jy of the skymodel source, as DP3 defines its spectrum."""
    i = I0 * (freq / NU0) ** ALPHA
    dlam2 = (C / freq) ** 2 - (C / NU0) ** 2
    p = (Q0 + 1j * U0) * (i / I0) * np.exp(2j * RM * dlam2)
    return np.stack([i, p.real, p.imag])


def test_wsclean_images_are_the_direct_fourier_sum(images):
    """WSClean's PSFs and its I, Q, U images of the off-centre source equal the direct
    Fourier sum of the MS's samples with the inverse of msleak's phase convention, and
    the source is on its own pixel (East to the left): one convention, orientation and
    unit (Jy/beam, PSF peak 1) in WSClean, msleak predict and ``--image``."""
    for im in images:
        assert im["header"]["BUNIT"].upper() == "JY/BEAM" and im["header"]["BMAJ"] > 0
        # WSClean's w-gridder claims WGRIDDER_ACCURACY in ducc0's L2 measure; the float32
        # FITS pixels add 6e-8 of it
        err = np.linalg.norm(im["pixels"] - im["direct"]) / np.linalg.norm(im["direct"])
        assert err < WGRIDDER_ACCURACY, (im["chan"], im["cube"], im["stokes"], err)
        if im["cube"] == "off" and im["stokes"] == "I":
            # the source is 0.5 deg East, 0.3 deg North: the brightest pixel is the one
            # nearest (l, m), not its mirror image
            l, m, _ = _pixel_lmn(im["header"])
            nearest = np.argmin(np.hypot(l - OFF_LM[0], m - OFF_LM[1]))
            assert np.argmax(im["pixels"]) == nearest


def test_image_route_cube_is_the_transform_of_the_direct_sum(route, images):
    """The uv cubes ``msleak grid --image`` makes of WSClean's PSFs (the sampling
    function g) and of its images of the off-centre source equal the discrete Fourier
    transform, at the cell centres, of the direct-sum images times Omega_pix / Omega_beam
    (Jy/beam to Jy/pixel with each channel's BMAJ, BMIN): units, stacking and FFT."""
    for im in images:
        cube = route[im["cube"]]
        got = cube["vis"].sel(stokes=im["stokes"]).values[im["chan"]]
        header = im["header"]
        l, m, _ = _pixel_lmn(header)
        omega_beam = (math.pi * math.radians(header["BMAJ"]) * math.radians(header["BMIN"])
                      / (4 * math.log(2)))
        omega_pix = abs(math.radians(header["CDELT1"]) * math.radians(header["CDELT2"]))
        to_jy_pixel = omega_pix / omega_beam
        # V(u, v) = sum_pixels S exp(-2 pi i (u l + v m)), separable in l (x) and m (y)
        ex = np.exp(-2j * np.pi * np.outer(cube["u"].values, l[0]))      # (u, x)
        ey = np.exp(-2j * np.pi * np.outer(cube["v"].values, m[:, 0]))   # (v, y)
        expected = to_jy_pixel * ey @ im["direct"] @ ex.T
        # WSClean's pixels differ from the direct sum by d (test above), so
        # |got - expected| <= to_jy_pixel sum |d| at any cell: a strict bound, plus
        # float64 rounding of the sums
        bound = to_jy_pixel * np.sum(np.abs(im["pixels"] - im["direct"])) + 1e-9
        assert np.max(np.abs(got - expected)) < bound
        # and it is small against the cells (g is of order Omega_FoV / Omega_beam, 170
        # here, times the fraction of the weight in the cell)
        assert bound < 1e-3 * np.max(np.abs(expected))


def test_visibility_route_holds_the_source_spectrum(route):
    """A source at the phase centre grids to its own spectrum in every cell with data
    (known in advance: the I power law, Q and U Faraday-rotated)."""
    vis = route["vis"]
    has = vis["weight"].values > 0
    expected = _source_spectrum(vis["freq"].values)
    assert has.any(axis=0).sum() >= 40
    for k, name in enumerate("IQU"):
        cube = vis["vis"].sel(stokes=name).values
        # complex64 MS column (6e-8) and wgrid --epsilon 1e-6
        err = np.abs(cube - expected[k][:, None, None])[has]
        assert np.max(err) < 1e-5 * I0, name


def _power(cube: xr.Dataset, mask: np.ndarray) -> xr.Dataset:
    import msleak

    cube = cube.assign(weight=(cube["weight"].dims, mask.astype(np.float64)))
    return msleak.power_spectrum(msleak.transform(cube), beam_area=1e-3)


def test_image_route_power_spectrum_is_visibility_route_weighted_by_psf(route):
    """The image route's power spectrum equals that of the visibility route's cube
    multiplied, cell by cell and channel by channel, by the uv cube of the PSF.

    For emission at the phase centre every sample holds the source's spectrum S(nu), so
    the dirty image is S(nu) times the PSF and its transform S(nu) g(u, nu), g the
    gridded PSF; the visibility route's cells hold S(nu). WSClean grids a channel's dirty
    image and PSF from the same samples with the same kernel, so even its gridding error
    scales with S(nu): the relation is exact up to rounding, float32 FITS pixels and
    complex64 visibilities (1e-7 relative each), and powers must agree to 1e-5 of the
    largest power of their Stokes parameter. Cells: those with data in the visibility
    route (the image route has every cell)."""
    image, vis, psf = route["image"], route["vis"], route["psf"]
    for a, b in ((image, vis), (psf, vis)):
        np.testing.assert_allclose(a["u"].values, b["u"].values, rtol=1e-9)
        np.testing.assert_allclose(a["v"].values, b["v"].values, rtol=1e-9)
        np.testing.assert_allclose(a["freq"].values, b["freq"].values, rtol=1e-12)
    mask = vis["weight"].values > 0
    g = psf["vis"].sel(stokes="I").values
    weighted = vis.assign(vis=(vis["vis"].dims, vis["vis"].values * g[None]))
    got, want = _power(image, mask), _power(weighted, mask)
    for name in "IQUP":
        p_got = got["power_jy2"].sel(stokes=name).values
        p_want = want["power_jy2"].sel(stokes=name).values
        used = got["counts"].values > 0
        assert used.sum() >= 10
        np.testing.assert_allclose(p_got[used], p_want[used], rtol=0,
                                   atol=1e-5 * np.max(p_want[used]), err_msg=name)


def test_glob_leaves_out_wsclean_mfs_images(tmp_path):
    """A glob matching WSClean's per-channel images and its whole-band MFS images (which
    ``-channels-out`` also writes) gives the per-channel ones; named files are kept. Only
    names ending as WSClean ends an MFS image count: ``-MFS-`` elsewhere in a name (a
    user's prefix) does not."""
    from msleak.verbs.images import _is_wsclean_mfs, image_paths

    names = [f"obs-{c}-{s}-image.fits" for c in ("0000", "0001", "MFS") for s in "QU"]
    names += ["obs-0000-psf.fits", "obs-MFS-psf.fits", "run-MFS-a-0000-Q-image.fits"]
    for name in names:
        (tmp_path / name).touch()
    got = image_paths(str(tmp_path / "obs-*-[QU]-image.fits"))
    assert [Path(p).name for p in got] == sorted(n for n in names if n.startswith("obs-")
                                                 and "MFS" not in n and "psf" not in n)
    mfs = image_paths(str(tmp_path / "obs-MFS-*-image.fits"))
    assert [Path(p).name for p in mfs] == ["obs-MFS-Q-image.fits", "obs-MFS-U-image.fits"]
    named = image_paths([str(tmp_path / "obs-0000-Q-image.fits"),
                         str(tmp_path / "obs-MFS-Q-image.fits")])
    assert [Path(p).name for p in named] == ["obs-0000-Q-image.fits", "obs-MFS-Q-image.fits"]
    psf = image_paths(str(tmp_path / "obs-*-psf.fits"))
    assert [Path(p).name for p in psf] == ["obs-0000-psf.fits"]
    # a prefix with -MFS- in it: a per-channel image, kept
    prefixed = image_paths(str(tmp_path / "run-*-Q-image.fits"))
    assert [Path(p).name for p in prefixed] == ["run-MFS-a-0000-Q-image.fits"]
    # WSClean's MFS names: Stokes or correlation (XYi: its imaginary part) or none, any
    # image type, primary-beam corrected (-pb), after -t0000 for -intervals-out
    for name in ("obs-MFS-image.fits", "obs-MFS-Q-image.fits", "obs-MFS-psf.fits",
                 "obs-MFS-I-residual.fits", "obs-MFS-dirty.fits", "obs-MFS-V-model.fits",
                 "obs-MFS-XYi-image.fits", "obs-MFS-I-image-pb.fits", "obs-MFS-beam-0.fits",
                 "obs-t0001-MFS-U-first-residual.fits", "d/x-MFS-Q-image.fits"):
        assert _is_wsclean_mfs(name), name
    for name in ("obs-0000-Q-image.fits", "obs-MFS-a-0000-Q-image.fits", "obs-MFS.fits",
                 "obs-MFS-Q-image.fits.gz", "obs-MFS-Q-notes.fits", "obsMFS-Q-image.fits",
                 "x-MFS-Q-image.fits/obs-0000-Q-image.fits"):
        assert not _is_wsclean_mfs(name), name
