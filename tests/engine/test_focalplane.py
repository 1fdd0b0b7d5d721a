"""A focal plane's pairs, each on its own samples: on the axis they are the boresight's, behind
an ideal HWP they return the sky."""

import healpy as hp
import numpy as np
import pytest
from helpers import iqu
from plates import wide_schedule

from boresight import engine, pointing
from boresight.instrument import focalplane
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Instrument, Systematics
from boresight.sky import SkyConfig, make_sky


def test_a_focal_plane_on_the_axis_simulates_as_the_boresight(small_sky):
    """Pairs on the axis, each on its own (equal) samples, give the maps of the shared stream; the
    chunks do not matter; and each pair draws the systematics of pair i of the instrument."""
    from helpers import toast_schedule

    from boresight.instrument import focalplane

    schedule = toast_schedule()
    sy = Systematics(dg={"mean": 0.0, "rms": 0.01}, rho_arcmin=(0.5, 1.0), dg_jitter=0.0, seed=4)
    a = engine.simulate_samples(small_sky, pointing.pointing(schedule), Instrument(), sy)
    fp = focalplane.on_axis((0.0, 45.0))
    b = engine.simulate_focalplane(small_sky, schedule, fp, sy)
    c = engine.simulate_focalplane(small_sky, schedule, fp, sy, chunk_samples=999)
    np.testing.assert_array_equal(a.pixels, b.pixels)
    np.testing.assert_array_equal(2 * a.hits_obs, b.hits_obs)  # pair-samples
    assert np.max(np.abs(a.q_obs - b.q_obs)) < 1e-12 and np.max(np.abs(a.u_obs - b.u_obs)) < 1e-12
    assert np.max(np.abs(b.q_obs - c.q_obs)) < 1e-12 and np.max(np.abs(b.u_obs - c.u_obs)) < 1e-12


def test_a_focal_plane_on_the_gpu_is_refused_clearly(small_sky):
    from helpers import toast_schedule

    from boresight.instrument import focalplane

    with pytest.raises(ValueError, match="backend 'gpu': a focal plane's TOD runs on the CPU"):
        engine.simulate_focalplane(
            small_sky, toast_schedule(), focalplane.on_axis(), Systematics(), backend="gpu"
        )


def test_a_focal_plane_on_the_axis_with_beams_simulates_as_the_boresight():
    """Each pair's own detector beams (for_pair's slices of the beam terms) as in the shared
    stream."""
    from helpers import toast_schedule

    from boresight.instrument import focalplane

    sky = make_sky(SkyConfig(nside=32, lmax=95, fwhm_arcmin=120.0, seed=7))
    schedule = toast_schedule()
    sy = Systematics(ellipticity_b=(0.05, 0.02), dfwhm_a_arcmin=(2.0, -1.0), dg=(0.01, 0.0))
    a = engine.simulate_samples(sky, pointing.pointing(schedule), Instrument(), sy)
    b = engine.simulate_focalplane(sky, schedule, focalplane.on_axis((0.0, 45.0)), sy)
    assert np.max(np.abs(a.q_obs)) > 0.1  # the beams leak
    assert np.max(np.abs(a.q_obs - b.q_obs)) < 1e-12 and np.max(np.abs(a.u_obs - b.u_obs)) < 1e-12


@pytest.mark.parametrize(
    "plate",
    [HWP("continuous", frequency_hz=0.37), HWP("stepped", step="repeat")],
    ids=["continuous", "stepped"],
)
def test_an_ideal_hwp_returns_the_sky_from_each_detectors_own_samples(plain_sky, plate):
    """The sky read in each sample's own pixel (TOAST's ScanHealpixMap), no systematic: behind
    the HWP the I, Q, U maps of the 3x3 map-maker are the input maps to rounding, from both
    detectors of every pair and from detector A alone (its 3x3 systems' rcond > 0.3 of at most
    1/2, measured 0.36-0.5). Without the HWP, detector A alone on one CES barely turns: rcond
    < 1e-3 in every pixel (measured < 5e-5)."""
    pairs = focalplane.on_axis((0.0, 30.0))
    sky = plain_sky
    for mapmaker in ("detectors", "single"):
        maps = engine.simulate_focalplane(
            sky, wide_schedule(4), pairs, evaluation="pixel", hwp=plate, mapmaker=mapmaker
        )
        valid = maps.q_obs != hp.UNSEEN
        assert maps.pixels.size > 15 and valid[maps.hits_obs >= 20].all(), mapmaker
        assert mapmaker == "detectors" or maps.rcond_obs.min() > 0.3
        want = sky.maps[:, maps.pixels[valid]]
        scale = np.abs(want).max()
        np.testing.assert_allclose(iqu(maps)[:, valid], want, rtol=0, atol=1e-10 * scale)
    bare = engine.simulate_focalplane(
        sky, wide_schedule(1), focalplane.on_axis((0.0,)), evaluation="pixel", mapmaker="single"
    )
    assert bare.pixels.size > 15 and bare.rcond_obs.max() < 1e-3
