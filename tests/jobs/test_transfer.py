"""The transfer function of a filtering pipeline: SOOPERCOOL's estimator against its own code,
the identity where nothing is filtered, a filter's F_ell^BB on a short real schedule, and its
F_ell^TT against a TOAST FilterBin observation matrix."""

import dataclasses
from pathlib import Path

import healpy as hp
import numpy as np
import pytest
from helpers import T0

from boresight import engine
from boresight.harmonics import alm2cl
from boresight.instrument.pairs import Systematics
from boresight.jobs.residual import residual
from boresight.jobs.transfer import (
    FIELD_PAIRS,
    FIELD_PAIRS_TEB,
    noise_transfer,
    pure_skies,
    soopercool_transfer,
    transfer_function,
)
from boresight.mitigation import Filtering
from boresight.schedule import CES, ScanMotion, Schedule, Site, load_schedule
from boresight.sky import SkyConfig, make_sky
from boresight.spectra import as_footprint, bin_spectrum

ROOT = Path(__file__).resolve().parents[2]

NSIDE = 32
EDGES = np.array([30, 40, 50, 65])


def _soopercool(mean_pcls_mat_filt, mean_pcls_mat_unfilt, pcls_mat_filt):
    """SOOPERCOOL's ``coupling_utils.get_transfer_with_error`` (simonsobs/SOOPERCOOL, read with
    fetch), its normal equations written with einsum as there."""
    cct_inv = np.transpose(
        np.linalg.inv(
            np.transpose(
                np.einsum("jil,jkl->ikl", mean_pcls_mat_unfilt, mean_pcls_mat_unfilt),
                axes=[2, 0, 1],
            )
        ),
        axes=[1, 2, 0],
    )
    tf = np.einsum(
        "ijl,jkl->kil",
        cct_inv,
        np.einsum("jil,jkl->ikl", mean_pcls_mat_unfilt, mean_pcls_mat_filt),
    )
    tferr = np.std(
        np.array(
            [
                np.einsum(
                    "ijl,jkl->kil",
                    cct_inv,
                    np.einsum("jil,jkl->ikl", mean_pcls_mat_unfilt, clf),
                )
                for clf in pcls_mat_filt
            ]
        ),
        axis=0,
    )
    return tf, tferr


@pytest.mark.parametrize("n_pure", [4, 9])
def test_the_estimator_is_soopercools(n_pure):
    """Least squares band by band against SOOPERCOOL's normal equations: the same matrix and
    error, for the polarised block (4 pure pairs) and for the 9x9 one."""
    rng = np.random.default_rng(1)
    raw = rng.normal(size=(n_pure, n_pure, 5)) + 3 * np.eye(n_pure)[:, :, None]
    each = raw[None] * rng.uniform(0.3, 1.0, size=(6, 1, n_pure, 5)) + rng.normal(
        scale=0.01, size=(6, n_pure, n_pure, 5)
    )
    mean = each.mean(axis=0)
    ours, ours_err = soopercool_transfer(mean, raw, each)
    theirs, theirs_err = _soopercool(mean, raw, each)
    assert np.max(np.abs(ours - theirs)) < 1e-10 * np.max(np.abs(theirs))
    assert np.max(np.abs(ours_err - theirs_err)) < 1e-10 * np.max(theirs_err)


@pytest.fixture(scope="module")
def sky():
    return make_sky(SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=120.0, seed=2))


def _footprint(sky, schedule):
    return (engine.simulate_schedule(sky, schedule).rcond > 0.05).astype(float)


def test_nothing_filtered_transfers_everything_as_it_is(sky):
    """The raw pipeline against itself: the identity in every band. (The error is each
    realisation's spread about it, SOOPERCOOL's, not zero.)"""
    ces = tuple(
        CES(T0 + 43200 * i, 1200.0, 50.0, 134.0 if i % 2 else 226.0, 40.0, turnaround_s=4.0)
        for i in range(4)
    )
    schedule = Schedule(ces, Site(), 2.0)
    tf = transfer_function(
        schedule, Filtering(), _footprint(sky, schedule), EDGES, nside=NSIDE, n_sims=2
    )
    for b in range(EDGES.size - 1):
        assert np.allclose(tf.matrix[:, :, b], np.eye(4), atol=1e-8)
    rows = tf.rows()
    assert len(rows) == 16 * (EDGES.size - 1)
    assert {(r["from"], r["to"]) for r in rows} == {
        (a, b) for a in FIELD_PAIRS for b in FIELD_PAIRS
    }
    with pytest.raises(ValueError, match="at least 2"):
        transfer_function(schedule, Filtering.parse("p1"), None, EDGES, nside=NSIDE, n_sims=1)
    teb = transfer_function(
        schedule, Filtering(), _footprint(sky, schedule), EDGES, nside=NSIDE, n_sims=2,
        intensity=True,
    )  # fmt: skip
    assert teb.fields == FIELD_PAIRS_TEB and len(teb.rows()) == 81 * (EDGES.size - 1)
    for b in range(EDGES.size - 1):
        assert np.allclose(teb.matrix[:, :, b], np.eye(9), atol=1e-8)
    with pytest.raises(ValueError, match="T block"):
        transfer_function(
            schedule, Filtering.parse("deproject(gain)"), None, EDGES, nside=NSIDE, n_sims=2,
            intensity=True,
        )  # fmt: skip


def test_the_noise_transfer_is_one_where_nothing_is_filtered(sky):
    """White noise's draws through two raw pipelines are the same maps: everything kept, with no
    spread (what a filter keeps of it is tests/jobs/suppression/test_filtered.py's). A pipeline
    that deprojects is refused (its templates of the uniform T would be a constant), and so is
    a single realisation."""
    ces = tuple(
        CES(T0 + 43200 * i, 1200.0, 50.0, 134.0 if i % 2 else 226.0, 40.0, turnaround_s=4.0)
        for i in range(4)
    )
    schedule = Schedule(ces, Site(), 2.0)
    footprint = _footprint(sky, schedule)
    same = noise_transfer(schedule, Filtering(), footprint, EDGES, nside=NSIDE, n_sims=2)
    assert same.n_sims == 2 and same.kept.shape == (2, EDGES.size - 1)
    assert np.all(same.entry("BB") == 1.0) and np.all(same.entry("EE") == 1.0)
    assert np.all(same.entry_error("BB") == 0.0)
    with pytest.raises(ValueError, match="filters only"):
        noise_transfer(schedule, Filtering.parse("deproject(gain)"), footprint, EDGES, nside=NSIDE)
    with pytest.raises(ValueError, match="at least 2"):
        noise_transfer(schedule, Filtering.parse("p1"), footprint, EDGES, nside=NSIDE, n_sims=1)


@pytest.mark.slow
def test_a_filter_keeps_of_a_sky_like_leak_what_it_keeps_of_the_sky(sky):
    """On the deep example's CES set: F_ell^BB of p3 + ground lies in (0.2, 0.9) and grows with
    ell, the filter moves under 5 % of E into B; and a polarisation-angle error, whose leak is
    the sky's own P turned, keeps through the filter what the sky's B keeps, F^BB, within twice
    a realisation's spread."""
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml")).single()
    mask = _footprint(sky, schedule)
    filtering = Filtering.parse("p3+ground")
    tf = transfer_function(schedule, filtering, mask, EDGES, nside=NSIDE, n_sims=6)
    f_bb = tf.entry("BB", "BB")
    assert np.all((f_bb > 0.2) & (f_bb < 0.9)) and np.all(np.diff(f_bb) > 0), f_bb
    assert np.all(np.abs(tf.entry("BB", "EE")) < 0.05), tf.entry("BB", "EE")
    for into, source in (("BB", "BB"), ("BB", "EE"), ("EB", "BE")):
        i, j = FIELD_PAIRS.index(into), FIELD_PAIRS.index(source)
        assert np.array_equal(tf.entry_error(into, source), tf.error[i, j])
        assert np.array_equal(tf.entry(into, source), tf.matrix[i, j])
    angle = Systematics(pol_angle_deg=0.5)
    kept = []
    for pipeline in (Filtering(), filtering):
        leak = residual(sky, schedule, angle, mask, 2 * NSIDE, filtering=pipeline).auto
        kept.append(bin_spectrum(leak, EDGES)[1])
    ratio = kept[1] / kept[0]
    assert np.all(np.abs(ratio - f_bb) < 2 * tf.error[3, 3]), (ratio, f_bb, tf.error[3, 3])


@pytest.mark.slow
def test_the_t_block_of_a_filter_on_each_detectors_tod(sky):
    """The 9x9 matrix through the detectors' map-maker, each detector's TOD filtered by p3 +
    ground on the deep example's CES set: F_ell^TT lies in (0.2, 0.9) and grows with ell; with
    both detectors of a pair on the same samples and no systematic, T and P do not mix (T
    cancels in the pair's Q and U, P in its I), so every T-to-P and P-to-T entry is 0 and the
    polarised block is the pairs' pipeline's own to rounding (the same Q and U maps)."""
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml")).single()
    mask = _footprint(sky, schedule)
    filtering = Filtering.parse("p3+ground")
    teb = transfer_function(schedule, filtering, mask, EDGES, nside=NSIDE, n_sims=6, intensity=True)
    f_tt = teb.entry("TT", "TT")
    assert np.all((f_tt > 0.2) & (f_tt < 0.9)) and np.all(np.diff(f_tt) > 0), f_tt
    for into in FIELD_PAIRS_TEB:
        for source in FIELD_PAIRS_TEB:
            if ("T" in into) != ("T" in source):
                assert np.all(np.abs(teb.entry(into, source)) < 1e-8), (into, source)
    pol = transfer_function(schedule, filtering, mask, EDGES, nside=NSIDE, n_sims=6)
    for into in FIELD_PAIRS:
        for source in FIELD_PAIRS:
            np.testing.assert_allclose(
                teb.entry(into, source), pol.entry(into, source), rtol=1e-6, atol=1e-8
            )


def _toast_filterbin_observation_matrix(directory, order):
    """TOAST's scheduler's 6 hours of a 20 deg patch, its SimGround with a pair on the boresight,
    and its FilterBin with a polynomial of ``order`` per throw (turnarounds flagged, neither fitted
    nor binned) writing the observation matrix: (the matrix, its I, Q, U blocks of RING pixels one
    after the other; the data; the pixel pointing; the binning operator; TOAST's rcond map; the
    schedule as boresight reads it, TOAST's UT1 - UTC and turnarounds left out)."""
    import scipy.sparse
    import toast
    from astropy import units as u
    from astropy.time import Time
    from helpers import toast_binning, toast_december_schedule
    from toast import ops
    from toast.instrument import GroundSite, Telescope
    from toast.instrument_sim import fake_boresight_focalplane
    from toast.observation import default_values as defaults
    from toast.ops.filterbin import combine_observation_matrix

    toast_schedule = toast_december_schedule(directory, width_deg=20, hours=(1, 7))
    focalplane = fake_boresight_focalplane(n_pix=1, sample_rate=5.0 * u.Hz)
    site = GroundSite(
        toast_schedule.site_name,
        toast_schedule.site_lat,
        toast_schedule.site_lon,
        toast_schedule.site_alt,
    )
    data = toast.Data(toast.mpi.Comm())
    telescope = Telescope("sat", focalplane=focalplane, site=site)
    ops.SimGround(telescope=telescope, schedule=toast_schedule, detset_key="pixel").apply(data)
    ops.DefaultNoiseModel(noise_model="noise_model").apply(data)
    detpointing = ops.PointingDetectorSimple()
    pixels = ops.PixelsHealpix(
        nside=NSIDE, nest=False, create_dist="pixel_dist", detector_pointing=detpointing
    )
    binning, flags = toast_binning(
        pixels, ops.StokesWeights(mode="IQU", detector_pointing=detpointing)
    )
    filterbin = ops.FilterBin(
        name="filterbin",
        det_data=defaults.det_data,
        binning=binning,
        ground_filter_order=None,
        poly_filter_order=order,
        poly_filter_view="throw",
        write_obs_matrix=True,
        output_dir=str(directory),
        **flags,
    )
    filterbin.apply(data)
    matrix = scipy.sparse.load_npz(
        combine_observation_matrix(str(directory / "filterbin_obs_matrix"))
    )
    rcond = hp.read_map(directory / "filterbin_filtered_rcond.fits")
    toast_schedule.write(str(directory / "schedule.ecsv"))
    ours = load_schedule(str(directory / "schedule.ecsv"), ScanMotion(sample_rate_hz=5.0))
    dut1 = float(Time(np.asarray(data.obs[0].shared["times"])[0], format="unix").delta_ut1_utc)
    ours = dataclasses.replace(ours, dut1_s=dut1, turnarounds="exclude")
    return matrix, data, pixels, filterbin, rcond, ours


@pytest.mark.parametrize("order", [pytest.param(1, marks=pytest.mark.slow), 3])
def test_f_tt_equals_a_toast_filterbin_observation_matrix(tmp_path, order):
    """TOAST 3.0.6's FilterBin(poly_filter_order, poly_filter_view="throw") writes its
    observation matrix M (the filtered, binned I, Q, U of any pixelised sky: M @ sky) on its own
    simulation of its scheduler's 8 CESs of a 20 deg patch, Nside 32. The pure-T skies of
    boresight's transfer function, through M, binned into the same bands on the same footprint:
    F_ell^TT = <C_filtered> / <C_sky> in 30-39, 40-49, 50-64; boresight's own 9x9 matrix on the
    same schedule and skies (its TOD reading each map's value in the sample's pixel, as M does)
    gives the same to 1 % (measured: p1 0.47 / 0.69 / 0.74 within 0.08 %, p3 0.13 / 0.31 / 0.46
    within 0.14 %; what TOAST's pyephem pointing, 30-45 arcsec off ICRS, moves across pixel
    edges). M is checked first: it gives TOAST's own filtered map of the sky scanned into its TOD
    to 1e-12."""
    pytest.importorskip("toast")
    from toast.observation import default_values as defaults

    matrix, data, pixels, filterbin, rcond, schedule = _toast_filterbin_observation_matrix(
        tmp_path, order
    )
    npix = 12 * NSIDE**2
    n_sims, seed = 3, 4
    # M against TOAST's own filtered map of the first sky, scanned pixel by pixel into the TOD
    sky = pure_skies(NSIDE, lmax=2 * NSIDE, fwhm_arcmin=60.0, seed=seed * 1_000_003, pure=("T",))[
        "T"
    ]
    pixels.apply(data)
    for ob in data.obs:
        for det in ob.local_detectors:
            ob.detdata[defaults.det_data][det] = sky.maps[0][ob.detdata[pixels.pixels][det]]
    filterbin.write_obs_matrix = False
    filterbin.name = "scanned"
    filterbin.apply(data)
    theirs = hp.read_map(tmp_path / "scanned_filtered_map.fits", None)
    through = matrix @ np.concatenate([sky.maps[0], np.zeros(2 * npix)])
    seen = np.flatnonzero(rcond > 0)
    assert seen.size > 100
    assert np.max(np.abs(through[:npix][seen] - theirs[0][seen])) < 1e-12 * np.std(theirs[0][seen])
    assert np.max(np.abs(through[npix:])) < 1e-12 * np.std(theirs[0][seen])  # no T to P
    # the footprint both keep: boresight's well-conditioned pixels that TOAST solves
    raw = engine.simulate_schedule(sky, schedule, mapmaker="detectors", evaluation="pixel")
    mask = ((raw.rcond > 0.05) & (rcond > 0)).astype(float)
    assert mask.sum() > 100
    footprint = as_footprint(mask)
    filtering = Filtering.parse(f"p{order}")
    ours = transfer_function(
        schedule,
        filtering,
        footprint,
        EDGES,
        nside=NSIDE,
        n_sims=n_sims,
        seed=seed,
        intensity=True,
        evaluation="pixel",
    ).entry("TT", "TT")

    def bandpower(m):
        alm = footprint.alm(m[footprint.pixels], 2 * NSIDE, 0)
        return bin_spectrum(alm2cl(alm, alm), EDGES)[1]

    filtered, skies = [], []
    for i in range(n_sims):
        t = pure_skies(
            NSIDE, lmax=2 * NSIDE, fwhm_arcmin=60.0, seed=seed * 1_000_003 + i, pure=("T",)
        )["T"].maps[0]
        filtered.append(bandpower((matrix @ np.concatenate([t, np.zeros(2 * npix)]))[:npix]))
        skies.append(bandpower(t))
    toast_f_tt = np.mean(filtered, axis=0) / np.mean(skies, axis=0)
    assert np.all((toast_f_tt > 0.05) & (toast_f_tt < 0.95)), toast_f_tt  # it filters
    np.testing.assert_allclose(ours, toast_f_tt, rtol=0.01)
