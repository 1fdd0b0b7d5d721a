import numpy as np

from boresight.kernels import rng

MASK64 = (1 << 64) - 1


def mix64_reference(z):
    """SplitMix64 finaliser in Python integers (independent of numba's uint64 arithmetic)."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
    return z ^ (z >> 31)


def uniform_reference(seed, pixel, hit, stream):
    h = mix64_reference(seed ^ 0x9E3779B97F4A7C15)
    h = mix64_reference(h ^ pixel)
    h = mix64_reference(h ^ (hit * rng.N_STREAMS + stream))
    return (h >> 11) * 2.0**-53


def test_matches_python_integer_reference():
    pixels = np.array([0, 1, 12345, 50331647, 2**40], dtype=np.int64)
    hits = np.array([0, 3, 1, 7, 2], dtype=np.int64)
    got = rng.uniform_array(42, pixels, hits, 1)
    want = [uniform_reference(42, int(p), int(h), 1) for p, h in zip(pixels, hits)]
    assert np.array_equal(got, want)  # exact: same integer arithmetic


def test_uniform_and_independent_statistics():
    n = 200_000
    pix = np.arange(n, dtype=np.int64)
    u = rng.uniform_array(1, pix, np.zeros(n, dtype=np.int64), 0)
    v = rng.uniform_array(1, pix, np.zeros(n, dtype=np.int64), 1)
    assert u.min() >= 0 and u.max() < 1
    # Kolmogorov-Smirnov distance of n uniforms: 1.63/sqrt(n) is the 1% critical value.
    ks = np.max(np.abs(np.sort(u) - np.arange(1, n + 1) / n))
    assert ks < 1.63 / np.sqrt(n)
    # Correlation between streams: |r| < 4 sigma, sigma = 1/sqrt(n).
    assert abs(np.corrcoef(u, v)[0, 1]) < 4 / np.sqrt(n)


def test_seed_changes_everything():
    pix = np.arange(1000, dtype=np.int64)
    zero = np.zeros(1000, dtype=np.int64)
    assert not np.any(rng.uniform_array(1, pix, zero, 0) == rng.uniform_array(2, pix, zero, 0))
