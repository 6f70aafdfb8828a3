"""HERA and MWA layouts, from the files pyuvdata and pyuvsim ship.

* HERA: pyuvdata's HERA antenna file and site, 350 antennas (HH0-HH319 in the core, HA and HB outriggers up to HB349) of 14 m dishes,
  fixed and pointing at the zenith (TELESCOPE_NAME ``HERA``).
* MWA: pyuvsim's 128-tile (Phase I) layout, East-North-Up offsets about pyuvsim's MWA
  site, tiles of 4 x 4 dipoles 1.1 m apart (DISH_DIAMETER 4.4 m, TELESCOPE_NAME ``MWA``).

Both need ``pip install 'msleak[hera]'`` or ``'msleak[mwa]'`` (docs/telescopes.md).
"""

from __future__ import annotations

import importlib.resources
import importlib.util

import numpy as np

from msleak.errors import InputError
from msleak.telescope.layouts import Layout, enu_to_itrf

__all__ = ["HERA_TELESCOPE_NAME", "MWA_TELESCOPE_NAME", "HERA_DISH_DIAMETER_M",
           "MWA_TILE_SIZE_M", "MWA_SITE", "hera_layout", "mwa_layout", "require"]

HERA_TELESCOPE_NAME = "HERA"
MWA_TELESCOPE_NAME = "MWA"
HERA_DISH_DIAMETER_M = 14.0
#: 4 x 4 dipoles on a 1.1 m pitch
MWA_TILE_SIZE_M = 4.4
#: Geodetic (WGS84) longitude, latitude (deg) and height (m) of pyuvsim's MWA layout
#: (its ``mwa128_config.yaml``)
MWA_SITE = (116.67081523611111, -26.70331940555556, 377.82699999958277)

_EXTRA = {"pyuvdata": "hera", "pyuvsim": "hera", "mwa_hyperbeam": "mwa"}


def require(package: str, what: str, extra: str | None = None) -> None:
    """Raise a one-line InputError if ``package`` is not installed, naming the extra."""
    if importlib.util.find_spec(package) is None:
        extra = extra or _EXTRA.get(package, "hera")
        raise InputError(f"{what} needs the Python package {package}: "
                         f"pip install 'msleak[{extra}]'")


def hera_layout(stations: str | None = None) -> Layout:
    """HERA's 350 antennas (pyuvdata's ``hera_ant_pos.csv`` about its known HERA site),
    selected by ``stations``."""
    require("pyuvdata", "--telescope hera")
    from pyuvdata.telescopes import KNOWN_TELESCOPES  # the site without astropy's registry

    loc = KNOWN_TELESCOPES["HERA"]["location"]
    site = np.array([loc.x.to_value("m"), loc.y.to_value("m"), loc.z.to_value("m")])
    text = importlib.resources.files("pyuvdata").joinpath(
        "data", KNOWN_TELESCOPES["HERA"]["antenna_positions_file"]).read_text()
    rows = [line.split(",") for line in text.splitlines()[1:] if line.strip()]
    rows.sort(key=lambda r: int(r[1]))
    offsets = np.array([[float(v) for v in r[2:5]] for r in rows])   # ECEF about the site
    lay = Layout(names=[r[0] for r in rows], positions=site + offsets,
                 diameters=np.full(len(rows), HERA_DISH_DIAMETER_M),
                 telescope=HERA_TELESCOPE_NAME)
    return lay.select(stations, "HERA")


def mwa_layout(stations: str | None = None) -> Layout:
    """The MWA's 128 tiles (pyuvsim's ``mwa_128T_layout.csv``), selected by ``stations``."""
    require("pyuvsim", "--telescope mwa", "mwa")
    import astropy.units as u
    from astropy.coordinates import EarthLocation

    text = importlib.resources.files("pyuvsim").joinpath("data", "mwa_128T_layout.csv")
    names, enu = [], []
    for line in text.read_text().splitlines()[1:]:
        parts = line.split()
        if len(parts) == 6:
            names.append(parts[0])
            enu.append([float(v) for v in parts[3:6]])
    lon, lat, height = MWA_SITE
    loc = EarthLocation.from_geodetic(lon * u.deg, lat * u.deg, height * u.m)
    site = np.array([loc.x.to_value(u.m), loc.y.to_value(u.m), loc.z.to_value(u.m)])
    lay = Layout(names=names, positions=enu_to_itrf(np.array(enu), site),
                 diameters=np.full(len(names), MWA_TILE_SIZE_M), telescope=MWA_TELESCOPE_NAME)
    return lay.select(stations, "the MWA")
