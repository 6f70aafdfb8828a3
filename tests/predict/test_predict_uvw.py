"""predict on UVW that are not exactly antenna-based.

* float32-rounded UVW (an MS converted from uvfits, tests/casa_ms.py ``uvw_float32``):
  within the phase tolerance of docs/predict.md the per-station factorisation is used for
  every row, and the result equals a direct DFT on the MS's own UVW within that phase
  error;
* UVW of some rows moved by centimetres: those rows (and only those) are predicted per
  baseline from their own UVW, equal to the direct DFT to 1e-6 of the peak (``--double``),
  also through a beam with the phase-centre correction;
* the per-baseline kernel against a direct sum written here.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from casa_ms import build_ms
from ms_helpers import C, channel_freqs, direct_dft, phase_centre, table, write_sky
from msleak.verbs import predict as engine
from msleak.predict.baselines import predict_rows
from msleak.predict.stations import PHASE_TOLERANCE_RAD, station_coordinates

#: baselines up to 5 km: float32 rounding of their UVW reaches 0.1-0.2 mm
WIDE_ENU = np.array([[0.0, 0.0, 0.0], [1500.0, 200.0, 1.0], [-900.0, 2600.0, -2.0],
                     [2800.0, -1900.0, 3.0], [-2300.0, -1200.0, 0.0]])
#: phase centre near transit at the MWA site at the casa_ms times (dipole beam sees it)
FIELD = dict(ra_deg=253.0, dec_deg=0.0)


def _offset_sources(ms, offsets_deg, fluxes):
    """(ra, dec, I, Q, U, V) of sources at (dl, dm) degrees from the phase centre."""
    ra0, dec0 = phase_centre(ms)
    out = []
    for (dl, dm), iquv in zip(np.radians(offsets_deg), fluxes):
        n = np.sqrt(1 - dl * dl - dm * dm)
        dec = np.arcsin(dm * np.cos(dec0) + n * np.sin(dec0))
        ra = ra0 + np.arctan2(dl, n * np.cos(dec0) - dm * np.sin(dec0))
        out.append((float(ra), float(dec), *iquv))
    return out


def _rows(ms):
    with table(ms) as t:
        return (t.getcol("TIME"), t.getcol("ANTENNA1"), t.getcol("ANTENNA2"), t.getcol("UVW"),
                t.getcol("MODEL_DATA") if "MODEL_DATA" in t.colnames() else None)


def test_float32_uvw_take_the_fast_path_within_the_phase_tolerance(tmp_path):
    ms = build_ms(tmp_path / "f32.ms", enu=WIDE_ENU, uvw_float32=True, ntime=3, **FIELD)
    twin = build_ms(tmp_path / "f64.ms", enu=WIDE_ENU, ntime=3, **FIELD)
    time, a1, a2, uvw, _ = _rows(ms)
    uvw64 = _rows(twin)[3]
    assert np.abs(uvw - uvw64).max() > 1e-4          # rounded by more than 0.1 mm ...
    # ... so that the former check (largest component of the least-squares residual
    # <= 0.1 mm, no per-baseline path) refused this MS
    tidx = np.searchsorted(np.unique(time), time)
    xyz, _ = station_coordinates(tidx, a1, a2, uvw, 3, 5, tolerance_m=np.inf)
    assert np.abs(xyz[tidx, a2] - xyz[tidx, a1] - uvw).max() > 1e-4

    sources = _offset_sources(ms, [(5.0, 3.0), (-12.0, 8.0), (20.0, -25.0)],
                              [(1.0, 0.4, -0.3, 0.0), (2.0, 0.1, 0.6, 0.0),
                               (1.5, -0.5, 0.2, 0.1)])
    sky = write_sky(tmp_path / "sky.skymodel", sources)
    res = engine.predict(ms, sky, beam="none", double=True)
    assert res.rows_per_baseline == 0
    expected = direct_dft(ms, sources)
    model = _rows(ms)[4]
    # a phase error <= PHASE_TOLERANCE_RAD per source moves each correlation by at most
    # that fraction of the sum of the sources' |brightness| (plus complex64 storage)
    b = np.array([[abs(i + q), abs(u + 1j * v), abs(u - 1j * v), abs(i - q)]
                  for _, _, i, q, u, v in sources]).sum(axis=0)
    bound = PHASE_TOLERANCE_RAD * b + 1e-6 * np.abs(expected).max()
    assert np.all(np.abs(model - expected) <= bound)


def _perturb(ms, rows, seed=4):
    """Move the UVW of ``rows`` by 2-5 cm in random directions; returns the shifts."""
    rng = np.random.default_rng(seed)
    shift = rng.normal(size=(len(rows), 3))
    shift *= rng.uniform(0.02, 0.05, (len(rows), 1)) / np.linalg.norm(shift, axis=1)[:, None]
    with table(ms, readonly=False) as t:
        uvw = t.getcol("UVW")
        uvw[rows] += shift
        t.putcol("UVW", uvw)
    return shift


#: rows of the default casa_ms layout (10 baselines per time) whose UVW are moved:
#: two in time 1, one in times 0 and 3
MOVED = [3, 17, 18, 35]


def test_rows_not_antenna_based_are_predicted_per_baseline_exactly(tmp_path):
    ms = build_ms(tmp_path / "moved.ms", ntime=4, **FIELD)
    original = tmp_path / "original.ms"
    shutil.copytree(ms, original)
    _perturb(ms, MOVED)
    sources = _offset_sources(ms, [(0.0, 0.0), (8.0, -6.0), (-15.0, 10.0)],
                              [(1.0, 0.4, -0.3, 0.05), (2.0, -0.6, 0.8, 0.0),
                               (1.0, 0.2, 0.1, 0.0)])
    sky = write_sky(tmp_path / "sky.skymodel", sources)
    res = engine.predict(ms, sky, beam="none", double=True, memory_limit=4096)
    assert res.rows_per_baseline == len(MOVED)
    expected = direct_dft(ms, sources)
    model = _rows(ms)[4]
    peak = np.abs(expected).max()
    np.testing.assert_allclose(model, expected, rtol=0, atol=1e-6 * peak)
    # the moved rows really differ from the antenna-based prediction
    unmoved = direct_dft(original, sources)
    assert np.abs(expected[MOVED] - unmoved[MOVED]).max() > 1e-3 * peak


def test_per_baseline_rows_through_a_beam_with_centre_correction(tmp_path):
    """One source: a row's visibility with UVW + d equals the antenna-based one times
    exp(2 pi i d . (l, m, n - 1) nu / c), whatever the (per-station) beam."""
    ms = build_ms(tmp_path / "moved.ms", ntime=4, **FIELD)
    original = tmp_path / "original.ms"
    shutil.copytree(ms, original)
    shift = _perturb(ms, MOVED)
    (source,) = _offset_sources(ms, [(12.0, 9.0)], [(1.0, 0.5, -0.4, 0.1)])
    sky = write_sky(tmp_path / "sky.skymodel", [source])
    for path in (ms, original):
        engine.predict(path, sky, beam="dipole", double=True)
    moved, unmoved = _rows(ms)[4], _rows(original)[4]
    ra0, dec0 = phase_centre(ms)
    ra, dec = source[:2]
    lmn1 = np.array([np.cos(dec) * np.sin(ra - ra0),
                     np.sin(dec) * np.cos(dec0) - np.cos(dec) * np.sin(dec0) * np.cos(ra - ra0),
                     np.sin(dec) * np.sin(dec0) + np.cos(dec) * np.cos(dec0) * np.cos(ra - ra0)
                     - 1.0])
    phase = np.exp(2j * np.pi * (shift @ lmn1)[:, None] * channel_freqs(ms)[None, :] / C)
    expected = unmoved.copy()
    expected[MOVED] *= phase[:, :, None]
    peak = np.abs(unmoved).max()
    assert peak > 0.1
    np.testing.assert_allclose(moved, expected, rtol=0, atol=1e-6 * peak)
    assert np.abs(moved[MOVED] - unmoved[MOVED]).max() > 1e-3 * peak


@pytest.mark.parametrize("regular", [True, False])
def test_predict_rows_equals_direct_sum(regular):
    rng = np.random.default_rng(7)
    nst, nt, ndir, nrow = 4, 2, 3, 7
    freq = (150e6 + 195312.5 * np.arange(5) if regular
            else np.array([150e6, 150.3e6, 151.1e6, 151.2e6, 153e6]))
    jones = (rng.normal(size=(nst, nt, freq.size, ndir, 2, 2))
             + 1j * rng.normal(size=(nst, nt, freq.size, ndir, 2, 2)))
    left = (rng.normal(size=(nst, nt, freq.size, 2, 2))
            + 1j * rng.normal(size=(nst, nt, freq.size, 2, 2)))
    iquv = rng.normal(size=(ndir, freq.size, 4))
    lmn1 = np.column_stack([rng.uniform(-0.2, 0.2, (ndir, 2)), -rng.uniform(0, 0.03, ndir)])
    tidx = rng.integers(0, nt, nrow)
    p = rng.integers(0, nst, nrow)
    q = rng.integers(0, nst, nrow)
    q[0] = p[0]                                         # an autocorrelation
    uvw = rng.normal(0, 300, (nrow, 3))
    got = predict_rows(jones, tidx, p, q, uvw, lmn1, freq, iquv, jones_left=left,
                       dtype=np.complex128)
    i, qq, u, v = (iquv[..., k] for k in range(4))
    bright = np.stack([np.stack([i + qq, u + 1j * v], -1),
                       np.stack([u - 1j * v, i - qq], -1)], -2)    # (ndir, nchan, 2, 2)
    for r in range(nrow):
        ph = np.exp(2j * np.pi * (lmn1 @ uvw[r])[:, None] * freq[None, :] / C)  # (ndir, nchan)
        jp, jq = jones[p[r], tidx[r]], jones[q[r], tidx[r]]                       # (nchan, ndir, 2, 2)
        vis = np.einsum("sc,csab,scbd,csed->cae", ph, jp, bright, jq.conj())
        vis = np.einsum("cab,cbd,ced->cae", left[p[r], tidx[r]], vis,
                        left[q[r], tidx[r]].conj())
        np.testing.assert_allclose(got[r], vis.reshape(freq.size, 4), rtol=0,
                                   atol=1e-10 * np.abs(vis).max())
    plain = predict_rows(None, tidx, p, q, uvw, lmn1, freq, iquv, dtype=np.complex128)
    ph = np.exp(2j * np.pi * (uvw @ lmn1.T)[:, :, None] * freq[None, None, :] / C)
    np.testing.assert_allclose(plain, np.einsum("rsc,scab->rcab", ph, bright).reshape(
        nrow, freq.size, 4), rtol=0, atol=1e-10 * np.abs(bright).sum(axis=0).max())
