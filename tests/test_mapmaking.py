"""The 2x2 map-maker against numpy's solver, and its flags of ill-conditioned pixels."""

import healpy as hp
import numpy as np

from boresight.mapmaking import RCOND_MIN, solve


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
