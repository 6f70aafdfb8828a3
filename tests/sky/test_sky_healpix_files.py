"""HEALPix skies from files (msleak.adapters.healpix) and their frames (msleak.sky.frames):

* SkyH5 written by pyradiosky reads back exactly (K and Jy/sr, ring and nested, full,
  subband and flat spectra, partial skies); HEALPix FITS maps written by healpy (tables,
  partial maps with UNSEEN pixels) and by astropy (an image cube of pixel x FREQ x STOKES)
  read back to their values;
* a rotation-measure map turns Q + iU by exp(2i RM (lambda^2 - lambda0^2)) (written here);
* a Galactic or ecliptic lit pixel becomes a source at astropy's ICRS position of its
  centre, its Q + iU turned by twice the ICRS position angle of its frame's North there
  (measured here by moving the pixel centre North in its own frame, astropy only);
* predict's sky loader tells the files apart by content;
* files msleak cannot read give one-line InputErrors naming what to fix.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from peers import require

require("pyradiosky", "pyradiosky writes and reads SkyH5 (msleak[healpix])")
require("healpy", "healpy writes HEALPix FITS maps (msleak[healpix])")

import astropy.units as u  # noqa: E402
from astropy.coordinates import BarycentricMeanEcliptic, Galactic, SkyCoord  # noqa: E402
from astropy.io import fits  # noqa: E402

from msleak.adapters.healpix import read_healpix  # noqa: E402
from msleak.errors import InputError  # noqa: E402
from msleak.sky.cube import SkyCube  # noqa: E402
from msleak.sky.healpix import HealpixSky, healpix_sources  # noqa: E402
from msleak.verbs.predict_plan import make_targets  # noqa: E402

C = 299_792_458.0
NSIDE = 8
NPIX = 12 * NSIDE**2
FREQ = np.array([150e6, 151e6, 152e6])


def _skymodel(path, *, unit="K", order="ring", spectral="full", frame="icrs", pixels=None,
              seed=1):
    from pyradiosky import SkyModel

    pixels = np.arange(NPIX) if pixels is None else np.asarray(pixels)
    rng = np.random.default_rng(seed)
    nfreq = 1 if spectral in ("flat", "spectral_index") else FREQ.size
    stokes = rng.normal(size=(4, nfreq, pixels.size))
    stokes[0] = np.abs(stokes[0])
    kw = {}
    if spectral in ("full", "subband"):
        kw["freq_array"] = FREQ * u.Hz
    if spectral == "subband":
        kw["freq_edge_array"] = np.stack([FREQ - 0.5e6, FREQ + 0.5e6]) * u.Hz
    if spectral == "spectral_index":
        kw.update(reference_frequency=np.full(pixels.size, 150e6) * u.Hz,
                  spectral_index=np.full(pixels.size, -2.5))
    model = SkyModel(nside=NSIDE, hpx_inds=pixels, stokes=stokes * u.Unit(unit),
                     spectral_type=spectral, frame=frame, hpx_order=order, **kw)
    model.write_skyh5(str(path))
    return stokes


@pytest.mark.parametrize("unit", ["K", "Jy/sr"])
@pytest.mark.parametrize("order", ["ring", "nested"])
@pytest.mark.parametrize("spectral", ["full", "subband"])
def test_skyh5_round_trip(tmp_path, unit, order, spectral):
    pixels = np.arange(0, NPIX, 3)
    stokes = _skymodel(tmp_path / "s.skyh5", unit=unit, order=order, spectral=spectral,
                       pixels=pixels)
    sky = read_healpix(tmp_path / "s.skyh5")
    assert (sky.nside, sky.order, sky.unit, sky.frame, sky.flat) == (NSIDE, order, unit,
                                                                     "icrs", False)
    np.testing.assert_array_equal(sky.pixels, pixels)
    np.testing.assert_array_equal(sky.freq_hz, FREQ)
    np.testing.assert_array_equal(sky.stokes, stokes)


def test_skyh5_flat_galactic_and_millikelvin(tmp_path):
    stokes = _skymodel(tmp_path / "flat.skyh5", unit="mK", spectral="flat", frame="galactic")
    sky = read_healpix(tmp_path / "flat.skyh5")
    assert sky.flat and sky.frame == "galactic" and sky.unit == "K"
    np.testing.assert_allclose(sky.stokes, stokes * 1e-3, rtol=1e-15)
    on = sky.on_channels(FREQ)
    np.testing.assert_array_equal(on.stokes, np.repeat(sky.stokes, FREQ.size, axis=1))


def _healpy_map(path, maps, *, names=None, units="K", coord="G", nest=False, freq=150e6,
                partial=False):
    import healpy as hp

    extra = [] if freq is None else [("FREQ", freq)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hp.write_map(str(path), maps, nest=nest, coord=coord, column_units=units,
                     column_names=names, extra_header=extra, partial=partial, dtype=np.float64)
    return path


def test_healpy_table_of_three_maps(tmp_path):
    rng = np.random.default_rng(2)
    maps = rng.normal(size=(3, NPIX))
    path = _healpy_map(tmp_path / "iqu.fits", maps, nest=True)   # TEMPERATURE, Q_, U_POL...
    sky = read_healpix(path)
    assert (sky.order, sky.frame, sky.unit) == ("nested", "galactic", "K")
    np.testing.assert_array_equal(sky.freq_hz, [150e6])
    np.testing.assert_array_equal(sky.stokes[:3, 0], maps)
    assert not sky.stokes[3].any()


def test_healpy_partial_map_leaves_unseen_pixels_out(tmp_path):
    import healpy as hp

    rng = np.random.default_rng(3)
    maps = rng.normal(size=(2, NPIX))
    maps[:, :100] = hp.UNSEEN
    maps[1, 150] = np.nan
    path = _healpy_map(tmp_path / "qu.fits", maps, names=["Q", "U"], units="Jy/sr",
                       coord="C", partial=True)
    sky = read_healpix(path)
    keep = np.setdiff1d(np.arange(100, NPIX), [150])
    assert (sky.frame, sky.unit) == ("icrs", "Jy/sr")
    np.testing.assert_array_equal(sky.pixels, keep)
    np.testing.assert_array_equal(sky.stokes[1:3, 0], maps[:, keep])


def test_astropy_image_cube_of_pixels_frequencies_and_stokes(tmp_path):
    rng = np.random.default_rng(4)
    data = rng.normal(size=(2, FREQ.size, NPIX))          # (STOKES, FREQ, pixel)
    header = fits.Header()
    header.update(PIXTYPE="HEALPIX", ORDERING="RING", NSIDE=NSIDE, COORDSYS="E", BUNIT="mK",
                  CTYPE2="FREQ", CRVAL2=150.0, CDELT2=1.0, CRPIX2=1.0, CUNIT2="MHz",
                  CTYPE3="STOKES", CRVAL3=2.0, CDELT3=1.0, CRPIX3=1.0)
    fits.PrimaryHDU(data, header).writeto(tmp_path / "cube.fits")
    sky = read_healpix(tmp_path / "cube.fits")
    assert (sky.frame, sky.unit, sky.order) == ("ecliptic", "K", "ring")
    np.testing.assert_allclose(sky.freq_hz, FREQ, rtol=1e-15)
    np.testing.assert_allclose(sky.stokes[1:3], data * 1e-3, rtol=1e-15)
    assert not sky.stokes[[0, 3]].any()


def test_rotation_measure_map_turns_q_and_u(tmp_path):
    rng = np.random.default_rng(5)
    q, u_, rm = rng.normal(size=NPIX), rng.normal(size=NPIX), rng.uniform(-10, 10, NPIX)
    cols = [fits.Column(name=n, format="D", unit=unit, array=a)
            for n, unit, a in (("Q", "K", q), ("U", "K", u_), ("RM", "rad/m2", rm))]
    table = fits.BinTableHDU.from_columns(cols)
    table.header.update(PIXTYPE="HEALPIX", ORDERING="RING", NSIDE=NSIDE, COORDSYS="C",
                        FREQ=140e6)
    fits.HDUList([fits.PrimaryHDU(), table]).writeto(tmp_path / "rm.fits")
    sky = read_healpix(tmp_path / "rm.fits").on_channels(FREQ)
    lam2 = (C / FREQ) ** 2 - (C / 140e6) ** 2
    expected = (q + 1j * u_)[None, :] * np.exp(2j * rm[None, :] * lam2[:, None])
    np.testing.assert_allclose(sky.stokes[1] + 1j * sky.stokes[2], expected, rtol=0,
                               atol=1e-13)
    assert not sky.stokes[[0, 3]].any()


@pytest.mark.parametrize("frame,astropy_frame", [
    ("galactic", Galactic()), ("ecliptic", BarycentricMeanEcliptic(equinox="J2000"))])
def test_a_lit_pixel_moves_to_icrs_and_its_polarization_turns(frame, astropy_frame):
    """Pixels all over the sphere, each lit with its own Q, U: the source is at astropy's
    ICRS position of the pixel centre (to 1e-11 rad) and Q + iU is turned by exp(2i psi),
    psi the ICRS position angle of the point 1e-6 rad North of the centre in the map's
    frame: to 1e-8 of |Q + iU| (measured 7e-10; the step's own error is about 1e-10)."""
    from astropy_healpix import healpix_to_lonlat

    pixels = np.arange(5, NPIX, 37)
    rng = np.random.default_rng(6)
    stokes = np.zeros((4, 1, pixels.size))
    stokes[1:3, 0] = rng.normal(size=(2, pixels.size))
    sky = HealpixSky(nside=NSIDE, order="ring", pixels=pixels, freq_hz=[150e6],
                     stokes=stokes, unit="Jy/sr", frame=frame)
    sources = healpix_sources(sky)
    lon, lat = healpix_to_lonlat(pixels, NSIDE, order="ring")
    centre = SkyCoord(lon, lat, frame=astropy_frame).icrs
    north = SkyCoord(lon, lat + 1e-6 * u.rad, frame=astropy_frame).icrs
    assert np.abs(centre.separation(SkyCoord(sources.ra * u.rad, sources.dec * u.rad)).rad
                  ).max() < 1e-11
    psi = centre.position_angle(north).rad
    area = 4 * np.pi / NPIX
    expected = (stokes[1, 0] + 1j * stokes[2, 0]) * np.exp(2j * psi) * area
    got = sources.stokes[:, 0, 1] + 1j * sources.stokes[:, 0, 2]
    print(f"{frame}: largest |msleak - astropy| / |Q + iU|: "
          f"{np.abs(got - expected).max() / np.abs(expected).max():.1e}")
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
    turned = np.abs(np.angle(got / ((stokes[1, 0] + 1j * stokes[2, 0]) * area))) > 0.1
    assert turned.mean() > 0.5                           # the frames' Norths differ


def test_predict_loader_tells_the_files_apart(tmp_path):
    from msleak.adapters.sky_fits import write_cube
    from msleak.sky.foreground import generate_foreground_cube

    _skymodel(tmp_path / "a.h5")
    _healpy_map(tmp_path / "m.fits", np.ones((3, NPIX)))
    cube = generate_foreground_cube(npix=4, fov_deg=2.0, freq_min_hz=150e6, nchan=2,
                                    chan_width_hz=1e6, seed=1)
    write_cube(cube, tmp_path / "c.fits")
    targets = make_targets([tmp_path / "a.h5", tmp_path / "m.fits", tmp_path / "c.fits"],
                           None, None, False)
    assert [type(t.sky) for t in targets] == [HealpixSky, HealpixSky, SkyCube]


def _table_file(path, header=None, columns=(("Q", "K"), ("U", "K")), primary=None):
    cols = [fits.Column(name=n, format="D", unit=unit, array=np.ones(NPIX))
            for n, unit in columns]
    table = fits.BinTableHDU.from_columns(cols)
    cards = dict(PIXTYPE="HEALPIX", ORDERING="RING", NSIDE=NSIDE, COORDSYS="G", FREQ=150e6)
    cards.update(header or {})
    for key, value in cards.items():
        if value is None:
            table.header.remove(key, ignore_missing=True)
        else:
            table.header[key] = value
    fits.HDUList([fits.PrimaryHDU(header=primary), table]).writeto(path)
    return path


def _bad_skyh5(kind):
    def make(path):
        if kind == "point":
            from pyradiosky import SkyModel

            SkyModel(name=["a"], skycoord=SkyCoord(1 * u.deg, 2 * u.deg),
                     stokes=np.ones((4, 1, 1)) * u.Jy, spectral_type="flat"
                     ).write_skyh5(str(path))
        elif kind == "index":
            _skymodel(path, spectral="spectral_index")
        else:
            import h5py

            with h5py.File(path, "w") as fh:
                fh["x"] = np.arange(3)
        return path
    return make


@pytest.mark.parametrize("make,words", [
    (lambda p: _table_file(p, {"COORDSYS": None}), "no COORDSYS; set it to G"),
    (lambda p: _table_file(p, {"COORDSYS": "X"}), "COORDSYS is 'X'"),
    (lambda p: _table_file(p, {"ORDERING": None}), "no ORDERING; set it to RING or NESTED"),
    (lambda p: _table_file(p, {"NSIDE": None}), "no NSIDE"),
    (lambda p: _table_file(p, columns=(("Q", "K_CMB"), ("U", "K_CMB"))),
     "CMB thermodynamic temperature"),
    (lambda p: _table_file(p, columns=(("Q", ""), ("U", ""))), "column Q is not given"),
    (lambda p: _table_file(p, columns=(("Q", "K"), ("U", "Jy/sr"))), "columns in K and in"),
    (lambda p: _table_file(p, {"FREQ": "030"}), "is not a frequency in Hz"),
    (lambda p: _table_file(p, {"FREQ": None}), "pass flat_spectrum"),
    (lambda p: _table_file(p, {"FREQ": None}, columns=(("Q", "K"), ("RM", "rad/m2"))),
     "needs the frequency of the Q, U maps"),
    (lambda p: _table_file(p, columns=(("Q", "K"), ("RM", "deg")),), "a rotation measure is"),
    (lambda p: _table_file(p, columns=(("COLUMN_1", "K"), ("COLUMN_2", "K"))),
     "no Stokes column"),
    (lambda p: _table_file(p, {"INDXSCHM": "EXPLICIT"}), "needs a PIXEL column"),
    (_bad_skyh5("point"), "holds point components"),
    (_bad_skyh5("index"), "spectral type 'spectral_index'"),
    (_bad_skyh5("h5"), "not a SkyH5 file pyradiosky can read"),
], ids=["no-coordsys", "bad-coordsys", "no-ordering", "no-nside", "cmb", "no-unit",
        "mixed-units", "freq-text", "no-freq", "rm-no-freq", "rm-unit", "unnamed",
        "explicit-no-pixel", "skyh5-point", "skyh5-index", "h5-not-skyh5"])
def test_files_msleak_cannot_read_give_one_line(tmp_path, make, words):
    path = make(tmp_path / "bad.skyh5")
    with pytest.raises(InputError) as err:
        read_healpix(path)
    assert words in str(err.value), str(err.value)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_a_cut_file_and_a_skyh5_name_on_text_are_refused(tmp_path):
    whole = _healpy_map(tmp_path / "m.fits", np.ones((3, NPIX)))
    cut = tmp_path / "cut.fits"
    cut.write_bytes(whole.read_bytes()[:-4000])
    with pytest.raises(InputError, match="cut short|truncated|shorter"):
        read_healpix(cut)
    text = tmp_path / "sky.skyh5"
    text.write_text("format = Name, Type, Ra, Dec, I\n")
    with pytest.raises(InputError, match="is not an HDF5 file, so not SkyH5"):
        make_targets(text, None, None, False)


@pytest.mark.parametrize("kw,words", [
    ({"frame": "supergalactic"}, "frame 'supergalactic' is not one of"),
    ({"rotation_measure": np.zeros(NPIX)}, "a flat or Faraday-rotated sky has one map"),
    ({"flat": True}, "a flat or Faraday-rotated sky has one map"),
])
def test_healpix_sky_refuses_what_does_not_fit(kw, words):
    with pytest.raises(InputError, match=words.replace("(", r"\(")):
        HealpixSky(nside=NSIDE, order="ring", pixels=np.arange(NPIX), freq_hz=FREQ,
                   stokes=np.zeros((4, FREQ.size, NPIX)), **kw)


def test_cosmo_convention_maps_have_their_u_turned_and_others_are_refused(tmp_path):
    from msleak.adapters.healpix import read_healpix_fits

    iau = read_healpix_fits(_table_file(tmp_path / "iau.fits", {"COORDSYS": "C"}))
    cosmo = read_healpix_fits(_table_file(tmp_path / "cosmo.fits", {"COORDSYS": "C",
                                                                     "POLCCONV": "COSMO"}))
    np.testing.assert_array_equal(cosmo.stokes[1], iau.stokes[1])
    np.testing.assert_array_equal(cosmo.stokes[2], -iau.stokes[2])
    assert np.all(iau.stokes[2] == 1.0)
    with pytest.raises(InputError, match="POLCCONV is 'OTHER'"):
        read_healpix_fits(_table_file(tmp_path / "x.fits", {"POLCCONV": "OTHER"}))
