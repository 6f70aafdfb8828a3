"""Predict kernels on arrays, against direct sums written here (no MS, no files)."""

from __future__ import annotations

import numpy as np
import pytest

from msleak.beam.base import JonesFactors
from msleak.conventions import stokes_to_correlations_matrix
from msleak.predict import kernels as K
from msleak.predict.chunks import plan_chunks
from msleak.predict.components import prepare_sources
from msleak.predict.stations import station_coordinates

C = 299_792_458.0


def _brightness(iquv):
    i, q, u, v = iquv
    return np.array([[i + q, u + 1j * v], [u - 1j * v, i - q]])


def _direct(jones, left, xyz, lmn1, freq, iquv):
    """V[t, c, 2p:2p+2, 2q:2q+2] by the textbook sum over sources (MS sign convention:
    uvw_pq = x_q - x_p, phase exp(+2 pi i uvw . (l, m, n-1) / lambda))."""
    nt, nst = xyz.shape[:2]
    nd = lmn1.shape[0]
    out = np.zeros((nt, freq.size, 2 * nst, 2 * nst), complex)
    for t in range(nt):
        for c in range(freq.size):
            for p in range(nst):
                for q in range(nst):
                    uvw = xyz[t, q] - xyz[t, p]
                    acc = np.zeros((2, 2), complex)
                    for s in range(nd):
                        jp = jones[p, t, c, s] if jones is not None else np.eye(2)
                        jq = jones[q, t, c, s] if jones is not None else np.eye(2)
                        if left is not None:
                            jp = left[p, t, c] @ jp
                            jq = left[q, t, c] @ jq
                        ph = np.exp(2j * np.pi * freq[c] / C * (uvw @ lmn1[s]))
                        acc += jp @ _brightness(iquv[s, c]) @ jq.conj().T * ph
                    out[t, c, 2 * p:2 * p + 2, 2 * q:2 * q + 2] = acc
    return out


def _setup(rng, nst=4, nt=2, nch=3, nd=5, freq=None):
    xyz = rng.normal(0, 400, (nt, nst, 3))
    ra = 1.0 + rng.uniform(-0.08, 0.08, nd)
    dec = 0.8 + rng.uniform(-0.08, 0.08, nd)
    lmn1 = K.lmn_minus_one(ra, dec, 1.0, 0.8)
    if freq is None:
        freq = 150e6 + 195312.5 * np.arange(nch)
    iquv = rng.normal(size=(nd, freq.size, 4))
    jones = rng.normal(size=(nst, nt, freq.size, nd, 2, 2)) + 1j * rng.normal(
        size=(nst, nt, freq.size, nd, 2, 2))
    return xyz, lmn1, freq, iquv, jones


@pytest.mark.parametrize("dtype,rtol", [(np.complex128, 1e-10), (np.complex64, 2e-5)])
def test_gram_matches_direct_sum(dtype, rtol):
    rng = np.random.default_rng(1)
    xyz, lmn1, freq, iquv, jones = _setup(rng)
    w, sign = K.brightness_factors(iquv)
    v = K.gram_to_matrix(K.predict_gram(jones, xyz, lmn1, freq, w, sign, dtype=dtype))
    ref = _direct(jones, None, xyz, lmn1, freq, iquv)
    assert v.dtype == dtype
    assert np.abs(v - ref).max() <= rtol * np.abs(ref).max()


@pytest.mark.parametrize("dtype,rtol", [(np.complex128, 1e-10), (np.complex64, 2e-5)])
def test_factored_jones_match_direct_sum_of_their_product(dtype, rtol):
    """J_p = S_p E_g(p) with two element groups and a broadcast time axis of E."""
    rng = np.random.default_rng(11)
    xyz, lmn1, freq, iquv, _ = _setup(rng)
    scalar = rng.normal(size=(4, 2, 3, 5)) + 1j * rng.normal(size=(4, 2, 3, 5))
    element = rng.normal(size=(2, 1, 3, 5, 2, 2)) + 1j * rng.normal(size=(2, 1, 3, 5, 2, 2))
    factors = JonesFactors(scalar.astype(dtype), element.astype(dtype), np.array([0, 1, 1, 0]))
    w, sign = K.brightness_factors(iquv)
    v = K.gram_to_matrix(K.predict_gram(factors, xyz, lmn1, freq, w, sign, dtype=dtype))
    product = scalar[..., None, None] * element[[0, 1, 1, 0]]
    ref = _direct(product, None, xyz, lmn1, freq, iquv)
    assert np.abs(v - ref).max() <= rtol * np.abs(ref).max()
    np.testing.assert_array_equal(factors.full(),
                                  factors.scalar[..., None, None] * factors.element[[0, 1, 1, 0]])


def test_left_correction_irregular_channels_and_broadcast_beam():
    rng = np.random.default_rng(2)
    freq = np.array([120e6, 121.3e6, 125e6, 140.7e6])  # uneven: per-channel phases
    xyz, lmn1, freq, iquv, jones = _setup(rng, freq=freq)
    jones = jones[:1]  # one beam for all stations (broadcast)
    left = rng.normal(size=(4, 2, 4, 2, 2)) + 1j * rng.normal(size=(4, 2, 4, 2, 2))
    w, sign = K.brightness_factors(iquv)
    gram = K.predict_gram(jones, xyz, lmn1, freq, w, sign, dtype=np.complex128)
    tidx, p, q = (a.ravel() for a in np.meshgrid(np.arange(2), np.arange(4), np.arange(4),
                                                 indexing="ij"))
    rows = K.gather_rows(gram, tidx, p, q, jones_left=left)
    ref = _direct(np.repeat(jones, 4, axis=0), left, xyz, lmn1, freq, iquv)
    ref_rows = np.stack([ref[t, :, 2 * a:2 * a + 2, 2 * b:2 * b + 2].reshape(-1, 4)
                         for t, a, b in zip(tidx, p, q)])
    assert np.abs(rows - ref_rows).max() <= 1e-10 * np.abs(ref).max()


def _bad_jones(case, nst=4, nt=2, nch=3, nd=5):
    """A beam argument for a 4-station, 2-time, 3-channel, 5-direction call, wrong in one
    way; the message predict_gram must give."""
    z = np.zeros
    ok_scalar, ok_element = z((nst, nt, nch, nd), complex), z((2, nt, nch, nd, 2, 2), complex)
    group = np.array([0, 1, 1, 0])
    return {
        "full: 5 axes": (z((nst, nt, nch, nd, 4), complex), r"jones has shape"),
        "full: not 2x2": (z((nst, nt, nch, nd, 2, 3), complex), r"jones has shape"),
        "full: directions": (z((nst, nt, nch, nd + 1, 2, 2), complex), r"jones has shape"),
        "full: stations": (z((3, nt, nch, nd, 2, 2), complex),
                           r"jones axis 0 has length 3, expected 1 or 4"),
        "full: channels": (z((nst, nt, 2, nd, 2, 2), complex),
                           r"jones axis 2 has length 2, expected 1 or 3"),
        "scalar: directions": (JonesFactors(z((nst, nt, nch, 4), complex), ok_element, group),
                               r"jones.scalar has shape"),
        "scalar: times": (JonesFactors(z((nst, 3, nch, nd), complex), ok_element, group),
                          r"jones.scalar axis 1 has length 3, expected 1 or 2"),
        "element: not 2x2": (JonesFactors(ok_scalar, z((2, nt, nch, nd, 2), complex), group),
                             r"jones.element has shape"),
        "element: channels": (JonesFactors(ok_scalar, z((2, nt, 4, nd, 2, 2), complex), group),
                              r"jones.element axis 2 has length 4, expected 1 or 3"),
        "group: length": (JonesFactors(ok_scalar, ok_element, np.array([0, 1, 1])),
                          r"jones.group must be 4 indices into jones.element's 2 groups"),
        "group: range": (JonesFactors(ok_scalar, ok_element, np.array([0, 1, 2, 0])),
                         r"jones.group must be 4 indices"),
        "group: negative": (JonesFactors(ok_scalar, ok_element, np.array([0, -1, 1, 0])),
                            r"jones.group must be 4 indices"),
    }[case]


@pytest.mark.parametrize("case", ["full: 5 axes", "full: not 2x2", "full: directions",
                                  "full: stations", "full: channels", "scalar: directions",
                                  "scalar: times", "element: not 2x2", "element: channels",
                                  "group: length", "group: range", "group: negative"])
def test_a_beam_of_the_wrong_shape_is_refused_by_name(case):
    """Each malformed beam argument (full Jones or factors) raises a ValueError naming the
    array, the axis and the length expected, before the kernel runs."""
    rng = np.random.default_rng(5)
    xyz, lmn1, freq, iquv, _ = _setup(rng)
    w, sign = K.brightness_factors(iquv)
    jones, message = _bad_jones(case)
    with pytest.raises(ValueError, match=message):
        K.predict_gram(jones, xyz, lmn1, freq, w, sign, dtype=np.complex128)


def test_no_beam_point_source_at_centre():
    """Identity beam, 1 Jy Q at the phase centre: XX = 1, YY = -1, XY = YX = 0."""
    rng = np.random.default_rng(3)
    xyz = rng.normal(0, 1000, (2, 5, 3))
    iquv = np.zeros((1, 3, 4))
    iquv[0, :, 1] = 1.0
    w, sign = K.brightness_factors(iquv)
    gram = K.predict_gram(None, xyz, np.zeros((1, 3)), np.array([1e8, 1.5e8, 2e8]), w, sign)
    tidx, p, q = np.meshgrid(np.arange(2), np.arange(5), np.arange(5), indexing="ij")
    vis = K.gather_rows(gram, tidx.ravel(), p.ravel(), q.ravel())
    np.testing.assert_allclose(vis, np.broadcast_to([1, 0, 0, -1], vis.shape), atol=1e-6)


def test_brightness_factors_reconstruct_and_drop_zeros():
    rng = np.random.default_rng(4)
    iquv = rng.normal(size=(6, 3, 4))
    iquv[0, 0] = 0.0                     # no flux: both columns dropped
    iquv[1, 0] = [2.0, 1.2, 1.6, 0.0]    # fully polarized: one zero eigenvalue
    w, sign = K.brightness_factors(iquv)
    b = np.einsum("dcik,dck,dcjk->dcij", w, sign.astype(float), w.conj())
    ref = np.stack([[_brightness(iquv[d, c]) for c in range(3)] for d in range(6)])
    np.testing.assert_allclose(b, ref, atol=1e-12)
    assert (sign[0, 0] == 0).all()
    assert sorted(sign[1, 0]) == [0, 1]


def test_gather_rows_any_order_and_autocorrelations():
    rng = np.random.default_rng(5)
    xyz, lmn1, freq, iquv, jones = _setup(rng)
    w, sign = K.brightness_factors(iquv)
    gram = K.predict_gram(jones, xyz, lmn1, freq, w, sign, dtype=np.complex128)
    v = K.gram_to_matrix(gram)
    tidx = np.array([1, 0, 1, 0, 1])
    p = np.array([3, 0, 2, 2, 1])
    q = np.array([0, 0, 2, 3, 3])  # p > q, autos, p < q
    rows = K.gather_rows(gram, tidx, p, q)
    for r in range(5):
        block = v[tidx[r], :, 2 * p[r]:2 * p[r] + 2, 2 * q[r]:2 * q[r] + 2]
        np.testing.assert_allclose(rows[r], block.reshape(-1, 4), atol=1e-12)
    # Hermitian: V_qp = V_pq^H
    np.testing.assert_allclose(v, np.conj(np.swapaxes(v, -1, -2)), atol=1e-9)


def test_linear_to_circular_matches_conventions():
    s_lin = stokes_to_correlations_matrix("linear")
    s_circ = stokes_to_correlations_matrix("circular")
    np.testing.assert_allclose(K.LINEAR_TO_CIRCULAR @ s_lin, s_circ, atol=1e-15)


def test_lmn_minus_one_small_offsets_exact():
    ra0, dec0 = 2.0, -0.5
    ra = ra0 + np.array([0.0, 1e-9, 0.1, 0.0])
    dec = dec0 + np.array([0.0, 0.0, 0.05, 1e-9])
    lmn1 = K.lmn_minus_one(ra, dec, ra0, dec0)
    l, m = lmn1[:, 0], lmn1[:, 1]
    # n - 1 = sqrt(1 - l^2 - m^2) - 1, evaluated with the series for tiny offsets
    r2 = l**2 + m**2
    expect = np.where(r2 < 1e-12, -r2 / 2, np.sqrt(1 - r2) - 1)
    np.testing.assert_allclose(lmn1[:, 2], expect, rtol=1e-9, atol=1e-30)
    assert lmn1[0].tolist() == [0.0, 0.0, 0.0]


def test_station_coordinates_fit_and_report_inconsistent_uvw():
    rng = np.random.default_rng(6)
    x = rng.normal(0, 500, (2, 5, 3))
    t, p, q = np.meshgrid(np.arange(2), np.arange(5), np.arange(5), indexing="ij")
    t, p, q = t.ravel(), p.ravel(), q.ravel()
    keep = p <= q
    t, p, q = t[keep], p[keep], q[keep]
    uvw = x[t, q] - x[t, p]
    fit, off = station_coordinates(t, p, q, uvw, 2, 5, tolerance_m=1e-4)
    np.testing.assert_allclose(fit[t, q] - fit[t, p], uvw, atol=1e-8)
    assert not off.any()
    # one cross-correlation 0.5 m off: only that row is reported, the others still fit
    bad = uvw.copy()
    row = int(np.flatnonzero(p != q)[3])
    bad[row] += 0.5
    fit, off = station_coordinates(t, p, q, bad, 2, 5, tolerance_m=1e-4)
    assert np.flatnonzero(off).tolist() == [row]
    np.testing.assert_allclose((fit[t, q] - fit[t, p])[~off], uvw[~off], atol=1e-8)


def test_station_coordinates_disconnected_groups():
    # baselines 0-1 and 2-3 only: two independent groups, both reproduced
    t = np.zeros(2, int)
    p = np.array([0, 2])
    q = np.array([1, 3])
    uvw = np.array([[10.0, 0, 0], [0, 5.0, 1.0]])
    fit, off = station_coordinates(t, p, q, uvw, 1, 4, tolerance_m=1e-4)
    np.testing.assert_allclose(fit[0, q] - fit[0, p], uvw, atol=1e-12)
    assert not off.any()


def test_prepare_sources_merges_duplicates_and_drops_empty_or_far():
    ra = np.array([1.0, 1.0, 1.1, 1.0 + np.pi])
    dec = np.array([0.5, 0.5, 0.5, -0.5])
    iquv = np.zeros((4, 2, 4))
    iquv[0, :, 1] = 1.0
    iquv[1, :, 1] = 2.0      # same direction as source 0: Q adds to 3
    iquv[3, :, 1] = 1.0      # antipode of the phase centre: dropped
    comp = prepare_sources(ra, dec, iquv, 1.0, 0.5)
    assert comp.ndir == 1    # source 2 has no flux
    np.testing.assert_allclose(comp.iquv[0, :, 1], 3.0)


def test_plan_chunks_respects_budget():
    nt, nc = plan_chunks(390, 50, 48, 2500, 1176, 2 * 1024**3, 8, True)
    per = (96**2 * 8 + 1176 * 4 * 24 + 48 * 2501 * 4 * 40)
    assert nt * nc * per <= 2 * 1024**3
    assert nc == 50 or nt == 1
    assert plan_chunks(4, 4, 6, 3, 15, 1.0, 8, False) == (1, 1)


def test_plan_chunks_are_balanced_and_shared_among_tasks():
    """All channels: as many times as fit, at least one chunk per task while there are
    times enough, each ceil(ntime / n) times for the fewest n chunks that fit."""
    per = 96**2 * 8 + 1176 * 4 * 24 + 48 * 2501 * 4 * 40       # per (time, channel)
    fit = 29 * 50 * per                                        # 29 times fit
    assert plan_chunks(30, 50, 48, 2500, 1176, fit, 8, True) == (15, 50)
    assert plan_chunks(30, 50, 48, 2500, 1176, fit, 8, True, tasks=4) == (8, 50)
    assert plan_chunks(30, 50, 48, 2500, 1176, 100 * fit, 8, True) == (30, 50)
    assert plan_chunks(30, 50, 48, 2500, 1176, 100 * fit, 8, True, tasks=2) == (15, 50)
    assert plan_chunks(1, 50, 48, 2500, 1176, 100 * fit, 8, True, tasks=2) == (1, 50)
    for ntime in range(1, 40):
        for most in (1, 7, 29):
            nt, _ = plan_chunks(ntime, 50, 48, 2500, 1176, most * 50 * per, 8, True, tasks=2)
            nchunk = -(-ntime // nt)
            fewest = max(-(-ntime // most), min(2, ntime))
            assert nt <= most and nt == -(-ntime // fewest) and nchunk >= min(2, ntime)


def test_plan_chunks_keep_every_channel_for_an_all_sky_sky(caplog):
    """An all-sky sky's chunks keep every channel: times are cut first, and a budget too
    small for one time of every channel still gives (1, nchan), with a warning."""
    per = 96**2 * 8 + 1176 * 4 * 24 + 48 * 1 * 4 * 40
    assert plan_chunks(30, 50, 48, 0, 1176, 120 * per, 8, True, whole_channels=True) == (2, 50)
    with caplog.at_level("WARNING"):
        assert plan_chunks(30, 50, 48, 0, 1176, 10 * per, 8, True,
                           whole_channels=True) == (1, 50)
    assert "too small for one time slot of every channel" in caplog.text
    assert plan_chunks(30, 50, 48, 0, 1176, 10 * per, 8, True) == (1, 10)


def test_plan_chunks_long_times_for_degridding():
    """A degridded sky: all times (or ntime / tasks) when LONG_CHANNELS channels fit with
    them, else fewer times with LONG_CHANNELS channels; always within the budget."""
    from msleak.predict.chunks import LONG_CHANNELS

    per = (96**2 * 8 + 1176 * 4 * 24 + 48 * 1601 * 4 * 40 + 48 * 900 * 80)  # per (t, c)
    for tasks, most in ((1, 390), (2, 195), (4, 98)):
        for budget in (64 * 1024**3, 2 * 1024**3, 200 * 1024**2, per * 3):
            nt, nc = plan_chunks(390, 50, 48, 1600, 1176, budget, 8, True, long_times=True,
                                 subgrid_dirs=900, tasks=tasks)
            assert nt * nc * per <= budget
            if budget >= most * LONG_CHANNELS * per:
                assert nt == most and nc == min(50, budget // per // most)
            elif budget >= LONG_CHANNELS * per:
                assert (nt, nc) == (budget // per // LONG_CHANNELS, LONG_CHANNELS)
            else:
                assert (nt, nc) == (1, 3)
