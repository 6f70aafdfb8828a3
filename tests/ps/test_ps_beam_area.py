"""Omega from the MS's beam model (ms_beam_area) against answers known in advance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from msleak.ps.beam_area import beam_area_from_power
from msleak.ps.gridding import beam_area_model, gridder_response, response_profile
from msleak.verbs.grid_tasks import ms_beam_area
import msleak


def test_flat_beam_gives_the_integral_of_the_response():
    """A = 1: Omega = int R^2 dl dm / n; small field, so n ~ 1 and the 2D integral
    separates into (int r(x)^2 dx / cell)^2 of the 1D profile."""
    cell = 16.0
    l = np.linspace(-0.25, 0.25, 2001)
    ll, mm = np.meshgrid(l, l)
    got = beam_area_from_power(np.ones_like(ll), gridder_response("wgrid", ll, mm, cell),
                               l, l)
    one_d, _ = integrate.quad(lambda x: response_profile("wgrid", np.array(x)) ** 2, -4, 4,
                              limit=200)
    assert got == pytest.approx((one_d / cell) ** 2, rel=2e-3)


def test_everybeam_area_close_to_a_station_sized_airy_disc(small_lofar_ms):
    """The LOFAR HBA field (30.75 m, 15.4 wavelengths at 150 MHz) is close to the Airy disc
    of a 16-wavelength aperture: Omega within 25 % of that model, and a little larger (the
    station is a little smaller than the cell)."""
    airy = beam_area_model("wgrid", 16.0)
    omega, how = ms_beam_area(small_lofar_ms, model="everybeam", gridder="wgrid",
                              cell=16.0)
    assert "everybeam" in how
    assert airy < omega < 1.25 * airy


def test_grid_records_the_ms_beam_area(small_lofar_ms):
    auto = msleak.grid(small_lofar_ms, column="DATA", beam_area_model="auto",
                   uv_range=(10.0, 180.0))
    airy = msleak.grid(small_lofar_ms, column="DATA", beam_area_model="airy",
                   uv_range=(10.0, 180.0))
    given = msleak.grid(small_lofar_ms, column="DATA", beam_area=1e-3, uv_range=(10.0, 180.0))
    assert "everybeam" in auto.attrs["beam_area_source"]
    assert airy.attrs["beam_area_sr"] == pytest.approx(beam_area_model("wgrid", 16.0))
    assert auto.attrs["beam_area_sr"] != pytest.approx(airy.attrs["beam_area_sr"], rel=1e-3)
    assert given.attrs["beam_area_sr"] == 1e-3 and given.attrs["beam_area_source"] == "given"
