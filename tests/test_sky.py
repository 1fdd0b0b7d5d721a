import healpy as hp
import numpy as np
import pytest
from helpers import rel_max

from boresight import harmonics, sky
from boresight.constants import ARCMIN


def test_realisation_has_the_input_spectrum(theory):
    cfg = sky.SkyConfig(nside=128, lmax=256, fwhm_arcmin=30.0, seed=3)
    s = sky.make_sky(cfg, theory)
    beam = hp.gauss_beam(30 * ARCMIN, lmax=256, pol=True)
    want = theory.total(lmax=256)
    nmodes = 2 * np.arange(30, 257) + 1

    def ratio(a, b, want_cl):
        got = harmonics.alm2cl(a, b)[30:257]
        return np.sum(nmodes * got) / np.sum(nmodes * want_cl[30:257])

    # Sums over ~6.5e4 modes: cosmic variance ~0.6% (TT, EE), a few % (TE); bounds are > 4 sigma.
    assert abs(ratio(s.alm[0], s.alm[0], want[0] * beam[:, 0] ** 2) - 1) < 0.03
    assert abs(ratio(s.alm[1], s.alm[1], want[1] * beam[:, 1] ** 2) - 1) < 0.03
    assert abs(ratio(s.alm[0], s.alm[1], want[3] * beam[:, 0] * beam[:, 1]) - 1) < 0.1


def test_maps_are_healpy_synthesis_of_alm(small_sky):
    assert rel_max(small_sky.maps, hp.alm2map(small_sky.alm, 64, pol=True)) < 1e-12


def test_seed_reproducible_and_unpolarised_option(theory):
    a = sky.make_sky(sky.SkyConfig(nside=16, lmax=40, seed=1), theory)
    b = sky.make_sky(sky.SkyConfig(nside=16, lmax=40, seed=1), theory)
    c = sky.make_sky(sky.SkyConfig(nside=16, lmax=40, seed=2), theory)
    d = sky.make_sky(sky.SkyConfig(nside=16, lmax=40, seed=1, polarised=False), theory)
    assert np.array_equal(a.maps, b.maps) and not np.allclose(a.maps, c.maps)
    assert np.array_equal(a.maps[0], d.maps[0]) and not d.maps[1:].any()


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(nside=-4), "nside"),
        (dict(nside=100), "nside"),
        (dict(nside=16, lmax=48), "lmax"),
        (dict(fwhm_arcmin=-1.0), "fwhm_arcmin"),
        (dict(r=-0.1), "r"),
        (dict(seed=-1), "seed"),
    ],
)
def test_bad_sky_config(kwargs, field):
    with pytest.raises(ValueError, match=field):
        sky.SkyConfig(**kwargs)


def test_from_maps_rejects_nan():
    m = np.zeros((3, 12 * 16**2))
    m[1, 5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        sky.Sky.from_maps(m)


def test_interleaved_fields_are_built_once(small_sky):
    """The kernels' (npix, fields) layout holds the maps, and every simulation shares one copy."""
    from boresight.evaluation import SkyFields

    np.testing.assert_array_equal(small_sky.interleaved, small_sky.maps.T)
    assert SkyFields(small_sky).stack is SkyFields(small_sky).stack is small_sky.interleaved
    template = np.arange(small_sky.maps.shape[1], dtype=float)
    stack = SkyFields(small_sky, template).stack
    np.testing.assert_array_equal(stack, np.vstack([small_sky.maps, template]).T)


def test_one_copy_of_the_maps(small_sky):
    """make_sky and from_maps store the maps interleaved: the kernels' layout is the maps
    themselves, not a second copy (1.2 GB at Nside 2048); the unpolarised copy keeps I alone."""
    for s in (small_sky, sky.Sky.from_maps(small_sky.maps, lmax=small_sky.lmax)):
        assert np.shares_memory(s.interleaved, s.maps)
        assert s.interleaved.flags.c_contiguous
    bare = small_sky.without_polarisation()
    assert np.shares_memory(bare.interleaved, bare.maps)
    np.testing.assert_array_equal(bare.maps[0], small_sky.maps[0])
    np.testing.assert_array_equal(bare.alm[0], small_sky.alm[0])
    assert not bare.maps[1:].any() and not bare.alm[1:].any()
    assert small_sky.maps[1:].any()  # the original is untouched


def test_a_sky_kept_on_a_span_is_the_sky_there_and_zero_elsewhere(small_sky):
    """kept_on keeps the maps' bits on [first, stop), zeros elsewhere, in the interleaved layout
    of its own memory; the alm are shared; an empty or out-of-sky span is refused."""
    npix = small_sky.maps.shape[1]
    first, stop = npix // 5, npix // 2
    kept = small_sky.kept_on(first, stop)
    np.testing.assert_array_equal(kept.maps[:, first:stop], small_sky.maps[:, first:stop])
    assert not kept.maps[:, :first].any() and not kept.maps[:, stop:].any()
    assert np.shares_memory(kept.interleaved, kept.maps) and kept.interleaved.flags.c_contiguous
    assert not np.shares_memory(kept.maps, small_sky.maps) and kept.alm is small_sky.alm
    for bad in ((5, 5), (-1, 10), (0, npix + 1)):
        with pytest.raises(ValueError):
            small_sky.kept_on(*bad)
