"""The prediction behind a half-wave plate against the TOD: a gain, a leak, a pointing offset and
beams read through the plate's moments, on the axis and off it; the plate's instrumental
polarisation, its synchronous signal, its angle offset and its jitter."""

import dataclasses

import healpy as hp
import numpy as np
import pytest
from helpers import EXAMPLES
from plates import wide_schedule

from boresight import engine, harmonics, spectra
from boresight import moments as scanstats
from boresight.constants import ARCMIN
from boresight.cosmology import load_spectra
from boresight.instrument import focalplane, hwp
from boresight.instrument.beams import Beam, BeamConvolver, turned
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Spread, Systematics
from boresight.predict import focalplane as predict_fp
from boresight.predict import hwp as predict_hwp
from boresight.schedule import load_schedule
from boresight.sky import Sky, SkyConfig, make_sky


@pytest.fixture(scope="module")
def deep_bare():
    """The deep example at 1 Hz, the paper's Q and U pairs, a sky smooth over a pixel, and the
    leaked pseudo-C_BB of a differential gain without a HWP."""
    base = dataclasses.replace(
        load_schedule(str(EXAMPLES / "schedule_deep_sat.toml")), sample_rate_hz=1.0
    )
    sky = make_sky(SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=450.0, seed=10))
    return base, sky, _leak(base, sky, None)


NSIDE = 32


EDGES = np.array([40, 48, 56, 2 * NSIDE + 1])  #: bands of 40 <= ell <= 2 Nside


GAIN = Systematics(dg=(0.01, -0.01))


POINTING = Systematics(rho_arcmin=1.0, chi_deg=30.0)


def _leak(schedule, sky, plate, systematics=GAIN, pairs=None, *, second_order=False):
    """The TOD's leaked pseudo-C_BB of ``systematics`` behind ``plate`` (the sky read exactly at
    every sample, through each detector's beam), and its prediction from the pairs'
    reflected-angle moments (a pointing offset to second order where asked), less the plate's
    own (its angle offset's); ``pairs`` default to the paper's Q and U pairs on the axis."""
    pairs = focalplane.on_axis((0.0, 45.0)) if pairs is None else pairs
    maps = [
        engine.simulate_focalplane(sky, schedule, pairs, s, evaluation="exact", hwp=plate)
        for s in (Systematics(), systematics)
    ]
    footprint = spectra.as_footprint((maps[0].rcond > 0.05).astype(float))
    stats = scanstats.characterise_focalplane(
        schedule, pairs, NSIDE, per_pair=True, hwp=plate, pointing=True,
        beams=systematics.has_beams,
    )  # fmt: skip

    def bb(dp):
        d = dp[footprint.pixels]
        b = footprint.alm(np.array([d.real, d.imag]), 2 * NSIDE, 2)[1]
        return spectra.bin_spectrum(harmonics.alm2cl(b), EDGES)[1]

    measured = bb((maps[1].q - maps[0].q) + 1j * (maps[1].u - maps[0].u))
    own = predict_fp.delta_p(sky, stats, Systematics())
    predicted = predict_fp.delta_p(sky, stats, systematics, second_order=second_order)
    return measured, bb(predicted - own)


@pytest.mark.parametrize(
    "plate", [HWP("continuous", frequency_hz=0.37), HWP("stepped")], ids=["continuous", "stepped"]
)
def test_a_gain_behind_a_hwp_leaks_as_its_moments_predict(deep_bare, plate):
    """Each pair behind the HWP on its own samples (engine.simulate_focalplane, the sky read
    exactly there) against the prediction from its reflected-angle moments: the leaked
    pseudo-C_BB within 5 % in every band 40 <= ell <= 2 Nside (measured 0.985-1.004 continuous,
    1.01 stepped). A continuous HWP averages the gain's T leak (h_{2,4}) away: 10x less at
    40 <= ell < 48 than without a HWP; a HWP stepped per CES does not (4x more there)."""
    schedule, sky, (bare, _) = deep_bare
    measured, predicted = _leak(schedule, sky, plate)
    assert np.all(np.abs(predicted / measured - 1) < 0.05), predicted / measured
    if plate.mode == "continuous":
        assert measured[0] < bare[0] / 5
    else:
        assert measured[0] > 2 * bare[0]


def test_without_a_hwp_the_same_route_predicts_the_gain(deep_bare):
    """The reference of the table above: no HWP, predicted / TOD 0.98-1.01."""
    measured, predicted = deep_bare[2]
    assert np.all(np.abs(predicted / measured - 1) < 0.05), predicted / measured


@pytest.mark.slow
def test_a_pointing_offset_behind_a_hwp_leaks_as_its_moments_predict(deep_bare):
    """Detector B 1 arcmin off, each pair behind the plate on its own samples: its offset turns
    with the pair's own crossing angle, the map-maker with the reflected one, so the T gradient
    reaches the map through exp(-4 i gamma) h_{1,4} and h_{3,4}, with their first-order change
    across the pixels (scanstats.pointing_behind). The leaked pseudo-C_BB is that prediction
    within 5 % in every band 40 <= ell <= 2 Nside: behind a plate stepped per CES (measured
    0.998-1.001), where it is 2x the bare pair's, and behind a spinning plate (1.03), which
    averages those moments away, 6.5-26x below the bare pair. There the moments are incoherent
    sums, and without the pixels' offsets the prediction is 0.77-0.95."""
    schedule, sky, _ = deep_bare
    bare, predicted = _leak(schedule, sky, None, POINTING)
    assert np.all(np.abs(predicted / bare - 1) < 0.05), predicted / bare
    stepped, predicted = _leak(schedule, sky, HWP("stepped"), POINTING)
    assert np.all(np.abs(predicted / stepped - 1) < 0.05), predicted / stepped
    assert np.all(stepped > 1.5 * bare)
    spinning, predicted = _leak(schedule, sky, HWP("continuous", frequency_hz=0.37), POINTING)
    assert np.all(np.abs(predicted / spinning - 1) < 0.05), predicted / spinning
    assert spinning[0] < bare[0] / 20 and np.all(spinning < bare / 5), bare / spinning


@pytest.mark.slow
def test_a_pointing_offset_reads_p_off_its_place_which_no_plate_cures(deep_bare):
    """A sky without T: detector B 1 arcmin off reads P there, (conj(delta) d P + delta dbar P)
    / 2 + cot(theta) (conj(delta) - delta) P / 2 (the components of P one step away in the
    coordinates, fp.coordinate_step), which reaches the map through h_1 of the pairs' own crossing
    angles (and h_{3,8}, h_{5,8}). A spinning plate takes it down by less than 2x in every band
    (measured 1.1-1.3x), where it takes the T gradient's down 6.5-26x, and the prediction is
    within 10 % in every band 40 <= ell <= 2 Nside, behind a spinning and a stepped plate
    (measured 1.00-1.08 on this leak of 1e-13 muK^2; 0.89-1.10 without the cot(theta) term)."""
    from boresight.sky import Sky

    schedule, full, _ = deep_bare
    alm, maps = full.alm.copy(), full.maps.copy()
    alm[0], maps[0] = 0.0, 0.0
    sky = Sky(alm=alm, maps=maps, nside=NSIDE, lmax=full.lmax, fwhm_arcmin=full.fwhm_arcmin)
    bare, _ = _leak(schedule, sky, None, POINTING)
    for plate in (HWP("continuous", frequency_hz=0.37), HWP("stepped")):
        measured, predicted = _leak(schedule, sky, plate, POINTING)
        assert np.all(np.abs(predicted / measured - 1) < 0.10), (plate.mode, predicted / measured)
        assert np.all(measured > bare / 2), (plate.mode, bare / measured)


@pytest.mark.parametrize("sky_t", ["T", "no T"])
def test_a_pointing_offsets_second_order_behind_a_plate_is_what_0_180_leaves(deep_bare, sky_t):
    """0/180 cancels every odd moment of a pointing offset behind a plate, its first order to
    rounding (< 1e-20 of the leak); what the TOD leaks is its second order in rho:
    d^2 T through h_{0,4}, h_{2,4}, h_{4,4}, read across each pixel to second order, and what B
    reads of P off its place through h_{2,0} and through no moment at all
    (predict.focalplane.delta_p(..., second_order=True)). 10 arcmin off, on the axis, within 3 %
    in every band 40 <= ell <= 2 Nside behind a stepped and a spinning plate (measured
    0.995-1.009); on a sky without T, where only P's part is left, within 10 % (0.99-1.08)."""
    schedule, sky, _ = deep_bare
    if sky_t == "no T":
        alm, maps = sky.alm.copy(), sky.maps.copy()
        alm[0], maps[0] = 0.0, 0.0
        sky = Sky(alm=alm, maps=maps, nside=NSIDE, lmax=sky.lmax, fwhm_arcmin=sky.fwhm_arcmin)
    schedule = dataclasses.replace(schedule, repeat_boresight_deg=(0.0, 180.0))
    offset = Systematics(rho_arcmin=10.0, chi_deg=30.0)
    bound = 0.03 if sky_t == "T" else 0.10
    for plate in (HWP("stepped"), HWP("continuous", frequency_hz=0.37)):
        measured, first = _leak(schedule, sky, plate, offset)
        assert np.all(first < 1e-20 * measured), first / measured
        _, both = _leak(schedule, sky, plate, offset, second_order=True)
        assert np.all(np.abs(both / measured - 1) < bound), (plate.mode, both / measured)


def test_what_a_hwp_pair_does_not_yet_carry_is_refused(deep_bare):
    schedule, sky, _ = deep_bare
    beam = Systematics(dfwhm_a_arcmin=0.5)
    turned = Systematics(dfwhm_a_arcmin=0.5, pol_angle_deg=0.2)
    pairs = focalplane.on_axis()
    with pytest.raises(ValueError, match="beams with pol_angle_deg behind a HWP"):
        engine.simulate_focalplane(sky, schedule, pairs, turned, hwp=HWP("stepped"))
    with pytest.raises(ValueError, match="dg_repeat behind a HWP"):
        hwp.reflected_systematics(HWP("stepped"), Systematics(dg_repeat=(0.0, 0.01)))
    stats = scanstats.characterise_focalplane(
        schedule.single(), pairs, 8, per_pair=True, hwp=HWP("stepped")
    )
    with pytest.raises(ValueError, match="beams with pol_angle_deg behind a HWP"):
        predict_fp.delta_p(sky, stats, turned)
    with pytest.raises(ValueError, match="characterise with per_pair and beams"):
        predict_fp.delta_p(sky, stats, beam)
    with pytest.raises(ValueError, match="characterise with per_pair and pointing"):
        predict_fp.delta_p(sky, stats, POINTING)
    with pytest.raises(ValueError, match=r"characterise_focalplane\(..., hwp=, ip=True\)"):
        predict_hwp.ip_delta_p_across(sky, stats, HWP("stepped", ip=1e-3))
    stats = scanstats.characterise_focalplane(
        schedule.single(), pairs, 8, per_pair=True, hwp=HWP("stepped"), beams=True
    )
    mask = (stats.combined.hits > 0).astype(float)
    with pytest.raises(ValueError, match="a pointing offset or a beam behind a HWP"):
        predict_fp.expected_residual(stats, mask, beam, load_spectra(), 450.0, lmax=16)
    for sy in (POINTING, beam):  # a synthetic scan's or the design's
        with pytest.raises(ValueError, match="behind a HWP.*only on a schedule's focal plane"):
            hwp.reflected_systematics(HWP("stepped"), sy)


def test_a_beam_behind_a_plate_turns_its_shape_and_its_polarisation_apart():
    """BeamConvolver.behind_hwp: a circular beam's signal is the bare one at the polarisation's
    angle (to ducc0's accuracy, 1e-8); an elliptical beam's, at one angle delta between its
    shape and its polarisation, is its T part at the shape's angle plus the polarised part of the
    beam whose major axis is delta further from its polarisation axis, read there (4e-11 of the
    polarised part, which is 1 % of the whole)."""
    sky = make_sky(SkyConfig(nside=32, lmax=64, fwhm_arcmin=120.0, seed=3))
    convolver = BeamConvolver(sky.alm, 120.0 * ARCMIN, 2)
    rng = np.random.default_rng(1)
    theta, phi = np.arccos(rng.uniform(-1, 1, 300)), rng.uniform(0, 2 * np.pi, 300)
    shape, delta = rng.uniform(-np.pi, np.pi, (2, 300))
    wide = Beam(130.0 * ARCMIN)
    got = convolver.behind_hwp(wide, theta, phi, shape=shape, delta=delta)
    want = convolver.extra(wide, theta, phi, shape + delta)
    assert np.max(np.abs(got - want)) < 1e-8 * np.max(np.abs(want))
    ellipse = Beam(120.0 * ARCMIN, 0.1, 0.3)
    polarised = np.max(np.abs(convolver.extra(ellipse, theta, phi, shape, part="P")))
    for d in (0.2, -1.1):
        got = convolver.behind_hwp(ellipse, theta, phi, shape=shape, delta=np.full(300, d))
        want = convolver.extra(ellipse, theta, phi, shape, part="T") + convolver.extra(
            turned(ellipse, -d), theta, phi, shape + d, part="P"
        )
        assert np.max(np.abs(got - want)) < 1e-9 * polarised
    whole = convolver.extra(ellipse, theta, phi, shape)
    parts = sum(convolver.extra(ellipse, theta, phi, shape, part=p) for p in ("T", "P"))
    assert np.max(np.abs(whole - parts)) < 1e-12 * np.max(np.abs(whole))
    assert polarised < 0.02 * np.max(np.abs(whole))


#: an elliptical beam on every detector A and a wider one on every B
BEAMS = Systematics(ellipticity_a=0.05, ellipticity_angle_a_deg=30.0, dfwhm_b_arcmin=10.0)


@pytest.fixture(scope="module")
def hexagon_sky(deep_bare):
    """The deep example at 1 Hz, a 7-pixel hexagon 20 deg wide, the sky of deep_bare and that sky
    without T."""
    schedule, sky, _ = deep_bare
    alm, maps = sky.alm.copy(), sky.maps.copy()
    alm[0], maps[0] = 0.0, 0.0
    plain = Sky(alm=alm, maps=maps, nside=NSIDE, lmax=sky.lmax, fwhm_arcmin=sky.fwhm_arcmin)
    return schedule, focalplane.hexagon(7, 20.0), sky, plain


def _beam_leak(hexagon_sky, plate, sky=None):
    """:func:`_leak` of BEAMS on the hexagon, on the full sky or on ``sky``."""
    schedule, pairs, full, _ = hexagon_sky
    return _leak(schedule, full if sky is None else sky, plate, BEAMS, pairs)


#: a gain and a pointing offset drawn per pair, scattered over a focal plane
SCATTERED = {
    "gain": Systematics(dg=Spread(0.0, 0.01), seed=5),
    "pointing": Systematics(rho_arcmin=Spread(1.0, 0.5), chi_deg=Spread(0.0, 90.0), seed=5),
}


@pytest.mark.parametrize("name", list(SCATTERED))
def test_leaks_scattered_over_a_focal_plane_behind_a_hwp_are_their_moments_prediction(
    hexagon_sky, name
):
    """A gain and a pointing offset drawn per pair of a 7-pixel hexagon 20 deg wide, each pair on
    its own samples: bare, behind a plate stepped per CES and behind a spinning one, the leaked
    pseudo-C_BB is the prediction from each pair's own moments (predict.focalplane.delta_p)
    within 10 % in every band 40 <= ell <= 2 Nside (measured 1.02-1.08 bare, 1.00-1.01 stepped,
    1.04-1.08 spinning). The spinning plate takes the bare leak down 4.4x (gain) and 15x
    (pointing) at 40 <= ell < 48, and the gain's 2x at the top band, where its incoherent sums of
    h_{2,4} are whitest."""
    schedule, pairs, sky, _ = hexagon_sky
    bare, predicted = _leak(schedule, sky, None, SCATTERED[name], pairs)
    assert np.all(np.abs(predicted / bare - 1) < 0.10), predicted / bare
    for plate in (HWP("stepped"), HWP("continuous", frequency_hz=0.37)):
        measured, predicted = _leak(schedule, sky, plate, SCATTERED[name], pairs)
        assert np.all(np.abs(predicted / measured - 1) < 0.10), (plate.mode, predicted / measured)
    assert measured[0] < bare[0] / 4 and np.all(measured < bare / 1.5), bare / measured


@pytest.mark.slow
def test_beams_behind_a_hwp_leak_as_their_moments_predict(hexagon_sky):
    """An elliptical beam on every A and a wider one on every B, each pair of a 7-pixel hexagon
    behind the plate on its own samples. The shapes turn with the pairs' own crossing angles,
    the polarisation with the reflected ones, so the sky's T reaches the map through h_{n,4},
    each read across the pixel to second order (scanstats.beams_behind). The leaked pseudo-C_BB
    is that prediction within 5 % in every band 40 <= ell <= 2 Nside: behind a plate stepped
    per CES (measured 0.99-1.00) and behind a spinning plate (1.03-1.05), which takes the bare
    pairs' leak down 40x at 40 <= ell < 48 (their prediction: 1.02-1.05)."""
    bare, predicted = _beam_leak(hexagon_sky, None)
    assert np.all(np.abs(predicted / bare - 1) < 0.07), predicted / bare
    for plate in (HWP("stepped"), HWP("continuous", frequency_hz=0.37)):
        measured, predicted = _beam_leak(hexagon_sky, plate)
        assert np.all(np.abs(predicted / measured - 1) < 0.05), (plate.mode, predicted / measured)
    assert measured[0] < bare[0] / 20, bare / measured


@pytest.mark.slow
def test_a_beams_polarised_part_behind_a_plate_turns_with_its_angle_offset(hexagon_sky):
    """A sky without T: what the beams leave is their polarised part, Re(exp(-2 i (a - psi)) C)
    through h_{n,0} and h_{n,8} to h_6. With the plate's angle offset of 15 deg turning it by
    exp(-+60 i deg), the prediction is within 10 % in every band behind a stepped and a spinning
    plate (measured 1.01-1.05); with that turn's sign flipped it is up to 22 % off."""
    _, _, _, plain = hexagon_sky
    for plate in (
        HWP("stepped", angle_offset_deg=15.0),
        HWP("continuous", frequency_hz=0.37, angle_offset_deg=15.0),
    ):
        measured, predicted = _beam_leak(hexagon_sky, plate, plain)
        assert np.all(np.abs(predicted / measured - 1) < 0.10), (plate.mode, predicted / measured)


IP = {"ip": 1e-3, "ip_phase_deg": 30.0}


@pytest.mark.parametrize(
    "plate",
    [HWP("continuous", frequency_hz=0.37, **IP), HWP("stepped", step="repeat", **IP)],
    ids=["continuous", "stepped"],
)
def test_the_plates_instrumental_polarisation_is_its_moments_prediction(plain_sky, plate):
    """The sky read in each sample's pixel: the TOD's spurious P of the plate's IP, in the pair
    differences' map and in both detectors' own, is predict.hwp.ip_delta_p's from the
    boresight's h_{2,0}, h_{2,8} and h_{4,8} (scanstats.hwp_moments, a separate binning) to
    rounding; detector A alone's, which solves I beside P, is its 3x3 prediction (with h_{0,4}
    and h_{2,4}) to rounding too."""
    schedule = wide_schedule(4)
    pairs = focalplane.on_axis((0.0, 30.0))

    def dp(mapmaker, with_plate):
        maps = engine.simulate_focalplane(
            plain_sky, schedule, pairs, evaluation="pixel", hwp=with_plate, mapmaker=mapmaker
        )
        return maps, maps.q_obs + 1j * maps.u_obs

    ideal = dataclasses.replace(plate, ip=0.0)
    hits, h = scanstats.hwp_moments(schedule, plate, 16, predict_hwp.SINGLE_IP_TERMS)
    angles = pairs.pair_angles_deg
    for mapmaker in ("pairs", "detectors", "single"):
        want_all = predict_hwp.ip_delta_p(
            plain_sky, h, plate, angles, mapmaker=mapmaker, spread=False
        )
        maps, with_ip = dp(mapmaker, plate)
        _, without = dp(mapmaker, ideal)
        valid = maps.q_obs != hp.UNSEEN
        if mapmaker != "single":
            np.testing.assert_array_equal(hits[maps.pixels] * 2, maps.hits_obs)
        want = want_all[maps.pixels[valid]]
        got = (with_ip - without)[valid]
        assert np.abs(want).max() > 1e-3 * 1e-2, mapmaker
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize(
    "plate",
    [
        HWP("continuous", frequency_hz=0.37, **IP),
        HWP("stepped", step="repeat", angles_deg=(0.0, 22.5), **IP),
    ],
    ids=["continuous", "stepped"],
)
def test_the_plates_instrumental_polarisation_on_a_focal_plane_is_its_relative_moments(
    plain_sky, plate
):
    """A 7-pixel hexagon 10 deg wide, each pair on its own samples, the sky read in each sample's
    pixel: the TOD's spurious P of the plate's IP, in the pair differences' map and in detector
    A's alone, is ip_delta_p's from the map-maker's combination of the pairs' moments of
    chi - gamma / 2 (hwp_moments(..., relative=True)) to rounding, where the 3x3 systems are
    not near singular (rcond > 0.01: 48-55 of 55 pixels). The boresight's moments with the
    pairs' angles, as if on the axis, miss it by 72-73 %."""
    schedule = wide_schedule(2)
    hexagon = focalplane.hexagon(7, 10.0)
    ideal = dataclasses.replace(plate, ip=0.0)
    _, h = scanstats.hwp_moments(
        schedule, plate, 16, predict_hwp.SINGLE_IP_TERMS, focalplane=hexagon, relative=True
    )
    _, boresight_h = scanstats.hwp_moments(schedule, plate, 16, predict_hwp.SINGLE_IP_TERMS)
    for mapmaker in ("pairs", "single"):
        maps = [
            engine.simulate_focalplane(
                plain_sky, schedule, hexagon, evaluation="pixel", hwp=p, mapmaker=mapmaker
            )
            for p in (ideal, plate)
        ]
        valid = maps[0].rcond_obs > 0.01  # rounding grows as 1 / rcond
        got = (maps[1].q_obs - maps[0].q_obs + 1j * (maps[1].u_obs - maps[0].u_obs))[valid]
        pixels = maps[0].pixels[valid]
        want = predict_hwp.ip_delta_p(plain_sky, h, plate, None, mapmaker=mapmaker, spread=False)
        assert np.abs(want).max() > 1e-3 * 1e-2, mapmaker
        np.testing.assert_allclose(got, want[pixels], rtol=0, atol=1e-9 * np.abs(want).max())
        on_axis = predict_hwp.ip_delta_p(
            plain_sky, boresight_h, plate, hexagon.pair_angles_deg, mapmaker=mapmaker, spread=False
        )[pixels]
        away = np.linalg.norm(on_axis - got) / np.linalg.norm(got)
        assert away > 0.5, (mapmaker, away)


def _ip_leak(schedule, sky, pairs, plate, mapmaker):
    """The leaked pseudo-C_BB of the plate's IP in ``mapmaker``'s map (the sky read exactly at
    every sample), and the binning that measured it, for a spurious P map."""
    ideal = dataclasses.replace(plate, ip=0.0)
    maps = [
        engine.simulate_focalplane(
            sky, schedule, pairs, evaluation="exact", hwp=p, mapmaker=mapmaker
        )
        for p in (ideal, plate)
    ]
    footprint = spectra.as_footprint((maps[0].rcond > 0.05).astype(float))

    def bb(dp):
        d = dp[footprint.pixels]
        b = footprint.alm(np.array([d.real, d.imag]), 2 * NSIDE, 2)[1]
        return spectra.bin_spectrum(harmonics.alm2cl(b), EDGES)[1]

    return bb((maps[1].q - maps[0].q) + 1j * (maps[1].u - maps[0].u)), bb


@pytest.mark.parametrize(
    "plate, repeats",
    [
        (HWP("continuous", frequency_hz=0.37, **IP), (0.0,)),
        (HWP("continuous", frequency_hz=0.37, **IP), (0.0, 45.0)),
        (HWP("continuous", frequency_hz=0.37, **IP), (0.0, 90.0)),
        (HWP("stepped", **IP), (0.0,)),
    ],
    ids=["continuous-0", "continuous-0/45", "continuous-0/90", "stepped-0"],
)
def test_the_plates_instrumental_polarisation_leaks_as_h20_predicts(deep_bare, plate, repeats):
    """The deep example at 1 Hz, the sky read exactly at every sample: the plate's IP survives the
    spinning plate, in the pair differences' map and in detector A's alone, and its leaked
    pseudo-C_BB is ip_delta_p's (its h_{2,0}) within 10 % in every band 40 <= ell <= 2 Nside
    (measured 0.99-1.03). 0/90 cancels h_{2,0} and the leak with it, to rounding (1e-35 muK^2
    against 1e-8). Detector A alone behind a plate stepped per CES solves I against P from few
    angles: its 3x3 prediction holds there too (0.99-1.01), where the pairs' is 0.55-0.89."""
    base, sky, _ = deep_bare
    schedule = dataclasses.replace(base, repeat_boresight_deg=repeats)
    pairs = focalplane.on_axis((0.0, 45.0))
    hits, h = scanstats.hwp_moments(schedule, plate, NSIDE, predict_hwp.SINGLE_IP_TERMS)
    for mapmaker in ("pairs", "single"):
        predicted = predict_hwp.ip_delta_p(sky, h, plate, pairs.pair_angles_deg, mapmaker=mapmaker)
        measured, bb = _ip_leak(schedule, sky, pairs, plate, mapmaker)
        if repeats == (0.0, 90.0):
            assert measured.max() < 1e-28, measured
            continue
        assert measured.min() > 1e-10, measured  # epsilon^2 T^2 h_{2,0}^2 of a 1e-3 plate
        np.testing.assert_allclose(bb(predicted) / measured, 1.0, atol=0.10)
    if plate.mode == "stepped":  # the pairs' 2x2 misses detector A's I row
        pairs_only = bb(predict_hwp.ip_delta_p(sky, h, plate, pairs.pair_angles_deg)) / measured
        assert pairs_only.min() < 0.9, pairs_only


@pytest.mark.parametrize(
    "plate",
    [HWP("continuous", frequency_hz=0.37, **IP), HWP("stepped", **IP)],
    ids=["continuous", "stepped"],
)
def test_the_plates_instrumental_polarisation_on_a_focal_plane_leaks_as_predicted(
    hexagon_sky, plate
):
    """The deep example at 1 Hz on a 7-pixel hexagon 20 deg wide, the sky read exactly at every
    sample: the IP's leaked pseudo-C_BB, in the pair differences' map and in detector A's alone,
    is ip_delta_p's from the pairs' relative moments within 10 % in every band 40 <= ell <=
    2 Nside (measured 1.01-1.05)."""
    schedule, pairs, sky, _ = hexagon_sky
    _, h = scanstats.hwp_moments(
        schedule, plate, NSIDE, predict_hwp.SINGLE_IP_TERMS, focalplane=pairs, relative=True
    )
    for mapmaker in ("pairs", "single"):
        measured, bb = _ip_leak(schedule, sky, pairs, plate, mapmaker)
        predicted = bb(predict_hwp.ip_delta_p(sky, h, plate, None, mapmaker=mapmaker))
        assert measured.min() > 1e-10, measured
        np.testing.assert_allclose(predicted / measured, 1.0, atol=0.10)


def test_a_plate_angle_offset_turns_the_maps_by_four_times_it(plain_sky):
    """A plate whose true angle is delta = 0.5 deg off the map-maker's: behind it the maps are the
    sky's P turned by exp(-4 i delta) to rounding (the sky read in each sample's pixel), and
    predict.focalplane.delta_p, with the offset as a 2 delta angle error of every pair at its
    reflected angle, gives the same spurious P."""
    schedule = wide_schedule(1)
    pairs = focalplane.on_axis((0.0, 30.0))
    plate = HWP("continuous", frequency_hz=0.37, angle_offset_deg=0.5)
    maps = engine.simulate_focalplane(plain_sky, schedule, pairs, evaluation="pixel", hwp=plate)
    valid = maps.q_obs != hp.UNSEEN
    p_sky = (plain_sky.maps[1] + 1j * plain_sky.maps[2])[maps.pixels[valid]]
    got = (maps.q_obs + 1j * maps.u_obs)[valid]
    np.testing.assert_allclose(got, p_sky * np.exp(-4j * np.radians(0.5)), atol=1e-9 * 100)
    stats = scanstats.characterise_focalplane(schedule, pairs, 16, per_pair=True, hwp=plate)
    dp = predict_fp.delta_p(plain_sky, stats, Systematics(), spread=False)[maps.pixels[valid]]
    np.testing.assert_allclose(dp, got - p_sky, atol=1e-9 * np.abs(got - p_sky).max())


@pytest.mark.parametrize(
    "plate", [HWP("continuous", frequency_hz=0.37), HWP("stepped")], ids=["continuous", "stepped"]
)
def test_the_plate_reflects_the_pairs_angle_errors(plain_sky, plate):
    """A detector at gamma + theta behind the plate sees a = psi - gamma - theta + 2 chi: both
    detectors of every pair 0.5 deg off turn the maps' P by exp(+2 i theta) to rounding, where a
    bare pair's turn by exp(-2 i theta); with the plate's 0.3 deg offset as well, by
    exp(2 i theta - 4 i delta). A non-orthogonality (A at -epsilon / 2, B at +epsilon / 2, drawn
    per pair) and a drawn angle error leave the TOD's spurious P that
    predict.focalplane.delta_p gives, to rounding."""
    schedule = wide_schedule(1)
    pairs = focalplane.on_axis((0.0, 30.0))
    run = dict(evaluation="pixel")
    theta, delta = 0.5, 0.3
    p_sky = plain_sky.maps[1] + 1j * plain_sky.maps[2]
    stats = scanstats.characterise_focalplane(schedule, pairs, 16, per_pair=True, hwp=plate)
    for offset, turn in ((0.0, 2 * theta), (delta, 2 * theta - 4 * delta)):
        shown = dataclasses.replace(plate, angle_offset_deg=offset)
        errors = Systematics(pol_angle_deg=theta)
        maps = engine.simulate_focalplane(plain_sky, schedule, pairs, errors, hwp=shown, **run)
        valid = maps.q_obs != hp.UNSEEN
        got = (maps.q_obs + 1j * maps.u_obs)[valid]
        want = p_sky[maps.pixels[valid]] * np.exp(1j * np.radians(turn))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    bare = engine.simulate_focalplane(plain_sky, schedule, pairs, errors, **run)
    valid = bare.q_obs != hp.UNSEEN
    want = p_sky[bare.pixels[valid]] * np.exp(-2j * np.radians(theta))
    np.testing.assert_allclose((bare.q_obs + 1j * bare.u_obs)[valid], want, atol=1e-9 * 100)
    drawn = Systematics(nonortho_deg={"mean": 2.0, "rms": 1.0}, pol_angle_deg=(0.4, -0.7))
    ideal = engine.simulate_focalplane(plain_sky, schedule, pairs, hwp=plate, **run)
    maps = engine.simulate_focalplane(plain_sky, schedule, pairs, drawn, hwp=plate, **run)
    valid = maps.q_obs != hp.UNSEEN
    got = ((maps.q_obs - ideal.q_obs) + 1j * (maps.u_obs - ideal.u_obs))[valid]
    dp = predict_fp.delta_p(plain_sky, stats, drawn, spread=False)[maps.pixels[valid]]
    np.testing.assert_allclose(dp, got, rtol=0, atol=1e-9 * np.abs(got).max())


SYNC = {"synchronous_muk": (3.0, 5.0), "synchronous_phase_deg": (20.0, -40.0)}


@pytest.mark.parametrize("where", ["on the axis", "hexagon"])
@pytest.mark.parametrize(
    "plate",
    [HWP("continuous", frequency_hz=0.37, **SYNC), HWP("stepped", step="ces", **SYNC)],
    ids=["continuous", "stepped"],
)
def test_the_plates_synchronous_signal_is_its_moments_prediction(plain_sky, plate, where):
    """The plate's 2 chi and 4 chi signal: in the pair differences' map the TOD's spurious P is
    predict.hwp.synchronous_delta_p's from h_{2,2}, h_{2,6} and h_{4,8} (a separate
    binning) to rounding, for pairs on the axis and on a 7-pixel hexagon 10 deg wide, whose pairs
    each on their own samples enter with their own exp(-4 i gamma) (synchronous_weights); the
    4 chi part, common to a pair, leaves it (so A_4 alone leaks nothing). On the axis 0/90
    cancels the 2 chi part with h_2 behind a spinning plate, whose repeats see the same angles,
    to rounding; behind a plate stepped per CES the repeat sees the next angles and keeps it
    (2.2 muK), as predicted."""
    pairs = (
        focalplane.on_axis((0.0, 30.0)) if where == "on the axis" else focalplane.hexagon(7, 10.0)
    )
    for repeats in (1, 2):
        schedule = dataclasses.replace(wide_schedule(1), repeat_boresight_deg=(0.0, 90.0)[:repeats])
        if where == "on the axis":
            _, h = scanstats.hwp_moments(schedule, plate, 16, scanstats.SYNCHRONOUS_TERMS)
            want_all = predict_hwp.synchronous_delta_p(h, plate, pairs.pair_angles_deg)
        else:
            _, h = scanstats.hwp_moments(
                schedule, plate, 16, scanstats.SYNCHRONOUS_TERMS, focalplane=pairs,
                pair_weights=scanstats.synchronous_weights(pairs),
            )  # fmt: skip
            want_all = predict_hwp.synchronous_delta_p(h, plate, None)
        made = {}
        for label, p in (
            ("ideal", dataclasses.replace(plate, synchronous_muk=(0.0, 0.0))),
            ("both", plate),
            ("4f", dataclasses.replace(plate, synchronous_muk=(0.0, 5.0))),
        ):
            maps = engine.simulate_focalplane(plain_sky, schedule, pairs, evaluation="pixel", hwp=p)
            made[label] = maps.q_obs + 1j * maps.u_obs
        valid = maps.q_obs != hp.UNSEEN
        got = (made["both"] - made["ideal"])[valid]
        want = want_all[maps.pixels[valid]]
        np.testing.assert_allclose(made["4f"][valid], made["ideal"][valid], rtol=0, atol=1e-9)
        scale = max(np.abs(want).max(), 1e-3)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * scale)
        cancelled = repeats == 2 and plate.mode == "continuous" and where == "on the axis"
        assert (np.abs(got).max() < 1e-9) == cancelled, (repeats, np.abs(got).max())


JITTER = 2.0  #: the plate's angle jitter of the tests below [deg]


@pytest.mark.parametrize(
    "plate",
    [
        HWP("continuous", frequency_hz=0.37, angle_jitter_deg=JITTER),
        HWP("stepped", angle_jitter_deg=JITTER),
    ],
    ids=["continuous", "stepped"],
)
@pytest.mark.parametrize("where", ["on the axis", "hexagon"])
def test_the_plates_angle_jitter_leaks_as_its_expectation_over_draws(deep_bare, plate, where):
    """The deep example at 1 Hz, pairs at 0 and 30 deg on the axis (so W = <exp(-4 i gamma)> =
    0.5 e^{-i pi / 3} and H_4 = W h_{4,8} enter), or three pairs of a 20 deg hexagon (at 45, 0
    and 45 deg, 10 deg apart: each pair's samples its own draws, through moments of chi - gamma
    / 2), the sky read in each sample's pixel, 16 draws of a 2 deg jitter:

    * the TOD's spurious P less the mean's (mu - 1) P has the variance angle_jitter_leak predicts,
      summed over the solved pixels, within 6 % (measured 1.006 and 1.019 over 40 draws, each draw
      0.87-1.29; on the hexagon 0.979 and 1.004, each 0.80-1.26);
    * the draws' mean is that (mu - 1) P: its distance from it is the noise left in a mean of 16,
      the predicted variance / 16, within 25 % (without the mean's term it would be 4.4 times
      that)."""
    base, sky, _ = deep_bare
    ideal = dataclasses.replace(plate, angle_jitter_deg=0.0)
    if where == "on the axis":
        pairs = focalplane.on_axis((0.0, 30.0))
        hits, h = scanstats.hwp_moments(base, plate, NSIDE, scanstats.JITTER_TERMS)
        angles = pairs.pair_angles_deg
    else:
        pairs = focalplane.hexagon(7, 20.0).subset([0, 1, 2])
        hits, h = scanstats.hwp_moments(
            base, plate, NSIDE, scanstats.JITTER_TERMS, focalplane=pairs, relative=True
        )
        angles = None
    ref = engine.simulate_focalplane(sky, base, pairs, evaluation="pixel", hwp=ideal)
    mask = (ref.rcond > 0.05).astype(float)
    dp, variance, _ = predict_hwp.angle_jitter_leak(
        sky, hits, h, plate, pair_angles_deg=angles, mask=mask
    )
    on = mask > 0
    p_ref = (ref.q + 1j * ref.u)[on]
    np.testing.assert_allclose(dp[on], (np.exp(-8 * np.radians(JITTER) ** 2) - 1) * p_ref)
    draws = np.array(
        [
            (m.q + 1j * m.u)[on] - p_ref
            for m in (
                engine.simulate_focalplane(
                    sky, base, pairs, Systematics(seed=s), evaluation="pixel", hwp=plate
                )
                for s in range(16)
            )
        ]
    )
    want = variance[on].sum()
    assert abs(np.mean(np.sum(np.abs(draws - dp[on]) ** 2, axis=1)) / want - 1) < 0.06
    left = np.sum(np.abs(draws.mean(axis=0) - dp[on]) ** 2)
    assert abs(left / (want / len(draws)) - 1) < 0.25, left / (want / len(draws))


def test_a_constant_plate_jitter_is_its_angle_offset_and_draws_ignore_the_chunks(
    plain_sky, monkeypatch
):
    """The jitter enters as the plate's true angle does: held at 0.5 deg at every sample it gives
    the maps of a 0.5 deg angle offset, to rounding; its draws are keyed by sample, so chunks of
    1000 pair-samples give the maps of one chunk to rounding."""
    schedule = wide_schedule(1)
    pairs = focalplane.on_axis((0.0, 30.0))
    plate = HWP("continuous", frequency_hz=0.37, angle_jitter_deg=1.0)
    run = dict(evaluation="pixel", hwp=plate)
    one = engine.simulate_focalplane(plain_sky, schedule, pairs, **run)
    chunked = engine.simulate_focalplane(plain_sky, schedule, pairs, chunk_samples=1000, **run)
    np.testing.assert_allclose(chunked.q, one.q, rtol=0, atol=1e-9)
    assert (
        np.abs(
            one.q
            - engine.simulate_focalplane(
                plain_sky,
                schedule,
                pairs,
                evaluation="pixel",
                hwp=dataclasses.replace(plate, angle_jitter_deg=0.0),
            ).q
        ).max()
        > 1e-3
    )
    monkeypatch.setattr(
        engine.focalplane, "angle_jitter", lambda hwp, seed, first, n: np.full(n, np.radians(0.5))
    )
    held = engine.simulate_focalplane(plain_sky, schedule, pairs, **run)
    offset = dataclasses.replace(plate, angle_jitter_deg=0.0, angle_offset_deg=0.5)
    want = engine.simulate_focalplane(plain_sky, schedule, pairs, evaluation="pixel", hwp=offset)
    np.testing.assert_allclose(held.q, want.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(held.u, want.u, rtol=0, atol=1e-9)
