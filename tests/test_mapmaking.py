"""The 2x2 (Q, U) and 3x3 (I, Q, U) map-makers against numpy's solvers, and their flags of
ill-conditioned pixels."""

import healpy as hp
import numpy as np

from boresight.mapmaking import RCOND_MIN, solve, solve_iqu


def _normal(angles, d):
    c, s = np.cos(2 * angles), np.sin(2 * angles)
    return np.array([np.sum(c * c), np.sum(c * s), np.sum(s * s), np.sum(c * d), np.sum(s * d)])


def test_solve_is_numpys_least_squares():
    rng = np.random.default_rng(3)
    normals, want = [], []
    for _ in range(100):
        angles = rng.uniform(0, np.pi, rng.integers(3, 20))
        q, u = rng.normal(size=2)
        d = q * np.cos(2 * angles) + u * np.sin(2 * angles) + 1e-3 * rng.normal(size=angles.size)
        normals.append(_normal(angles, d))
        design = np.array([np.cos(2 * angles), np.sin(2 * angles)]).T
        want.append(np.linalg.lstsq(design, d, rcond=None)[0])
    q, u, rcond = solve(np.array(normals))
    np.testing.assert_allclose(np.array([q, u]).T, want, rtol=1e-10, atol=1e-12)
    assert np.all((rcond > 0) & (rcond <= 1))


def test_one_angle_or_none_is_flagged_unseen():
    one = _normal(np.array([0.3, 0.3, 0.3]), np.ones(3))
    none = np.zeros(5)
    q, u, rcond = solve(np.array([one, none]))
    assert np.all(q == hp.UNSEEN) and np.all(u == hp.UNSEEN)
    assert np.all(rcond < RCOND_MIN)


def _normal_iqu(weights, d):
    """The nine sums of solve_iqu from (n, 3) weights and samples d."""
    upper = np.triu_indices(3)
    return np.concatenate([(weights.T @ weights)[upper], weights.T @ d])


def test_solve_iqu_is_numpys_least_squares():
    """Random detector angles and samples: the 3x3 solve against numpy's lstsq per pixel, and the
    reciprocal condition number against the matrix's eigenvalues from numpy's eigvals."""
    rng = np.random.default_rng(4)
    normals, want, conds = [], [], []
    for _ in range(100):
        angles = rng.uniform(0, np.pi, rng.integers(4, 20))
        w = np.stack([np.ones_like(angles), np.cos(2 * angles), np.sin(2 * angles)], axis=1)
        d = w @ rng.normal(size=3) + 1e-3 * rng.normal(size=angles.size)
        normals.append(_normal_iqu(w, d))
        want.append(np.linalg.lstsq(w, d, rcond=None)[0])
        eig = np.sort(np.abs(np.linalg.eigvals(w.T @ w)))
        conds.append(eig[0] / eig[-1])
    i, q, u, rcond = solve_iqu(np.array(normals), rcond_min=0.0)
    np.testing.assert_allclose(np.array([i, q, u]).T, want, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(rcond, conds, rtol=1e-8)


def test_solve_iqu_flags_two_angles_or_none():
    """Two angles 90 deg apart see I +- Q only: singular, as no samples at all."""
    angles = np.array([0.2, 0.2 + np.pi / 2, 0.2])
    w = np.stack([np.ones(3), np.cos(2 * angles), np.sin(2 * angles)], axis=1)
    good = np.array([0.0, np.pi / 3, 2 * np.pi / 3])
    w_good = np.stack([np.ones(3), np.cos(2 * good), np.sin(2 * good)], axis=1)
    rows = [_normal_iqu(w, np.ones(3)), np.zeros(9), _normal_iqu(w_good, w_good @ [1.0, 2.0, 3.0])]
    i, q, u, rcond = solve_iqu(np.array(rows))
    assert np.all(np.array([i, q, u])[:, :2] == hp.UNSEEN) and np.all(rcond[:2] < RCOND_MIN)
    np.testing.assert_allclose([i[2], q[2], u[2]], [1.0, 2.0, 3.0], rtol=1e-12)
    # three angles 60 deg apart: w w^T = diag(3, 3/2, 3/2), rcond 1/2
    np.testing.assert_allclose(rcond[2], 0.5, rtol=1e-12)
