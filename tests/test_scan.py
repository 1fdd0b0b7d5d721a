import numpy as np
import pytest

from boresight import engine
from boresight.scan import SyntheticScan, paper_scan


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(n_phi=0), "n_phi"),
        (dict(n_phi=2.5), "n_phi"),
        (dict(range_rad=7.0), "range_rad"),
        (dict(range_rad=-0.1), "range_rad"),
        (dict(rotations_deg=()), "rotations_deg"),
        (dict(in_pixel="corner"), "in_pixel"),
        (dict(seed=-3), "seed"),
        (dict(range_rad=np.array([0.1, np.nan])), "range_rad"),
    ],
)
def test_bad_scan(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SyntheticScan(**kwargs)


def test_map_parameters_must_match_sky(small_sky):
    scan = SyntheticScan(n_phi=np.full(100, 2))
    with pytest.raises(ValueError, match="n_phi map has 100 pixels"):
        engine.simulate(small_sky, scan)


def test_per_pixel_maps_drive_hits():
    nside = 8
    nphi = np.arange(12 * nside**2) % 5 + 1
    scan = SyntheticScan(n_phi=nphi, range_rad=np.linspace(0, 1, 12 * nside**2))
    h, ncross = engine.scan_moments(scan, nside)
    assert np.array_equal(ncross, nphi)
    assert np.allclose(np.abs(h[:, nphi == 1]), 1.0)  # one angle: |h_n| = 1
    assert np.allclose(np.abs(h[2, 0]), 1.0)  # R = 0 in pixel 0: all angles equal


def test_hn_mean_matches_closed_form():
    """E[h_n] for psi uniform in a range R is sin(n R / 2) / (n R / 2) (sinc of the half range)."""
    scan = SyntheticScan(n_phi=4, range_rad=0.719, seed=1)
    h, _ = engine.scan_moments(scan, 64)
    for n in (1, 2, 3, 4):
        want = np.sinc(n * 0.719 / 2 / np.pi)
        sigma = np.sqrt((1 - want**2) / 4 / h.shape[1])  # standard error of the mean
        assert abs(h[n].real.mean() - want) < 5 * sigma
        assert abs(h[n].imag.mean()) < 5 * sigma


def test_complex64_moments_are_the_complex128_ones_rounded():
    """h_n kept in complex64 (the jobs' moments, half the memory) are the complex128 sums rounded
    once: within complex64's half-ulp of the unit circle, 6e-8, and not closer than float32."""
    scan = SyntheticScan(n_phi=4, range_rad=0.719, seed=1, rotations_deg=(0.0, 70.0))
    h, ncross = engine.scan_moments(scan, 16)
    h32, ncross32 = engine.scan_moments(scan, 16, dtype=np.complex64)
    assert h32.dtype == np.complex64 and np.array_equal(ncross, ncross32)
    np.testing.assert_array_equal(h32, h.astype(np.complex64))
    err = np.max(np.abs(h32 - h))
    assert 1e-9 < err < 6e-8 * np.sqrt(2)
    with pytest.raises(ValueError, match="complex128 or complex64"):
        engine.scan_moments(scan, 16, dtype=np.float64)


def test_paper_scans():
    assert paper_scan("deep", 90).rotations_deg == (0.0, 90.0)
    assert paper_scan("wide").n_phi == 2 and paper_scan("wide").range_rad == 0.169
    with pytest.raises(ValueError, match="survey"):
        paper_scan("medium")
