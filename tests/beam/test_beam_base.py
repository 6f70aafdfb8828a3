"""The beam interface: the identity model, input checks, the 2x2 inverse."""

from __future__ import annotations

import numpy as np
import pytest

from msleak.adapters.beams import load_beam
from msleak.beam import invert_2x2
from msleak.errors import InputError


def test_none_beam_is_the_identity(small_lofar_ms):
    beam = load_beam("none", small_lofar_ms)
    assert beam.n_stations == 6 and beam.station_names[0] == "CS001HBA0"
    j = beam.jones([4.86234e9, 4.86235e9], [150e6], [0.1, 0.2, 0.3], [0.5, -1.2, 1.5],
                   stations=[1, 4], centre_correction=True, dtype=np.complex64)
    assert j.shape == (2, 2, 1, 3, 2, 2) and j.dtype == np.complex64
    np.testing.assert_array_equal(j, np.broadcast_to(np.eye(2), j.shape))
    assert beam.jones_centre([4.86234e9], [150e6, 151e6]).shape == (6, 1, 2, 2, 2)


@pytest.mark.parametrize("kwargs, message", [
    (dict(stations=[7]), "out of range"),
    (dict(stations=[0.5]), "ANTENNA row numbers"),
    (dict(dtype=np.float64), "must be complex"),
    (dict(dec=[2.0]), "declinations"),
    (dict(freq=[-1.0]), "positive"),
    (dict(ra=[np.nan]), "finite"),
])
def test_bad_arguments(small_lofar_ms, kwargs, message):
    beam = load_beam("none", small_lofar_ms)
    args = dict(time_mjd_s=[4.86234e9], freq_hz=[150e6], ra=[0.1], dec=[0.5])
    for key, value in kwargs.items():
        args[{"freq": "freq_hz"}.get(key, key)] = value
    with pytest.raises(InputError, match=message):
        beam.jones(**args)


def test_none_beam_takes_no_options(small_lofar_ms):
    with pytest.raises(InputError, match="takes no option"):
        load_beam("none", small_lofar_ms, factor="airy")


def test_invert_2x2():
    rng = np.random.default_rng(3)
    j = rng.normal(size=(5, 2, 2)) + 1j * rng.normal(size=(5, 2, 2))
    j[2] = 0
    j[3] = [[1, 2], [2, 4]]
    inv, singular = invert_2x2(j)
    np.testing.assert_array_equal(singular, [False, False, True, True, False])
    np.testing.assert_allclose(inv[[0, 1, 4]], np.linalg.inv(j[[0, 1, 4]]), rtol=1e-12)
    assert np.all(inv[[2, 3]] == 0)
