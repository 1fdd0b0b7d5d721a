"""The simulation engine against analytic identities (paper eq. 6; see docs/conventions.md)."""

from dataclasses import replace

import healpy as hp
import numpy as np
import pytest
from helpers import CENTRED, T0, rel_max
from plates import minute_schedule, wide_schedule

from boresight import engine, masks, pointing, predict
from boresight.constants import DEG
from boresight.instrument import focalplane, hwp
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Instrument, Systematics
from boresight.mitigation import CesScan, Filtering
from boresight.scan import SyntheticScan
from boresight.schedule import CES, Schedule, Site
from boresight.sky import SkyConfig, make_sky


@pytest.mark.parametrize("pairs", [(0.0, 45.0), (10.0, 55.0, 100.0), (0.0, 30.0)])
def test_no_systematic_returns_input(small_sky, pairs):
    m = engine.simulate(small_sky, SyntheticScan(**CENTRED), Instrument(pairs))
    assert rel_max(m.q, small_sky.maps[1]) < 1e-12  # rounding of a 2x2 solve
    assert rel_max(m.u, small_sky.maps[2]) < 1e-12


def test_single_pair_single_angle_is_flagged(small_sky):
    m = engine.simulate(small_sky, SyntheticScan(n_phi=1, range_rad=0.5), Instrument((0.0,)))
    assert not m.valid.any() and np.all(m.rcond < 1e-6)


def test_unobserved_pixels_flagged(small_sky):
    pix = np.arange(100, 300)
    m = engine.simulate(small_sky, SyntheticScan(**CENTRED), pixels=pix)
    assert m.valid.sum() == 200 and m.valid[pix].all() and (m.hits[pix] == 4).all()


def test_gain_equals_analytic_map(small_sky, small_sky_unpolarised):
    """dP = 1/2 h2 (dg1 + i dg2) T - (dg1+dg2)/4 P - (dg1-dg2)/4 h4 P*, exact at pixel centres."""
    scan = SyntheticScan(**CENTRED)
    sysm = Systematics(dg=(0.01, -0.02))
    h, _ = engine.scan_moments(scan, small_sky.nside)
    for sky in (small_sky_unpolarised, small_sky):
        ref = engine.simulate(sky, scan)
        m = engine.simulate(sky, scan, systematics=sysm)
        dp = (m.q - ref.q) + 1j * (m.u - ref.u)
        pred = predict.delta_p(sky, h, sysm)
        assert rel_max(dp, pred) < 1e-11  # rounding only


def test_a_strided_pixel_list_reaches_the_kernels_contiguous():
    """A view such as pix[::2] is valid input; passed on as a view, it would compile a second
    specialisation of generate_hits and accumulate (5.6 s with an empty numba cache)."""
    import numba

    from boresight._util import precompile

    npix = 12 * 64**2
    pix = np.arange(0, npix, 7)[::2]
    got = engine._pixel_list(pix, npix)
    assert np.array_equal(got, pix)
    assert numba.typeof(got) == precompile.KERNELS["generate_hits"].signature[2]


def test_prediction_and_maps_at_observed_pixels(small_sky):
    """delta_p at some pixels and Maps.qu_at are the full-sky ones restricted to them: the
    residual jobs hold only observed-pixel values. delta_p's pointing term reads the gradient
    synthesised on those pixels' rings alone, the full-sky one to rounding (6e-13 relative)."""
    scan = SyntheticScan(**CENTRED)
    sysm = Systematics(dg=(0.01, -0.02), rho_arcmin=(0.5, 0.3))
    h, _ = engine.scan_moments(scan, small_sky.nside)
    pixels = np.flatnonzero(masks.survey_mask("deep", small_sky.nside))
    full = predict.delta_p(small_sky, h, sysm)
    got = predict.delta_p(small_sky, h, sysm, pixels=pixels)
    np.testing.assert_allclose(got, full[pixels], rtol=0, atol=1e-13 * np.abs(full).max())
    pix = np.arange(0, 12 * 64**2, 7)
    m = engine.simulate(small_sky, scan, pixels=pix[::2])  # the others: unobserved, invalid
    assert (~m.valid).any() and m.valid.any()
    np.testing.assert_array_equal(m.qu_at(pix), m.qu[:, pix])


def test_take_qu_hands_on_the_engines_own_maps(small_sky):
    """Maps.take_qu is qu_at on the observed pixels, as the engine's own (2, n) Q, U array (no
    copy), for the sky's maps and for the Q = U = 0 maps made beside them; elsewhere a copy."""
    scan = SyntheticScan(**CENTRED)
    pix = np.arange(0, 12 * 64**2, 7)[::2]
    sim, sim0 = engine.simulate_with_zero_qu(small_sky, scan, pixels=pix)
    assert (~sim.valid).any()  # some pixels unobserved: their UNSEEN become 0
    for maps in (sim, sim0):
        want = maps.qu_at(maps.pixels)
        other = maps.take_qu(maps.pixels[::3])
        assert not np.shares_memory(other, maps.q_obs)
        np.testing.assert_array_equal(other, want[:, ::3])
        got = maps.take_qu(maps.pixels)
        assert np.shares_memory(got, maps.q_obs) and np.shares_memory(got, maps.u_obs)
        np.testing.assert_array_equal(got, want)
    copy = engine.simulate(small_sky, scan, pixels=pix)  # Maps whose rows are not one array
    copy = type(copy)(
        copy.nside, copy.pixels, copy.q_obs.copy(), copy.u_obs.copy(), copy.hits_obs, copy.rcond_obs
    )
    got = copy.take_qu(copy.pixels)
    assert not np.shares_memory(got, copy.q_obs)
    np.testing.assert_array_equal(got, sim.qu_at(sim.pixels))


def test_gain_cancels_with_90_degree_rotation(small_sky_unpolarised):
    scan = SyntheticScan(**CENTRED, rotations_deg=(0, 90))
    m = engine.simulate(small_sky_unpolarised, scan, systematics=Systematics(dg=(0.01, 0.01)))
    t_rms = np.std(small_sky_unpolarised.maps[0])
    assert np.max(np.abs(m.q + 1j * m.u)) < 1e-14 * t_rms  # cancels to rounding


def test_leak_is_a_gain_with_its_own_template(small_sky_unpolarised):
    scan = SyntheticScan(**CENTRED)
    template = np.cos(np.arange(small_sky_unpolarised.maps.shape[1]) / 50.0)
    sysm = Systematics(leak=(0.02, 0.01))
    m = engine.simulate(small_sky_unpolarised, scan, systematics=sysm, leak_template=template)
    h, _ = engine.scan_moments(scan, small_sky_unpolarised.nside)
    pred = predict.delta_p(small_sky_unpolarised, h, sysm, template=template)
    assert rel_max(m.q + 1j * m.u, pred) < 1e-11  # rounding only


def _pointing_error(sky, rho_arcmin):
    scan = SyntheticScan(**CENTRED)
    sysm = Systematics(rho_arcmin=(rho_arcmin, 0.6 * rho_arcmin), chi_deg=(20.0, -35.0))
    m = engine.simulate(sky, scan, systematics=sysm, evaluation="exact")
    h, _ = engine.scan_moments(scan, sky.nside)
    pred = predict.delta_p(sky, h, sysm)
    return np.max(np.abs(m.q + 1j * m.u - pred)), np.max(np.abs(pred))


def test_pointing_matches_first_order_with_quadratic_error(small_sky_unpolarised):
    """Halving rho halves the leak and quarters the error: the formula is right to O(rho^2)."""
    e1, a1 = _pointing_error(small_sky_unpolarised, 1.0)
    e2, a2 = _pointing_error(small_sky_unpolarised, 0.5)
    assert e1 / a1 < 0.03  # second order: ~ rho / (beam scale) ~ 1 arcmin / 25 arcmin
    assert 3.6 < e1 / e2 < 4.4  # ratio 4 for an O(rho^2) remainder
    assert abs(a1 / a2 - 2) < 1e-12


def test_pointing_first_order_cancels_with_180_rotation(small_sky_unpolarised):
    sysm = Systematics(rho_arcmin=0.5)
    leak = engine.simulate(
        small_sky_unpolarised, SyntheticScan(**CENTRED), systematics=sysm, evaluation="exact"
    )
    pbr = engine.simulate(
        small_sky_unpolarised,
        SyntheticScan(**CENTRED, rotations_deg=(0, 180)),
        systematics=sysm,
        evaluation="exact",
    )
    # The O(rho) part cancels; the O(rho^2) rest is ~ rho / beam scale ~ 0.5 / 25 of the leak.
    assert np.max(np.abs(pbr.q + 1j * pbr.u)) < 0.02 * np.max(np.abs(leak.q + 1j * leak.u))


@pytest.mark.parametrize("evaluation", ["interp", "exact"])
def test_zero_qu_maps_are_those_of_the_unpolarised_sky_to_the_bit(small_sky, evaluation):
    """The Q = U = 0 maps from the same pass equal a scan of sky.without_polarisation(): gain,
    pointing, leak (its template the sky's I), angle errors and gain jitter alike."""
    unpolarised = small_sky.without_polarisation()
    scan = SyntheticScan(n_phi=3, range_rad=0.5, rotations_deg=(0, 90), seed=5)
    cases = [Systematics(dg=0.02, rho_arcmin=1.0, leak=(0.01, 0.0))]  # exact evaluation: 1 s each
    if evaluation == "interp":
        cases += [
            Systematics(rho_arcmin=3.0, chi_deg=(10.0, -20.0)),
            Systematics(pol_angle_deg=0.5, dg_jitter=0.01),
        ]
    for sysm in cases:
        kw = dict(systematics=sysm, evaluation=evaluation, chunk_pixels=5000)
        maps, zero = engine.simulate_with_zero_qu(small_sky, scan, **kw)
        alone = engine.simulate(small_sky, scan, **kw)
        separate = engine.simulate(unpolarised, scan, **kw)
        for got, want in ((maps, alone), (zero, separate)):
            for name in ("q", "u", "hits", "rcond"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        assert not np.array_equal(zero.q, maps.q)  # the sky's Q, U are in the first only


def test_zero_qu_refuses_detector_beams(small_sky):
    with pytest.raises(ValueError, match="without_polarisation"):
        engine.simulate_with_zero_qu(
            small_sky, SyntheticScan(), systematics=Systematics(dfwhm_a_arcmin=0.5)
        )


def test_chunking_and_threads_do_not_change_results(small_sky):
    scan = SyntheticScan(n_phi=3, range_rad=0.7, rotations_deg=(0, 90), seed=11)
    sysm = Systematics(dg=(0.01, -0.01), rho_arcmin=0.5)
    a = engine.simulate(small_sky, scan, systematics=sysm, chunk_pixels=1 << 16, nthreads=2)
    b = engine.simulate(small_sky, scan, systematics=sysm, chunk_pixels=777, nthreads=1)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)
    c = engine.simulate(
        small_sky,
        SyntheticScan(n_phi=3, range_rad=0.7, rotations_deg=(0, 90), seed=12),
        systematics=sysm,
    )
    assert not np.array_equal(a.q, c.q)


def test_pixel_subset_equals_full_sky_restricted(small_sky):
    scan = SyntheticScan(n_phi=2, range_rad=0.3, seed=5)
    sysm = Systematics(dg=(0.01, -0.01))
    full = engine.simulate(small_sky, scan, systematics=sysm)
    pix = np.arange(5000, 9000)
    part = engine.simulate(small_sky, scan, systematics=sysm, pixels=pix)
    assert np.array_equal(full.q[pix], part.q[pix])


def test_moments_rotation_closed_form():
    scan = SyntheticScan(n_phi=3, range_rad=1.0, seed=2)
    h0, _ = engine.scan_moments(scan, 16)
    for alpha in (70.0, 89.0, 160.0):
        rot = SyntheticScan(n_phi=3, range_rad=1.0, seed=2, rotations_deg=(0, alpha))
        h1, _ = engine.scan_moments(rot, 16)
        for n in range(1, 5):
            want = np.abs(h0[n]) ** 2 * np.cos(n * alpha * DEG / 2) ** 2
            assert np.allclose(np.abs(h1[n]) ** 2, want, rtol=1e-12, atol=1e-15)
            assert np.isclose(
                predict.rotation_suppression(n, (0, alpha)),
                np.cos(n * alpha * DEG / 2) ** 2,
                rtol=1e-12,
            )


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


def test_a_focal_plane_on_the_axis_simulates_as_the_boresight(small_sky):
    """Pairs on the axis, each on its own (equal) samples, give the maps of the shared stream; the
    chunks do not matter; and each pair draws the systematics of pair i of the instrument."""
    from helpers import toast_schedule

    from boresight import pointing
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

    from boresight import pointing
    from boresight.instrument import focalplane
    from boresight.sky import SkyConfig, make_sky

    sky = make_sky(SkyConfig(nside=32, lmax=95, fwhm_arcmin=120.0, seed=7))
    schedule = toast_schedule()
    sy = Systematics(ellipticity_b=(0.05, 0.02), dfwhm_a_arcmin=(2.0, -1.0), dg=(0.01, 0.0))
    a = engine.simulate_samples(sky, pointing.pointing(schedule), Instrument(), sy)
    b = engine.simulate_focalplane(sky, schedule, focalplane.on_axis((0.0, 45.0)), sy)
    assert np.max(np.abs(a.q_obs)) > 0.1  # the beams leak
    assert np.max(np.abs(a.q_obs - b.q_obs)) < 1e-12 and np.max(np.abs(a.u_obs - b.u_obs)) < 1e-12


@pytest.mark.parametrize("n_max", [-1, 1.5, True])
def test_scan_moments_refuses_an_n_max_that_is_no_count(n_max):
    with pytest.raises((TypeError, ValueError), match="n_max"):
        engine.scan_moments(SyntheticScan(n_phi=2), 8, n_max=n_max)


def _iqu(maps):
    return np.array([maps.i_obs, maps.q_obs, maps.u_obs])


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
        np.testing.assert_allclose(_iqu(maps)[:, valid], want, rtol=0, atol=1e-10 * scale)
    bare = engine.simulate_focalplane(
        sky, wide_schedule(1), focalplane.on_axis((0.0,)), evaluation="pixel", mapmaker="single"
    )
    assert bare.pixels.size > 15 and bare.rcond_obs.max() < 1e-3


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
        np.testing.assert_allclose(_iqu(m), plain_sky.maps, rtol=0, atol=1e-9 * scale)


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


def _filtered_schedule(turnarounds="include"):
    """Two 5-minute CESs at 10 Hz over 20 deg throws, turning around in 2 s, seen twice."""
    ces = tuple(
        CES(T0 + start, 300.0, 50.0, centre, 20.0, turnaround_s=2.0)
        for start, centre in ((0.0, 150.0), (900.0, 210.0))
    )
    return Schedule(ces, Site(), 10.0, repeat_boresight_deg=(0.0, 45.0), turnarounds=turnarounds)


@pytest.mark.parametrize("turnarounds", ["include", "exclude"])
@pytest.mark.parametrize(
    "text",
    [
        "p3",
        "p1+ground3-split",
        "groundbin2",
        "deproject(gain)",
        "p1+deproject(gain)",
        "p1+deproject(gain/1h)",
    ],
)
@pytest.mark.parametrize("where", ["boresight", "hexagon:7:10"])
def test_filtered_maps_are_the_tod_filtered_by_hand_and_binned(plain_sky, turnarounds, text, where):
    """An independent route: each pair difference written from the sky's maps in the samples'
    pixels, filtered CES by CES with the filters themselves, the T map in the samples' pixels
    (filtered alike) regressed from it with numpy's least squares off the turnarounds per CES or
    over both CESs (a block of an hour), binned with bincount, solved with numpy; the pairs on the boresight (simulate_schedule) or each at its
    place in a focal plane (simulate_focalplane)."""
    schedule, filtering = _filtered_schedule(turnarounds), Filtering.parse(text)
    dg = 0.01
    run = dict(evaluation="pixel", filtering=filtering)
    if where == "boresight":
        angles = np.radians([0.0, 45.0])
        maps = engine.simulate_schedule(
            plain_sky, schedule, Instrument(pair_angles_deg=(0.0, 45.0)), Systematics(dg=dg), **run
        )
    else:
        plane = focalplane.load_focalplane(where)
        angles = np.radians(plane.pair_angles_deg)
        maps = engine.simulate_focalplane(plain_sky, schedule, plane, Systematics(dg=dg), **run)
    npix = 12 * plain_sky.nside**2
    normal = np.zeros((5, npix))
    i_map, q_map, u_map = plain_sky.maps
    # the deprojection's blocks: each CES, or (a "/1h" block) both CESs, 15 minutes apart
    blocks = [m for _, m in filtering.deprojection.blocks(schedule.ces)]
    for repeat in schedule.repeat_boresight_deg:
        for block in blocks:
            held = []  # per CES: pix, c, s, filtered d and template, fit and keep masks
            for ces in (schedule.ces[k] for k in block):
                one = replace(
                    schedule, ces=(ces,), repeat_boresight_deg=(repeat,), turnarounds="include"
                )
                if where == "boresight":
                    theta, phi, psi = (
                        np.concatenate(x)[None] for x in zip(*pointing.pointing(one))
                    )
                else:
                    chunks = pointing.detector_pointing(one, plane)
                    theta, phi, psi = (np.concatenate(x, axis=1) for x in zip(*chunks))
                pix = hp.ang2pix(plain_sky.nside, theta, phi)  # (1 or pairs, H)
                c = np.cos(2 * (psi[:, None, :] + angles[None, :, None]))
                s = np.sin(2 * (psi[:, None, :] + angles[None, :, None]))
                if where != "boresight":  # pair m at its own place: its own samples alone
                    c, s = (np.einsum("mmh->mh", x)[:, None, :] for x in (c, s))
                i, q, u = (m[pix][:, None, :] for m in (i_map, q_map, u_map))
                d = 0.5 * (i + q * c + u * s - (1 - dg) * (i - q * c - u * s))
                scan = CesScan.of(ces, schedule)
                keep = ~scan.turning if turnarounds == "exclude" else np.ones(pix.shape[1], bool)
                rows = []
                for row in range(pix.shape[0]):
                    dr = filtering.apply(d[row], scan) if filtering.filters else d[row]
                    x = i_map[pix[row]][None]
                    x = filtering.apply(x, scan) if filtering.filters else x
                    rows.append((pix[row], c[row], s[row], dr, x))
                held.append((rows, ~scan.turning, keep))
            for row in range(len(held[0][0])):
                pix_r, c_r, s_r, dr, x = (
                    np.concatenate([h[0][row][k] for h in held], axis=-1) for k in range(5)
                )
                fit = np.concatenate([h[1] for h in held])
                keep = np.concatenate([h[2] for h in held])
                if filtering.deprojection:  # the T map in the samples' pixels, over the block
                    coefficients = np.linalg.lstsq(x[:, fit].T, dr[:, fit].T, rcond=None)[0]
                    dr = dr - coefficients.T @ x
                for j, term in enumerate((c_r**2, c_r * s_r, s_r**2)):
                    normal[j] += np.bincount(pix_r[keep], term[:, keep].sum(axis=0), npix)
                for j, term in ((3, c_r * dr), (4, s_r * dr)):
                    normal[j] += np.bincount(pix_r[keep], term[:, keep].sum(axis=0), npix)
    seen = maps.pixels
    a11, a12, a22, b1, b2 = normal[:, seen]
    det = a11 * a22 - a12**2
    q_ref, u_ref = (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
    assert seen.size > 10 and np.array_equal(seen, np.flatnonzero(normal[0] + normal[2]))
    scale = np.max(np.abs(q_ref))
    assert np.max(np.abs(maps.q_obs - q_ref)) < 1e-10 * scale
    assert np.max(np.abs(maps.u_obs - u_ref)) < 1e-10 * scale


def test_a_filtered_focal_plane_on_the_axis_is_the_filtered_boresight(plain_sky):
    """The paper's two pairs as a focal plane on the axis, filtered: the boresight's maps."""
    schedule, filtering = _filtered_schedule(), Filtering.parse("p3+ground-split")
    systematics = Systematics(dg=(0.01, -0.01), rho_arcmin=2.0, chi_deg=30.0)
    axis = engine.simulate_schedule(
        plain_sky, schedule, Instrument(), systematics, filtering=filtering
    )
    plane = engine.simulate_focalplane(
        plain_sky, schedule, focalplane.on_axis((0.0, 45.0)), systematics, filtering=filtering
    )
    assert np.array_equal(axis.pixels, plane.pixels)
    scale = np.max(np.abs(axis.q_obs))
    assert np.max(np.abs(plane.q_obs - axis.q_obs)) < 1e-10 * scale
    assert np.max(np.abs(plane.u_obs - axis.u_obs)) < 1e-10 * scale


def test_a_filter_of_order_0_removes_a_constant_leak_and_keeps_the_rest(plain_sky):
    """A constant additive leak is a constant in every pair difference: the mean per throw takes
    all of it, and, the filter being linear, nothing else changes."""
    schedule, ones = _filtered_schedule(), np.ones(12 * plain_sky.nside**2)
    instrument = Instrument(pair_angles_deg=(0.0, 45.0))

    def maps(leak, text):
        return engine.simulate_schedule(
            plain_sky,
            schedule,
            instrument,
            Systematics(dg=0.01, leak=leak),
            leak_template=ones,
            filtering=Filtering.parse(text),
        )

    raw, leaked = maps(0.0, "none"), maps(0.02, "none")
    assert np.max(np.abs(leaked.q_obs - raw.q_obs)) > 1e-3  # the leak is there unfiltered
    clean, filtered = maps(0.0, "p0"), maps(0.02, "p0")
    scale = np.max(np.abs(clean.q_obs))
    assert np.max(np.abs(filtered.q_obs - clean.q_obs)) < 1e-12 * scale
    assert np.max(np.abs(filtered.u_obs - clean.u_obs)) < 1e-12 * scale


@pytest.mark.parametrize("where", ["boresight", "hexagon:7:10"])
def test_the_bk_templates_take_constant_gains_and_offsets_on_a_t_only_sky(plain_sky, where):
    """T alone, gains and pointing offsets constant per pair: the BK templates, regressed per
    CES from each pair's own stream, leave the leak's third order in rho (ell rho ~ 1e-2 here);
    the gain alone (its template exactly the leak) to rounding."""
    sky, schedule = plain_sky.without_polarisation(), _filtered_schedule()
    systematics = Systematics(dg=0.01, rho_arcmin=1.0, chi_deg=30.0)
    plane = focalplane.load_focalplane(where) if where != "boresight" else None

    def maps(text, systematics):
        run = dict(evaluation="exact", filtering=Filtering.parse(text))
        if plane is None:
            return engine.simulate_schedule(sky, schedule, Instrument(), systematics, **run)
        return engine.simulate_focalplane(sky, schedule, plane, systematics, **run)

    gains = Systematics(dg=0.01)
    size = np.max(np.abs(maps("none", gains).q_obs))
    assert size > 1e-2
    assert np.max(np.abs(maps("deproject(gain)", gains).q_obs)) < 1e-13 * size
    size = np.max(np.abs(maps("none", systematics).q_obs))
    left = maps("deproject(bk)", systematics)
    assert np.max(np.abs(left.q_obs)) < 1e-5 * size
    assert np.max(np.abs(left.u_obs)) < 1e-5 * size
    first_order = maps("deproject(gain,pointing)", systematics)
    assert np.max(np.abs(first_order.q_obs)) > 1e-4 * size  # the offset's second order


def test_filtered_maps_do_not_depend_on_the_chunks_or_threads(plain_sky):
    schedule, filtering = _filtered_schedule(), Filtering.parse("p3+ground")
    systematics = Systematics(dg=0.01, dg_jitter=0.001, rho_arcmin=1.0)
    a = engine.simulate_schedule(
        plain_sky, schedule, Instrument(), systematics, filtering=filtering
    )
    b = engine.simulate_schedule(
        plain_sky,
        schedule,
        Instrument(),
        systematics,
        filtering=filtering,
        chunk_samples=999,
        nthreads=1,
    )
    assert np.array_equal(a.q_obs, b.q_obs) and np.array_equal(a.u_obs, b.u_obs)


@pytest.mark.parametrize(
    ("text", "options", "match"),
    [
        ("p3", dict(backend="gpu"), "CPU backend"),
        ("p3", dict(mapmaker="detectors"), "pairs' map-maker"),
        ("p3", dict(hwp=HWP("continuous", frequency_hz=1.0)), "no plate"),
        ("p40", dict(sample_rate_hz=1.0), "samples per throw"),
        ("groundbin30", {}, "wider than the scan"),
        ("deproject(pointing)", dict(evaluation="interp"), "evaluation 'exact'"),
        (
            "deproject(gain)",
            dict(sample_rate_hz=0.1, duration_s=10.0),
            "1 template per CES; a CES of this schedule has 1 samples",
        ),
    ],
)
def test_a_filter_the_schedule_cannot_take_is_refused_before_any_work(
    plain_sky, text, options, match
):
    schedule = _filtered_schedule()
    if "sample_rate_hz" in options:  # 20 samples a throw
        schedule = replace(schedule, sample_rate_hz=options.pop("sample_rate_hz"))
    if "duration_s" in options:  # one sample a CES
        duration = options.pop("duration_s")
        ces = tuple(replace(c, duration_s=duration) for c in schedule.ces)
        schedule = replace(schedule, ces=ces)
    with pytest.raises(ValueError, match=match):
        if "hwp" in options:  # a focal plane behind a plate
            plane = focalplane.on_axis()
            engine.simulate_focalplane(
                plain_sky, schedule, plane, filtering=Filtering.parse(text), **options
            )
        engine.simulate_schedule(plain_sky, schedule, filtering=Filtering.parse(text), **options)
