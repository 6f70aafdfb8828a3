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


@pytest.mark.parametrize("feed", ["linear", "circular"])
def test_identity_jones_gives_identity_mueller_for_both_feeds(feed):
    """An ideal (centre-corrected) beam changes no Stokes parameter, whatever the feeds."""
    m = jones_to_mueller(np.eye(2, dtype=complex), feed=feed)
    np.testing.assert_allclose(m, np.eye(4), atol=1e-15)
    assert polarized_beam(m) == pytest.approx(np.sqrt(2), abs=1e-15)
    assert leakage(m) == pytest.approx(0, abs=1e-15)


def test_ideal_circular_feeds_see_the_circular_convention():
    # R, L = (X + iY)/sqrt 2, (X - iY)/sqrt 2 of the (North, East) field: the circular
    # correlations of msleak.conventions (RR = I + V, RL = Q + iU)
    c = np.array([[1, 1j], [1, -1j]]) / np.sqrt(2)
    iquv = np.array([1.0, 0.2, -0.3, 0.1])
    corr = (c @ _brightness(iquv) @ c.conj().T).reshape(4)
    np.testing.assert_allclose(correlations_to_stokes(corr, "circular"), iquv, atol=1e-14)
    np.testing.assert_allclose(corr, [1.1, 0.2 - 0.3j, 0.2 + 0.3j, 0.9], atol=1e-15)


def _feed_correlations(jp, jq, iquv, feed):
    """Correlations (4,) of sky Stokes iquv through (X, Y) Jones matrices jp, jq, in the
    feeds' own basis, with 2x2 matrices."""
    c = np.eye(2) if feed == "linear" else np.array([[1, 1j], [1, -1j]]) / np.sqrt(2)
    return (c @ jp @ _brightness(iquv) @ jq.conj().T @ c.conj().T).reshape(4)


@pytest.mark.parametrize("feed", ["linear", "circular"])
def test_mueller_reproduces_the_measurement_equation(feed):
    """M @ (I,Q,U,V) equals the Stokes of C J_p B J_q^H C^H computed with 2x2 matrices."""
    jp, jq = _random_jones(5), _random_jones(5)
    iquv = RNG.normal(size=(5, 4))
    m = jones_to_mueller(jp, jq, feed=feed)
    for k in range(5):
        corr = _feed_correlations(jp[k], jq[k], iquv[k], feed)
        expected = np.linalg.solve(stokes_to_correlations_matrix(feed), corr)
        np.testing.assert_allclose(m[k] @ iquv[k], expected, rtol=1e-12, atol=1e-12)


def test_stokes_mueller_does_not_depend_on_the_feeds():
    """The same physical beam (random Jones pair) leaks the same way into the Stokes
    parameters formed from linear or from circular correlations."""
    jp, jq = _random_jones(20), _random_jones(20)
    lin = jones_to_mueller(jp, jq, feed="linear")
    circ = jones_to_mueller(jp, jq, feed="circular")
    np.testing.assert_allclose(circ, lin, rtol=0, atol=1e-12 * np.abs(lin).max())
    auto = jones_to_mueller(jp, feed="circular")
    np.testing.assert_allclose(leakage(auto), leakage(jones_to_mueller(jp)), rtol=1e-12)


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
