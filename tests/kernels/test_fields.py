"""What both backends share: each pixel's hits in a chunk, detector B's fields only with a
pointing offset, and the Q = U = 0 fields a copy of the sky's with Q and U zeroed."""

import numpy as np

from boresight.kernels import fields


def test_hit_offsets_bracket_each_pixels_hits():
    n_phi = np.array([3, 0, 5, 1])
    offsets = fields.hit_offsets(n_phi)
    assert offsets.dtype == np.int64
    np.testing.assert_array_equal(offsets, [0, 3, 3, 8, 9])
    np.testing.assert_array_equal(np.diff(offsets), n_phi)


def test_detector_b_is_read_only_with_a_pointing_offset():
    theta, phi, psi = np.full(4, 1.0), np.linspace(0, 1, 4), np.zeros(4)
    at = lambda t, p: np.array([t + p, t - p, t * p])  # three fields at points
    rot, ang, rho, chi = np.zeros(2), np.zeros(3), np.zeros(3), np.zeros(3)
    a, b = fields.pair_fields(at, None, 3, theta, phi, psi, rot, ang, rho, chi, pointing=False)
    np.testing.assert_array_equal(a, at(theta, phi))
    assert b.shape == (3, 0, 2, 3)

    def offset_points(t, p, *_):  # B looks 0.1 rad further in theta, every repeat and pair
        shape = (t.size, rot.size, ang.size)
        return np.broadcast_to((t + 0.1)[:, None, None], shape), np.broadcast_to(
            p[:, None, None], shape
        )

    a, b = fields.pair_fields(at, offset_points, 3, theta, phi, psi, rot, ang, rho, chi, True)
    assert b.shape == (3, 4, 2, 3)
    np.testing.assert_allclose(b[:, :, 1, 2], at(theta + 0.1, phi))


def test_the_zero_qu_sums_are_those_of_the_fields_with_q_and_u_zeroed():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(4, 6)), rng.normal(size=(4, 6, 1, 1))
    sums = lambda x, y: np.array([x.sum(axis=1), y.sum(axis=(1, 2, 3))])
    alone = fields.sums_with_zero_qu(sums, a, b, zero_qu=False)
    sky, zero = fields.sums_with_zero_qu(sums, a, b, zero_qu=True)
    np.testing.assert_array_equal(alone, sky)
    np.testing.assert_array_equal(zero[:, 1:3], 0.0)
    np.testing.assert_array_equal(zero[:, [0, 3]], sky[:, [0, 3]])
    assert np.any(a[1:3])  # the inputs are untouched
