"""Mueller matrices from Jones matrices: identities and cases derived by hand."""

from __future__ import annotations

import numpy as np
import pytest

from msleak.beam import jones_to_mueller, leakage, polarized_beam, to_db
from msleak.beam.mueller import polarized_beam_invariant
from msleak.conventions import correlations_to_stokes, stokes_to_correlations_matrix

RNG = np.random.default_rng(42)


def _random_jones(*shape):
    return RNG.normal(size=shape + (2, 2)) + 1j * RNG.normal(size=shape + (2, 2))


def _brightness(iquv):
    i, q, u, v = iquv
    return np.array([[i + q, u + 1j * v], [u - 1j * v, i - q]])


def test_identity_jones_gives_identity_mueller():
    m = jones_to_mueller(np.eye(2, dtype=complex))
    np.testing.assert_allclose(m, np.eye(4), atol=1e-15)
    assert leakage(m) == 0
    assert polarized_beam(m) == pytest.approx(np.sqrt(2))


def test_ideal_circular_feeds_give_identity():
    # R, L from the (North, East) field: the matrix that makes the circular correlations of
    # msleak.conventions (RR = I + V, RL = Q + iU) out of the linear sky brightness
    c = np.array([[1, 1j], [1, -1j]]) / np.sqrt(2)
    iquv = np.array([1.0, 0.2, -0.3, 0.1])
    corr = (c @ _brightness(iquv) @ c.conj().T).reshape(4)
    np.testing.assert_allclose(correlations_to_stokes(corr, "circular"), iquv, atol=1e-14)
    np.testing.assert_allclose(jones_to_mueller(c, feed="circular"), np.eye(4), atol=1e-15)


@pytest.mark.parametrize("feed", ["linear", "circular"])
def test_mueller_reproduces_the_measurement_equation(feed):
    """M @ (I,Q,U,V) equals the Stokes of J_p B J_q^H computed with 2x2 matrices."""
    jp, jq = _random_jones(5), _random_jones(5)
    iquv = RNG.normal(size=(5, 4))
    m = jones_to_mueller(jp, jq, feed=feed)
    for k in range(5):
        corr = (jp[k] @ _brightness(iquv[k]) @ jq[k].conj().T).reshape(4)
        expected = np.linalg.solve(stokes_to_correlations_matrix(feed), corr)
        np.testing.assert_allclose(m[k] @ iquv[k], expected, rtol=1e-12, atol=1e-12)


def test_auto_correlation_mueller_is_real():
    j = _random_jones(10)
    assert np.abs(jones_to_mueller(j).imag).max() < 1e-13


@pytest.mark.parametrize("angle_deg", [0.0, 10.0, 30.0, 45.0, 100.0])
def test_feed_rotation_mixes_q_and_u_by_twice_the_angle(angle_deg):
    # feeds rotated by a from (North, East): X = cos a N + sin a E, Y = -sin a N + cos a E;
    # XX = I + Q cos 2a + U sin 2a, YY = I - Q cos 2a - U sin 2a, so
    # Q' = Q cos 2a + U sin 2a, U' = -Q sin 2a + U cos 2a, I' = I, V' = V.
    a = np.radians(angle_deg)
    j = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]], dtype=complex)
    c2, s2 = np.cos(2 * a), np.sin(2 * a)
    expected = np.array([[1, 0, 0, 0], [0, c2, s2, 0], [0, -s2, c2, 0], [0, 0, 0, 1]])
    m = jones_to_mueller(j)
    np.testing.assert_allclose(m, expected, atol=1e-14)
    assert leakage(m) == pytest.approx(0, abs=1e-14)
    assert polarized_beam_invariant(m) == pytest.approx(np.sqrt(2))


@pytest.mark.parametrize("g", [0.5, 0.9, 1.1, 2.0])
def test_gain_imbalance_leaks_q_into_i(g):
    # J = diag(g, 1): XX = g^2 (I + Q), YY = I - Q, so
    # I' = (g^2 + 1)/2 I + (g^2 - 1)/2 Q and Q' = (g^2 - 1)/2 I + (g^2 + 1)/2 Q.
    m = jones_to_mueller(np.diag([g, 1.0]).astype(complex))
    assert m[0, 1] == pytest.approx((g ** 2 - 1) / 2, abs=1e-14)
    assert m[1, 0] == pytest.approx((g ** 2 - 1) / 2, abs=1e-14)
    assert m[0, 0] == pytest.approx((g ** 2 + 1) / 2, abs=1e-14)
    assert m[0, 2] == pytest.approx(0, abs=1e-14)
    assert leakage(m) == pytest.approx(abs(g ** 2 - 1) / (g ** 2 + 1), rel=1e-13)


def test_db_and_floor():
    np.testing.assert_allclose(to_db(np.array([1.0, 0.1, 0.5]), 1.0), [0.0, -10.0,
                                                                     10 * np.log10(0.5)])
    assert to_db(np.array([0.0]))[0] == -100.0
    assert np.isnan(to_db(np.array([np.nan]))[0])
    assert to_db(np.array([2.0]), 4.0)[0] == pytest.approx(10 * np.log10(0.5))
