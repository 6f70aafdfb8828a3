"""makesourcedb text sky models: round trips, a hand-written file, errors with line numbers."""

import math

import numpy as np
import pytest

from msleak.errors import InputError
from msleak.io.angles import format_dec, format_ra, parse_angle
from msleak.adapters.skymodel import read_skymodel, write_skymodel
from msleak.sky import PointSources, make_celestial_wcs, sources_from_cube
from msleak.sky.cube import SkyCube
from msleak.verbs.sky import read_sky

C = 299_792_458.0

HAND = """\
# a sky model written by hand, DP3's second format-line form
# (Name, Type, Patch, Ra, Dec, I, Q, U, V, ReferenceFrequency='150e6', SpectralIndex='[]', RotationMeasure) = format

, , mypatch, 08:13:36.0, +48.13.03.0
a, POINT, mypatch, 08:13:36.0, +48.13.03.0, 10.0, 0.5, -0.2, 0.01, , [-0.7, 0.1]
b, POINT, , 12:00:00, -30.30.00, 2.0, , , , 140e6, []
c, , , 00:00:00.000, +90.00.00.000, 1.0, 0.3, 0.4, 0, , , 6.5
d, POINT, , 187.5deg, -0.5deg, 3.0
"""


def test_hand_written_file(tmp_path):
    p = tmp_path / "hand.skymodel"
    p.write_text(HAND)
    s = read_skymodel(p)
    assert s.names == ("a", "b", "c", "d")
    assert np.allclose(np.degrees(s.ra), [123.4, 180.0, 0.0, 187.5], atol=1e-10)
    assert np.allclose(np.degrees(s.dec), [48 + 13 / 60 + 3 / 3600, -30.5, 90.0, -0.5],
                       atol=1e-10)
    f = np.array([140e6, 150e6, 160e6])
    st = s.at_frequencies(f)
    # a: logarithmic SI on I only (DP3), Q/U/V constant; default ReferenceFrequency 150 MHz
    x = np.log10(f / 150e6)
    assert np.allclose(st[0, :, 0], 10.0 * 10 ** (x * (-0.7 + 0.1 * x)), rtol=1e-12)
    assert np.allclose(st[0, :, 1:], [0.5, -0.2, 0.01])
    # b: empty Q, U, V are zero; I flat
    assert np.allclose(st[1], [[2.0, 0, 0, 0]] * 3)
    # c: RM with Q/U at 150 MHz: P = (Q + iU) exp(2i RM (lambda^2 - lambda0^2)), I flat
    lam2, lam02 = (C / f) ** 2, (C / 150e6) ** 2
    p_exp = (0.3 + 0.4j) * np.exp(2j * 6.5 * (lam2 - lam02))
    assert np.allclose(st[2, :, 1] + 1j * st[2, :, 2], p_exp, rtol=1e-12, atol=1e-14)
    # d: missing trailing fields -> zero Q, U, V
    assert np.allclose(st[3], [[3.0, 0, 0, 0]] * 3)


def test_round_trip_parametric(tmp_path):
    src = PointSources.parametric(
        ra=[0.1, 2.0, 5.9, 0.0], dec=[math.pi / 2, -0.3, 0.7, -1.2],
        i=[1.0, 2.0, -1.5, 4.0], q=[0.1, 0.0, 0.3, 0.0], u=[0.2, 0.0, 0.0, 0.0],
        v=[0.0, 0.01, 0.0, 0.0], ref_freq=[150e6, 140e6, 150e6, 0.0],
        spectral_index=[[-0.7, 0.1], [0, 0], [0.5, 0], [0, 0]],
        rotation_measure=[3.0, np.nan, -7.5, np.nan], names=["s1", "s2", "s3", "s4"])
    path = write_skymodel(tmp_path / "rt.skymodel", src)
    back = read_skymodel(path)
    f = np.linspace(120e6, 190e6, 7)
    assert back.names == src.names
    assert np.allclose(back.at_frequencies(f), src.at_frequencies(f), rtol=1e-9, atol=1e-12)
    assert np.abs(back.ra - src.ra).max() < 1e-9
    assert np.abs(back.dec - src.dec).max() < 1e-9
    with pytest.raises(InputError, match="exists"):
        write_skymodel(path, src)


def test_cube_channel_to_skymodel_and_back(tmp_path):
    rng = np.random.default_rng(5)
    data = rng.normal(size=(2, 3, 4, 4)) * 0.05
    cube = SkyCube(data=data, freq=150e6 + np.arange(3) * 195312.5, stokes=("Q", "U"),
                   wcs=make_celestial_wcs(4, 4, 1.0, 0.0, 90.0), units="Jy/pixel")
    src = sources_from_cube(cube)
    with pytest.raises(InputError, match="choose a channel"):
        write_skymodel(tmp_path / "x.skymodel", src)
    path = write_skymodel(tmp_path / "ch1.skymodel", src, channel=1)
    back = read_sky(path)
    st = back.at_frequencies([cube.freq[1], 170e6])  # flat spectrum
    assert np.allclose(st[:, 0, 1], data[0, 1].ravel(), rtol=1e-9, atol=1e-15)
    assert np.allclose(st[:, 1, 2], data[1, 1].ravel(), rtol=1e-9, atol=1e-15)
    assert np.all(st[:, :, 0] == 0) and np.all(st[:, :, 3] == 0)
    # positions survive: same direction cosines about the NCP
    l1, m1, _ = src.lmn(0.0, math.pi / 2)
    l2, m2, _ = back.lmn(0.0, math.pi / 2)
    assert np.abs(l1 - l2).max() < 1e-9 and np.abs(m1 - m2).max() < 1e-9


def test_angle_formats():
    assert math.isclose(parse_angle("08:13:36.0"), math.radians(123.4), abs_tol=1e-14)
    assert math.isclose(parse_angle("-00.30.00", allow_colon=False), math.radians(-0.5))
    assert math.isclose(parse_angle("12h30m"), math.radians(187.5))
    assert math.isclose(parse_angle("0.25"), 0.25)                # bare number: radians
    assert math.isclose(parse_angle("30arcmin"), math.radians(0.5))
    for ra in (0.0, 1e-12, 2 * math.pi - 1e-12, 3.0):
        assert abs((parse_angle(format_ra(ra)) - ra + math.pi) % (2 * math.pi) - math.pi) < 1e-9
    for dec in (-math.pi / 2, -1e-7, 0.0, 0.8, math.pi / 2):
        assert abs(parse_angle(format_dec(dec), allow_colon=False) - dec) < 1e-9
    assert format_dec(math.radians(-0.5)) == "-00.30.00.00000"
    assert format_ra(math.radians(123.4)) == "08:13:36.000000"


BAD = [
    ("a, POINT, 01:00:00, +10.00.00, 1.0\n", 1, "before any format line"),
    ("format = Name, Type, Ra, Dec, I\n# ok\na, POINT, 01:00:00, 10:00:00, 1\n", 3, "colons"),
    ("format = Name, Type, Ra, Dec, I\na, POINT, 01:00:00, +10.00.00, 1\nb, POINT, "
     "01:00:00, +10.00.00, one\n", 3, "not a number"),
    ("format = Name, Type, Ra, Dec, I\na, GAUSSIAN, 01:00:00, +10.00.00, 1\n", 2,
     "not supported"),
    ("format = Name, Type, Ra, Dec, I, RotationMeasure\na, POINT, 01:00:00, +10.00.00, 1, 3\n",
     2, "RotationMeasure"),
    ("format = Name, Type, Ra, Dec, I\na, POINT, 01:00:00, +95.00.00, 1\n", 2, "outside"),
    ("format = Name, Type, Ra, Dec, I, SpectralIndex\na, POINT, 01:00:00, +1.00.00, 1, "
     "[-0.7\n", 2, "unbalanced"),
]


@pytest.mark.parametrize("text,lineno,match", BAD)
def test_malformed_lines(tmp_path, text, lineno, match):
    p = tmp_path / "bad.skymodel"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as info:
        read_skymodel(p)
    assert f"bad.skymodel:{lineno}:" in str(info.value)
    assert "\n" not in str(info.value)
