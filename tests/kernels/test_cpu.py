"""The CPU kernels: the fused bin_scan equals its stages, and detector B's offset pointing equals
the direct formula, past the poles too."""

import numpy as np

from boresight.instrument.pairs import Systematics, response
from boresight.kernels import cpu, fields


def test_cpu_bin_scan_equals_its_stages(small_sky):
    """bin_scan is generate_hits -> interpolate -> offset_points -> accumulate, to the bit; its
    Q = U = 0 sums are those stages over the sky without polarisation."""
    pixels = np.arange(0, 12 * 64**2, 97, dtype=np.int64)
    n_phi = np.full(pixels.size, 3)
    rng_rad, centre = np.full(pixels.size, 0.7), np.zeros(pixels.size)
    rot, ang = np.radians([0.0, 180.0]), np.radians([0.0, 45.0])
    systematics = Systematics(rho_arcmin=0.1, pol_angle_deg=0.5, dg=0.01, dg_jitter=0.02)
    par = systematics.per_pair(2)
    table = response(rot, ang, par, systematics.per_repeat(2))
    rho, chi, leak, jitter = par.rho, par.chi, par.leak, par.dg_jitter
    args = (rot, ang, table, rho, chi, leak, jitter, True)
    scan_args = (5, 64, pixels, n_phi, rng_rad, centre, False, small_sky.interleaved)
    fused = cpu.bin_scan(*scan_args, *args, False)
    both = cpu.bin_scan(*scan_args, *args, True)
    offsets = fields.hit_offsets(n_phi)
    theta, phi, psi = cpu.generate_hits(5, 64, pixels, offsets, rng_rad, centre, False)
    tb, pb = cpu.offset_points(theta, phi, psi, rot, ang, rho, chi)
    no_beams = np.empty((2, 0) + tb.shape[1:])
    unpolarised = small_sky.without_polarisation()
    for maps_of, got in (
        (small_sky, fused),
        (small_sky, both[0]),
        (unpolarised, both[1]),
    ):
        stack = maps_of.interleaved
        values_a = cpu.interpolate(stack, 64, theta, phi)
        values_b = cpu.interpolate(stack, 64, tb.ravel(), pb.ravel()).reshape((3,) + tb.shape)
        staged = cpu.accumulate(
            offsets, psi, values_a, values_b, no_beams, table, leak, jitter, 5, pixels
        )
        np.testing.assert_array_equal(got, staged)
    assert not np.array_equal(both[0], both[1])


def test_cpu_offset_points_equal_the_direct_formula_past_the_poles_too(offset_inputs):
    """B at theta + rho cos(beta), phi + rho sin(beta) / sin(theta), beta = psi + rotation + pair
    angle + chi, folded back past a pole: the kernel's angle-addition route against numpy's
    cos(beta) and sin(beta) of the whole angle."""
    theta, phi, psi, rot, ang, rho, chi = offset_inputs
    tb, pb = cpu.offset_points(*offset_inputs)
    beta = psi[:, None, None] + rot[None, :, None] + (ang + chi)[None, None, :]
    t = theta[:, None, None] + rho * np.cos(beta)
    f = phi[:, None, None] + rho * np.sin(beta) / np.sin(theta)[:, None, None]
    folded = (t < 0) | (t > np.pi)
    assert folded.sum() > 0  # the pole cases are exercised
    t = np.where(t < 0, -t, np.where(t > np.pi, 2 * np.pi - t, t))
    f = np.mod(np.where(folded, f + np.pi, f), 2 * np.pi)
    # a few ulp of the angles (8.9e-16 at 2 pi); phi wraps at 2 pi and divides by sin(theta), so
    # it is compared as a distance on the sphere, sin(theta) dphi
    np.testing.assert_allclose(tb, t, rtol=0, atol=4e-15)
    dphi = np.angle(np.exp(1j * (pb - f)))
    assert np.max(np.abs(dphi * np.sin(t))) < 4e-15
    assert ((pb >= 0) & (pb < 2 * np.pi)).all() and ((tb >= 0) & (tb <= np.pi)).all()
