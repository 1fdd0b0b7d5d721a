"""The engine's hot loop: pixel lists and samples checked at the boundary, samples at pixel
centres read exactly, and the 3x3 map-makers of each detector's own samples."""

import healpy as hp
import numpy as np
import pytest
from helpers import iqu
from plates import minute_schedule, wide_schedule

from boresight import engine, pointing
from boresight.engine.binner import pixel_list
from boresight.instrument import focalplane, hwp
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Instrument, Systematics
from boresight.sky import SkyConfig, make_sky


def test_a_strided_pixel_list_reaches_the_kernels_contiguous():
    """A view such as pix[::2] is valid input; passed on as a view, it would compile a second
    specialisation of generate_hits and accumulate (5.6 s with an empty numba cache)."""
    import numba

    from boresight._util import precompile

    npix = 12 * 64**2
    pix = np.arange(0, npix, 7)[::2]
    got = pixel_list(pix, npix)
    assert np.array_equal(got, pix)
    assert numba.typeof(got) == precompile.KERNELS["generate_hits"].signature[2]


def test_longitudes_of_any_turn_give_the_same_maps(small_sky):
    """Samples whose phi lies in (-pi, pi] or a turn further give the maps of phi in [0, 2 pi):
    the interpolation, and detector B's offset, take [0, 2 pi)."""
    from helpers import toast_schedule

    from boresight import pointing

    theta, phi, psi = (np.concatenate(x) for x in zip(*pointing.pointing(toast_schedule())))
    sy = Systematics(dg=0.01, rho_arcmin=1.0)
    a = engine.simulate_samples(small_sky, [(theta, phi, psi)], Instrument(), sy)
    for shifted in (np.where(phi > np.pi, phi - 2 * np.pi, phi), phi + 4 * np.pi):
        b = engine.simulate_samples(small_sky, [(theta, shifted, psi)], Instrument(), sy)
        np.testing.assert_array_equal(a.pixels, b.pixels)
        assert np.max(np.abs(a.q_obs - b.q_obs)) < 1e-9 and np.max(np.abs(a.u_obs - b.u_obs)) < 1e-9


def test_pixel_centre_hits_of_a_band_limited_sky_are_exact(plain_sky):
    """Samples at pixel centres, the alm evaluated there exactly, an ideal HWP at random angles
    (each sample's angle reflected as the engine does): I, Q, U are the sky's maps, alm2map's, to
    ducc0's accuracy."""
    rng = np.random.default_rng(7)
    pix = np.repeat(np.arange(12 * 16**2), 6)
    theta, phi = hp.pix2ang(16, pix)
    psi, chi = rng.uniform(0, 2 * np.pi, (2, pix.size))
    chunks = [(theta, phi, hwp.reflected(psi, chi, 0.0))]
    maps = engine.simulate_samples(plain_sky, chunks, evaluation="exact", mapmaker="detectors")
    one = Instrument(pair_angles_deg=(0.0,))
    single = engine.simulate_samples(plain_sky, chunks, one, evaluation="exact", mapmaker="single")
    for m in (maps, single):
        assert m.pixels.size == 12 * 16**2 and np.all(m.q_obs != hp.UNSEEN)
        scale = np.abs(plain_sky.maps).max()
        np.testing.assert_allclose(iqu(m), plain_sky.maps, rtol=0, atol=1e-9 * scale)


def test_both_detectors_own_samples_give_the_pair_differences_q_and_u():
    """When both detectors of a pair share their samples the 3x3 system's I-Q and I-U terms
    cancel, so its Q, U are the pair difference's whatever the pairs carry: a gain, a leak and a
    gain jitter behind a HWP, to rounding."""
    schedule = wide_schedule(1)
    sky = make_sky(SkyConfig(nside=16, lmax=32, fwhm_arcmin=120.0, seed=5))
    carried = Systematics(dg=(0.02, -0.01), leak=(0.003, 0.0), dg_jitter=(0.01, 0.02))
    pairs = focalplane.on_axis((0.0, 45.0))
    plate = HWP("continuous", frequency_hz=0.37)
    made = {
        m: engine.simulate_focalplane(sky, schedule, pairs, carried, hwp=plate, mapmaker=m)
        for m in ("pairs", "detectors")
    }
    a, b = made["pairs"], made["detectors"]
    np.testing.assert_array_equal(a.pixels, b.pixels)
    np.testing.assert_array_equal(a.hits_obs, b.hits_obs)
    valid = (a.q_obs != hp.UNSEEN) & (b.q_obs != hp.UNSEEN)
    assert valid[a.hits_obs >= 20].all() and a.i_obs is None
    scale = np.abs(sky.maps[1:]).max()
    for x, y in ((a.q_obs, b.q_obs), (a.u_obs, b.u_obs)):
        np.testing.assert_allclose(x[valid], y[valid], rtol=0, atol=1e-11 * scale)


def test_the_iqu_map_makers_refuse_the_gpu_and_unknown_names(plain_sky):
    schedule = minute_schedule([0.0])
    chunks = pointing.pointing(schedule, 1 << 16)
    with pytest.raises(ValueError, match="CPU backend only"):
        engine.simulate_samples(plain_sky, chunks, backend="gpu", mapmaker="detectors")
    with pytest.raises(ValueError, match="mapmaker must be one of"):
        engine.simulate_samples(plain_sky, chunks, mapmaker="demodulated")


@pytest.mark.parametrize("mapmaker", ["pairs", "detectors"])
def test_the_kept_samples_binned_are_the_streams_sums(mapmaker):
    """What a filter acts on, kept per sample (Binner.differences: the pair differences, or both
    detectors' samples) and binned in sample order (bin_differences, bin_detectors), gives the
    sums the stream bins directly (Binner.scatter), for pairs carrying a gain, a pointing offset,
    a leak and a gain jitter: the same numbers in the same order, to the bit."""
    from boresight.engine.binner import Binner, normal_sums
    from boresight.kernels.cpu import bin_detectors, bin_differences

    sky = make_sky(SkyConfig(nside=16, lmax=32, fwhm_arcmin=120.0, seed=5))
    carried = Systematics(dg=(0.02, -0.01), rho_arcmin=1.0, leak=(0.003, 0.0), dg_jitter=0.01)
    binner = Binner(
        sky, Instrument(pair_angles_deg=(0.0, 45.0)), carried, (0.0,), "interp", None, 0, "cpu"
    )
    theta, phi, psi = (np.concatenate(x) for x in zip(*pointing.pointing(wide_schedule(1))))
    pix = hp.ang2pix(16, theta, phi)
    direct, kept = (normal_sums(binner.kernels, 16, mapmaker) for _ in range(2))
    binner.scatter(pix, theta, phi, psi, direct, seed=3, first=11, mapmaker=mapmaker)
    c, s, d = binner.differences(
        theta, phi, psi, seed=3, first=11, detectors=mapmaker == "detectors"
    )
    if mapmaker == "pairs":
        bin_differences(pix, c, s, d, kept)
    else:
        bin_detectors(pix, c, s, *np.split(d, 2), kept)
    assert np.count_nonzero(direct[:, 0]) > 10
    np.testing.assert_array_equal(kept, direct)
