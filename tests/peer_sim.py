"""The visibility simulators pyuvsim and matvis, run on the metadata of an msleak MS.

Used by tests/peers/test_peer_simulators.py and tests/peers/test_peer_healpix.py. Each
peer gets the MS's antenna positions (as East, North, Up offsets from their mean
position), TIME centres, channel frequencies, the same sources and the same beam, and
returns drift-scan visibilities that this module phases to the MS's phase centre. How
each peer's conventions map onto msleak's (baseline sign, feed order, Stokes factor,
polarization basis) is in docs/conventions.md, "Peer simulators (matvis, pyuvsim)".
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import pytest

from ms_helpers import C, channel_freqs, phase_centre


@dataclass
class Observation:
    """What the peers need from an MS.

    Attributes
    ----------
    positions : (nant, 3) ITRF antenna positions, m
    times : (ntime,) TIME centres, UTC MJD seconds
    freqs : (nchan,) channel centres, Hz
    phase_centre : (ra, dec) of FIELD 0, J2000, rad
    location : astropy EarthLocation of the mean antenna position
    enu : (nant, 3) antenna offsets from ``location`` in its East, North, Up frame, m
    """

    positions: np.ndarray
    times: np.ndarray
    freqs: np.ndarray
    phase_centre: tuple[float, float]
    location: object
    enu: np.ndarray


def small_hera(path) -> tuple:
    """A small HERA MS (4 dishes, 2 channels of 15 MHz from 100 MHz, 2 x 600 s) and its
    :class:`Observation`: the all-sky peer comparisons' observation."""
    from msleak.verbs.simulate import simulate

    ms = simulate(path, telescope="hera", stations="HH65,HH66,HH67,HH82", nchan=2,
                  freq_min=100e6, chan_width=15e6, duration=1200 / 3600, interval=600.0)
    return ms, read_observation(ms)


def read_observation(ms) -> Observation:
    """Antennas, times, channels and phase centre of ``ms`` (one field, one window)."""
    import astropy.units as u
    import casacore.tables as pt
    from astropy.coordinates import EarthLocation
    from pyuvdata.utils import ENU_from_ECEF

    with pt.table(f"{ms}/ANTENNA", ack=False) as t:
        positions = t.getcol("POSITION")
    with pt.table(str(ms), ack=False) as t:
        times = np.unique(t.getcol("TIME"))
    location = EarthLocation.from_geocentric(*positions.mean(axis=0), unit=u.m)
    enu = ENU_from_ECEF(positions, center_loc=location)
    return Observation(positions, times, channel_freqs(ms), phase_centre(ms), location, enu)


def astropy_time(mjd_s):
    """astropy Time (UTC) of MS TIME values (MJD seconds)."""
    from astropy.time import Time

    return Time(np.asarray(mjd_s) / 86400.0, format="mjd", scale="utc")


def j2000(ra, dec):
    """SkyCoord of J2000 (FK5, equinox J2000) directions in rad, msleak's sky frame."""
    import astropy.units as u
    from astropy.coordinates import FK5, SkyCoord

    return SkyCoord(ra=np.atleast_1d(ra) * u.rad, dec=np.atleast_1d(dec) * u.rad,
                    frame=FK5(equinox="J2000"))


def topocentric(ra, dec, mjd_s: float, location) -> np.ndarray:
    """(n, 3) unit East, North, Up vectors of J2000 directions at one time (astropy AltAz,
    no refraction), the frame both peers compute their fringes in."""
    from astropy.coordinates import AltAz

    altaz = j2000(ra, dec).transform_to(AltAz(obstime=astropy_time(mjd_s), location=location))
    alt, az = altaz.alt.rad, altaz.az.rad
    return np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], axis=-1)


def _rephase(obs: Observation, it: int, ifreq: int) -> np.ndarray:
    """(nant, nant) exp(-2 pi i (x_q - x_p) . s0 / lambda): removes the drift-scan fringe
    of the phase centre s0 from the pair (p, q) at time index ``it``, channel ``ifreq``."""
    s0 = topocentric(*obs.phase_centre, obs.times[it], obs.location)[0]
    delay = obs.enu @ s0                                   # (nant,) m
    return np.exp(-2j * np.pi * (delay[None, :] - delay[:, None])
                  * obs.freqs[ifreq] / C)


def pyuvsim_visibilities(obs: Observation, beam, ra, dec, stokes) -> np.ndarray:
    """pyuvsim's visibilities of point sources, phased to the phase centre.

    Parameters
    ----------
    beam : pyuvdata UVBeam or AnalyticBeam (E-field), the same for every antenna
    ra, dec : (nsrc,) J2000, rad
    stokes : (nsrc, nchan, 4) pyradiosky (I, Q, U, V) at the MS channels, Jy

    Returns
    -------
    (ntime, nant, nant, nchan, 2, 2) complex: ``[t, p, q, c, a, b]`` is pyuvsim's
    correlation of feed ``a`` of antenna p with feed ``b`` of antenna q (feeds in the
    beam's ``feed_array`` order), filled for p < q, multiplied by
    exp(-2 pi i (x_q - x_p) . s0 / lambda).
    """
    import astropy.units as u
    from pyradiosky import SkyModel

    sky = SkyModel(name=[f"s{i}" for i in range(len(ra))], skycoord=j2000(ra, dec),
                   stokes=np.transpose(stokes, (2, 1, 0)) * u.Jy, spectral_type="full",
                   freq_array=obs.freqs * u.Hz)
    return pyuvsim_sky_visibilities(obs, beam, sky)


def pyuvsim_sky_visibilities(obs: Observation, beam, sky) -> np.ndarray:
    """:func:`pyuvsim_visibilities` of a pyradiosky SkyModel of point components with
    spectral type ``full`` at the MS channels (a HEALPix model: after its
    ``healpix_to_point()``, as pyuvsim's own set-up does); same result layout."""
    import astropy.units as u
    from pyuvsim import Antenna, Baseline, BeamList, Telescope, UVEngine, UVTask

    telescope = Telescope("peer", obs.location, BeamList([beam]))
    antennas = [Antenna(f"a{i}", i, obs.enu[i], 0) for i in range(len(obs.enu))]
    nant, nchan = len(antennas), len(obs.freqs)
    out = np.zeros((len(obs.times), nant, nant, nchan, 2, 2), complex)
    engine = UVEngine()
    for it, t in enumerate(obs.times):
        time = astropy_time(t)
        for c, f in enumerate(obs.freqs):
            phasor = _rephase(obs, it, c)
            for p in range(nant):
                for q in range(p + 1, nant):
                    engine.set_task(UVTask(sky, time, f * u.Hz,
                                           Baseline(antennas[p], antennas[q]), telescope,
                                           freq_i=c))
                    xx, yy, xy, yx = engine.make_visibility()
                    out[it, p, q, c] = np.array([[xx, xy], [yx, yy]]) * phasor[p, q]
    return out


def matvis_visibilities(obs: Observation, beam, ra, dec, flux,
                        frame: str = "j2000") -> np.ndarray:
    """matvis's visibilities of unpolarized point sources, phased to the phase centre.

    Parameters
    ----------
    beam : pyuvdata UVBeam or AnalyticBeam (E-field), the same for every antenna
    ra, dec : (nsrc,) rad, in ``frame``: "j2000" (FK5, converted to ICRS, which matvis
        requires) or "icrs" (given as they are, e.g. HEALPix pixel centres)
    flux : (nsrc, nchan) Stokes I, Jy

    Returns
    -------
    (ntime, nant, nant, nchan, 2, 2) complex: ``[t, p, q, c, a, b]`` is matvis's pair
    (p, q), feeds a, b in the beam's order, multiplied by
    exp(-2 pi i (x_q - x_p) . s0 / lambda).
    """
    from matvis import simulate_vis

    if frame == "icrs":
        ra_icrs, dec_icrs = np.asarray(ra, float), np.asarray(dec, float)
    elif frame == "j2000":
        icrs = j2000(ra, dec).icrs
        ra_icrs, dec_icrs = icrs.ra.rad, icrs.dec.rad
    else:
        raise ValueError(f"frame {frame!r} is not j2000 or icrs")
    nant, ntime, nchan = len(obs.enu), len(obs.times), len(obs.freqs)
    vis = simulate_vis(ants={i: obs.enu[i] for i in range(nant)}, fluxes=flux,
                       ra=ra_icrs, dec=dec_icrs, freqs=obs.freqs,
                       times=astropy_time(obs.times), beams=[beam],
                       telescope_loc=obs.location, polarized=True, precision=2)
    vis = vis.reshape(nchan, ntime, nant, nant, 2, 2).transpose(1, 2, 3, 0, 4, 5)
    for it in range(ntime):
        for c in range(nchan):
            vis[it, :, :, c] *= _rephase(obs, it, c)[:, :, None, None]
    return vis


def as_ms_rows(peer: np.ndarray, obs: Observation, vis, ns_feed: int = 1) -> np.ndarray:
    """A peer's (ntime, nant, nant, nchan, 2, 2) array on the rows of msleak's DataArray
    ``vis`` (row, chan, corr XX, XY, YX, YY): the peer's pair (p, q) for the row of
    antenna1 p and antenna2 q, X being the peer's feed ``ns_feed`` (North-South) and Y
    the other."""
    it = np.searchsorted(obs.times, vis.time.values)
    rows = peer[it, vis.antenna1.values, vis.antenna2.values]   # (row, chan, 2, 2)
    x, y = ns_feed, 1 - ns_feed
    out = np.empty(rows.shape[:2] + (4,), complex)
    for k, name in enumerate(vis.corr.values):
        a, b = {"XX": (x, x), "XY": (x, y), "YX": (y, x), "YY": (y, y)}[str(name)]
        out[:, :, k] = rows[:, :, a, b]
    return out


def mirrored_azimuth(beam):
    """A copy of an E-field beam (UVBeam or pyuvdata AnalyticBeam) with its azimuth
    component negated: what pyuvsim 1.4.2 needs to agree with the geometry for polarized
    sources (docs/conventions.md, "Peer simulators")."""
    if hasattr(beam, "data_array"):
        out = beam.copy()
        out.data_array[0] = -out.data_array[0]
        return out

    class Mirrored(type(beam)):
        def _efield_eval(self, **grids):
            data = super()._efield_eval(**grids)
            data[0] = -data[0]
            return data

    out = copy.copy(beam)
    out.__class__ = Mirrored
    return out


def hera_beam():
    """pyuvsim's HERA_NicCST.beamfits, read as msleak reads it (no mount type in the file:
    pyuvdata assumes a fixed mount, as for HERA)."""
    import warnings

    from pyuvdata import UVBeam

    from msleak.io.uvbeam import default_beam_file

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="The mount_type parameter must be set")
        return UVBeam.from_file(str(default_beam_file()))


def zenith_amplitude(beam) -> np.ndarray:
    """(nfreq,) |E| of the zenith pixel component that is largest at the first frequency:
    what msleak divides a UVBeam file by (docs/hera.md, "Normalisation")."""
    zenith = int(np.argmin(np.abs(beam.axis2_array)))
    at_zenith = beam.data_array[:, :, :, zenith, :]
    a, f, k = np.unravel_index(np.argmax(np.abs(at_zenith[:, :, 0, :])),
                               at_zenith[:, :, 0].shape)
    return np.abs(at_zenith[a, f, :, k])


def peak_amplitude(beam) -> np.ndarray:
    """(nfreq,) the largest |E| per frequency: what pyuvsim's BeamList divides by."""
    return np.abs(beam.data_array).max(axis=(0, 1, 3, 4))


def hyperbeam_tile(latitude_rad: float):
    """mwa_hyperbeam's analytic MWA tile (zenith delays, unit amplitudes, normalised to
    the zenith) as a pyuvdata analytic E-field beam, evaluated exactly at every direction
    a peer asks for (no interpolation).

    Feeds ``x`` = the East-West dipole (``feed_angle`` 90 deg), ``y`` = North-South (0).
    hyperbeam returns rows (EW, NS) and columns along increasing zenith angle (theta) and
    increasing azimuth North through East (phi); pyuvdata's azimuth runs East through
    North, so its az component is -phi and its za component theta.
    """
    import mwa_hyperbeam

    def efield(self, *, az_grid, za_grid, f_grid):
        data = self._get_empty_data_array(az_grid.shape).astype(complex)
        tile = mwa_hyperbeam.AnalyticBeam()
        up = za_grid < np.pi / 2                      # hyperbeam refuses the rest
        for f in np.unique(f_grid):
            sel = up & (f_grid == f)
            az = np.mod(np.pi / 2 - az_grid[sel], 2 * np.pi)   # North through East
            h = np.asarray(tile.calc_jones_array(az, za_grid[sel], float(f), [0] * 16,
                                                 [1.0] * 16, latitude_rad, True))
            h = h.reshape(-1, 2, 2)                   # (n, EW/NS, theta/phi)
            data[0, 0][sel] = -h[:, 0, 1]
            data[1, 0][sel] = h[:, 0, 0]
            data[0, 1][sel] = -h[:, 1, 1]
            data[1, 1][sel] = h[:, 1, 0]
        return data

    return _xy_beam("HyperbeamTile", efield)


def identity_beam():
    """A pyuvdata analytic E-field beam whose x feed takes the azimuth component and y the
    zenith-angle component, with gain 1 everywhere: J J^H is the identity, so unpolarized
    sources see no beam at all."""
    def efield(self, *, az_grid, za_grid, f_grid):
        data = self._get_empty_data_array(az_grid.shape).astype(complex)
        data[0, 0] = 1.0
        data[1, 1] = 1.0
        return data

    return _xy_beam("IdentityBeam", efield)


def _xy_beam(name: str, efield):
    """A pyuvdata analytic E-field beam in the az/za basis with feeds ``x`` (East-West,
    ``feed_angle`` 90 deg) and ``y`` (North-South, 0) whose ``_efield_eval`` is ``efield``."""
    from pyuvdata.analytic_beam import AnalyticBeam

    def validate(self):
        self.feed_array = np.asarray(["x", "y"])
        self.feed_angle = np.asarray([np.pi / 2, 0.0])

    cls = type(name, (AnalyticBeam,), {"__annotations__": {}, "basis_vector_type": "az_za",
                                       "validate": validate, "_efield_eval": efield})
    return dataclass(kw_only=True, eq=False)(cls)()


#: The two ways a beam's azimuth component can be handed to pyuvsim: as the beam gives it,
#: or negated (:func:`mirrored_azimuth`). Which one the installed pyuvsim needs for
#: polarized sources is decided against geometry alone (:func:`geometry_verdict` of
#: :func:`short_dipole_errors`).
AZIMUTH_HANDLING = {"as given": lambda beam: beam, "mirrored": mirrored_azimuth}
#: Q, U sign conventions tried with each handling: only the identity may agree
QU_SIGNS = ((1, 1, 1, 1), (1, -1, 1, 1), (1, 1, -1, 1), (1, -1, -1, 1))
#: pyuvsim against the dipole geometry, in units of a unit source: pyradiosky turns the
#: field to alt/az by its frame axes' average rotation plus the shortest turn onto each
#: apparent position, not by the central differences used here; they differ by 1.7e-5
#: (printed), a wrong azimuth sign by 1.1 and a wrong Q or U sign by 0.6 to 1.9
GEOMETRY_TOLERANCE = 1e-4


def short_dipole_errors() -> dict:
    """{(handling, Q/U signs): largest |pyuvsim - geometry|} for five polarized sources
    seen by pyuvdata's analytic short dipoles on one zero-length baseline, against the
    projection of each dipole's axis on each source's electric field computed here from
    astropy's AltAz alone (no msleak)."""
    import astropy.units as u
    from astropy.coordinates import AltAz, EarthLocation, SkyCoord
    from pyuvdata.analytic_beam import ShortDipoleBeam

    location = EarthLocation.from_geodetic(21.4283 * u.deg, -30.7215 * u.deg, 1051.7 * u.m)
    t = 58000.25 * 86400.0
    frame = AltAz(obstime=astropy_time(t), location=location)
    az = np.radians([30.0, 120.0, 210.0, 300.0, 75.0])          # North through East
    alt = np.radians([60.0, 45.0, 70.0, 55.0, 80.0])
    chi = np.radians([20.0, -35.0, 70.0, 5.0, -80.0])           # IAU, North through East
    radec = SkyCoord(az=az * u.rad, alt=alt * u.rad, frame=frame).transform_to(
        j2000(0.0, 0.0).frame)
    ra, dec = radec.ra.rad, radec.dec.rad
    # each source's sky North and East in (East, North, Up): central differences of 1e-5
    # rad (truncation ~1e-10; astropy's rounding, ~1e-12 per vector, adds ~1e-7)
    step = 1e-5
    north = (topocentric(ra, dec + step, t, location)
             - topocentric(ra, dec - step, t, location))
    east = (topocentric(ra + step / np.cos(dec), dec, t, location)
            - topocentric(ra - step / np.cos(dec), dec, t, location))
    north /= np.linalg.norm(north, axis=1)[:, None]
    east /= np.linalg.norm(east, axis=1)[:, None]
    field = np.cos(chi)[:, None] * north + np.sin(chi)[:, None] * east    # (nsrc, 3)
    # feeds x (East-West dipole) and y (North-South): V_ab = sum I (a . e)(b . e)
    volts = field[:, :2]                                        # (nsrc, [x, y])
    expected = np.einsum("sa,sb->ab", volts, volts)

    stokes = np.stack([np.ones(5), np.cos(2 * chi), np.sin(2 * chi), np.zeros(5)], -1)
    obs = Observation(positions=np.zeros((2, 3)), times=np.array([t]),
                      freqs=np.array([150e6]), phase_centre=(ra[0], dec[0]),
                      location=location, enu=np.zeros((2, 3)))   # one zero-length baseline
    errors = {}
    for name, handle in AZIMUTH_HANDLING.items():
        for signs in QU_SIGNS:
            got = pyuvsim_visibilities(obs, handle(ShortDipoleBeam()), ra, dec,
                                       (stokes * np.array(signs))[:, None, :])[0, 0, 1, 0]
            errors[name, signs] = float(np.abs(got - expected).max())
    return errors


def geometry_verdict(errors: dict) -> tuple[str, str]:
    """(the handling that agrees with the geometry, the other one); fails unless exactly
    one handling agrees, and with Q and U as they are."""
    for (name, signs), error in errors.items():
        print(f"short dipoles, pyuvsim, azimuth {name}, signs {signs}: {error:.2e}")
    agree = [key for key, error in errors.items() if error < GEOMETRY_TOLERANCE]
    if len(agree) != 1 or agree[0][1] != QU_SIGNS[0]:
        pytest.fail(f"pyuvsim with short dipoles: {agree or 'no'} (azimuth handling, Q/U "
                    f"signs) agree with the geometry; exactly one handling with Q, U as "
                    f"given should: {errors}", pytrace=False)
    right = agree[0][0]
    return right, next(name for name in AZIMUTH_HANDLING if name != right)
