"""The windows' Legendre sums against numpy's legval, whatever the thread count."""

import numpy as np

from boresight.predict import windows


def test_legendre_means_match_numpy_and_ignore_threads():
    """The windows' Legendre sums (a numba recurrence over fixed blocks) against numpy's legval,
    and the same bits on one thread as on all."""
    from numpy.polynomial import legendre

    from boresight._util.threads import numba_threads

    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (4, 4, 1000))
    w = rng.normal(size=x.shape)
    got = windows._legendre_means(x, w, 200)
    want = [np.sum(w * legendre.legval(x, np.eye(201)[ell])) / 1000 for ell in range(201)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * np.max(np.abs(want)))
    with numba_threads(1):
        assert np.array_equal(windows._legendre_means(x, w, 200), got)
