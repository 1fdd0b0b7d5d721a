"""The half-wave plate: its angles over a schedule, and a detector's I, Q, U weights through it
against TOAST's own StokesWeights with a continuous and a stepped HWP, on a
schedule of December 2026. The TOAST tests skip where it is not installed."""

import dataclasses

import healpy as hp
import numpy as np
import pytest
from helpers import EXAMPLES, T0, toast_december_schedule

from boresight import engine, focalplane, harmonics, hwp, pointing, scanstats, spectra
from boresight.beams import Beam, BeamConvolver, turned
from boresight.cli import main
from boresight.constants import ARCMIN
from boresight.cosmology import load_spectra
from boresight.hwp import HWP
from boresight.instrument import Instrument, Spread, Systematics
from boresight.predict import focalplane as predict_fp
from boresight.schedule import CES, Schedule, Site, load_schedule
from boresight.sky import Sky, SkyConfig, make_sky
from boresight.validation import ConfigError

RATE = 5.0  #: samples per second of the TOAST simulation
RPM = 88.0  #: the continuous HWP's revolutions per minute there


def _wrap(x):
    return (x + np.pi) % (2 * np.pi) - np.pi


@pytest.fixture(scope="module")
def toast_hwp(tmp_path_factory):
    """TOAST's SimGround with a continuous HWP, its PointingDetectorSimple and StokesWeights
    (IQU, with the HWP and without) for a 7-pixel hexagon: per observation, its detectors'
    quaternions, gamma, the HWP angle and both sets of weights."""
    pytest.importorskip("toast")
    import toast
    import toast.ops
    from astropy import units as u
    from toast.instrument import GroundSite, Telescope
    from toast.instrument_sim import fake_hexagon_focalplane

    d = tmp_path_factory.mktemp("toast_hwp")
    schedule = toast_december_schedule(d)
    schedule.scans = schedule.scans[:4]
    fp = fake_hexagon_focalplane(n_pix=7, width=10 * u.deg, sample_rate=RATE * u.Hz)
    site = GroundSite(schedule.site_name, schedule.site_lat, schedule.site_lon, schedule.site_alt)
    data = toast.Data(toast.mpi.Comm())
    telescope = Telescope("sat", focalplane=fp, site=site)
    toast.ops.SimGround(
        telescope=telescope, schedule=schedule, hwp_angle="hwp_angle", hwp_rpm=RPM
    ).apply(data)
    detector_pointing = toast.ops.PointingDetectorSimple()
    detector_pointing.apply(data)

    def weights(name, **hwp_keys):
        toast.ops.StokesWeights(
            mode="IQU", detector_pointing=detector_pointing, weights=name, **hwp_keys
        ).apply(data)

    weights("bare")
    weights("continuous", hwp_angle="hwp_angle", fp_gamma="gamma")
    out = []
    for ob in data.obs:
        dets = list(ob.local_detectors)
        out.append(
            dict(
                times=np.array(ob.shared["times"]),
                chi=np.array(ob.shared["hwp_angle"]),
                quats={det: np.array(ob.detdata["quats"][det]) for det in dets},
                gamma={det: fp[det]["gamma"].to_value(u.rad) for det in dets},
                bare={det: np.array(ob.detdata["bare"][det]) for det in dets},
                continuous={det: np.array(ob.detdata["continuous"][det]) for det in dets},
            )
        )
    # a stepped HWP: TOAST 3.0.6's own stepping (SimGround's hwp_step) stops with a
    # UnitConversionError, so the angles are set here, one per observation, and its
    # StokesWeights run on them
    steps = np.radians([0.0, 22.5, 45.0, 67.5])
    for i, ob in enumerate(data.obs):
        ob.shared["hwp_angle"].set(np.full(ob.n_local_samples, steps[i % 4]), offset=(0,))
        out[i]["stepped_chi"] = steps[i % 4]
    weights("stepped", hwp_angle="hwp_angle", fp_gamma="gamma")
    for ob, one in zip(data.obs, out):
        one["stepped"] = {det: np.array(ob.detdata["stepped"][det]) for det in ob.local_detectors}
    return out


def test_stokes_weights_equal_toasts_with_and_without_a_hwp(toast_hwp):
    """boresight's weights from its crossing angle psi = TOAST's detector angle alpha - gamma +
    pi (the relation tests/test_focalplane.py checks against PointingDetectorSimple) equal TOAST's
    StokesWeights to 1e-10: bare, behind a continuously turning HWP and behind a stepped one."""
    from toast import qarray

    worst = {"bare": 0.0, "continuous": 0.0, "stepped": 0.0}
    for ob in toast_hwp:
        for det, q in ob["quats"].items():
            alpha = qarray.to_iso_angles(q)[2]
            gamma = ob["gamma"][det]
            psi = alpha - gamma + np.pi
            for kind, chi in (
                ("bare", None),
                ("continuous", ob["chi"]),
                ("stepped", np.full(psi.size, ob["stepped_chi"])),
            ):
                ours = hwp.stokes_weights(psi, gamma, chi)
                worst[kind] = max(worst[kind], np.abs(ours - ob[kind][det]).max())
    assert max(worst.values()) < 1e-10, worst
    # and the HWP matters: a detector's Q weight behind it is not the bare one
    det = next(iter(toast_hwp[0]["quats"]))
    assert np.abs(toast_hwp[0]["continuous"][det][:, 1] - toast_hwp[0]["bare"][det][:, 1]).max() > 1


def test_a_continuous_hwp_turns_as_toasts(toast_hwp):
    """chi advances by 2 pi f / rate per sample as TOAST's SimGround's (to its own rounding of the
    sample rate, 1e-6 rad); its phase at an observation's first sample differs from 2 pi f t by
    less than one sample's turn, TOAST's rounding of the observation's start to a whole sample."""
    f = RPM / 60.0
    one = HWP("continuous", frequency_hz=f)
    for ob in toast_hwp:
        t, chi = ob["times"], ob["chi"]
        ces = CES(float(t[0]), t.size / RATE, 50.0, 180.0, 10.0)
        schedule = Schedule((ces,), Site(-22.958, -67.787, 5200.0), RATE)
        ours = hwp.chunk_angles(one, schedule, 0, 0, first=0, n=t.size)
        assert abs(_wrap(ours[0] - 2 * np.pi * f * t[0])) < 1e-5
        moved = _wrap((chi - chi[0]) - (ours - ours[0]))
        assert np.abs(moved).max() < 1e-6
        assert abs(_wrap(chi[0] - ours[0])) < 2 * np.pi * f / RATE


def _schedule(starts, repeats=(0.0,)):
    """One-minute CESs turning around for 2 s at each end of their 10 deg throws."""
    ces = tuple(CES(T0 + s, 60.0, 50.0, 180.0, 10.0, turnaround_s=2.0) for s in starts)
    return Schedule(ces, Site(-22.958, -67.787, 5200.0), 2.0, repeat_boresight_deg=repeats)


def _chi_per_ces(schedule, one):
    """The HWP's angles of each (repeat, CES), from the pointing's own stream."""
    seen = {}
    for repeat, index, args in pointing.ces_chunks(schedule, 50):
        chi = hwp.chunk_angles(one, schedule, repeat, index, first=args[0], n=args[1])
        seen.setdefault((repeat, index), set()).update(np.round(np.degrees(chi), 9))
    return seen


def test_a_stepped_hwp_steps_per_ces_day_or_repeat():
    day = 86400.0
    schedule = _schedule([0.0, 3600.0, day, day + 3600.0], repeats=(0.0, 90.0))
    expect = {
        "ces": [0.0, 22.5, 45.0, 67.5, 0.0, 22.5, 45.0, 67.5],
        "day": [0.0, 0.0, 22.5, 22.5, 45.0, 45.0, 67.5, 67.5],
        "repeat": [0.0, 0.0, 0.0, 0.0, 22.5, 22.5, 22.5, 22.5],
    }
    for step, angles in expect.items():
        seen = _chi_per_ces(schedule, HWP("stepped", step=step))
        assert [s.pop() for s in seen.values()] == angles, step
        assert all(not s for s in seen.values())  # one angle per CES
    # four steps of 22.5 deg cancel exp(4 i chi), as a 0/90 rotation cancels exp(2 i psi)
    chi = np.radians(expect["ces"][:4])
    assert abs(np.mean(np.exp(4j * chi))) < 1e-15


def test_the_pointing_carries_the_hwp_angle_and_keeps_its_own_numbers():
    schedule = dataclasses.replace(_schedule([0.0, 600.0]), turnarounds="exclude")
    bare = [np.concatenate(x) for x in zip(*pointing.pointing(schedule, 37))]
    with_hwp = [
        np.concatenate(x)
        for x in zip(*pointing.pointing(schedule, 37, hwp=HWP("continuous", frequency_hz=1.3)))
    ]
    for a, b in zip(bare, with_hwp):
        np.testing.assert_array_equal(a, b)
    whole = [
        np.concatenate(x)
        for x in zip(*pointing.pointing(schedule, 1 << 20, hwp=HWP("continuous", frequency_hz=1.3)))
    ]
    np.testing.assert_array_equal(whole[3], with_hwp[3])  # the chunks do not change it
    assert with_hwp[3].size == bare[0].size < schedule.n_samples  # no turnarounds in either


@pytest.mark.parametrize(
    "keys, message",
    [
        (dict(mode="spinning"), "allowed"),
        (dict(mode="continuous", frequency_hz=0.0), "frequency"),
        (dict(mode="stepped", angles_deg=()), "angles"),
        (dict(mode="stepped", angles_deg=(0.0, float("nan"))), "angles"),
        (dict(mode="stepped", step="hour"), "step"),
        (dict(mode="continuous", ip=float("nan")), "ip"),
        (dict(mode="continuous", angle_offset_deg=50.0), "angle_offset_deg must be >= -45"),
        (dict(mode="continuous", synchronous_muk=(1.0,)), "2 numbers"),
        (dict(mode="continuous", synchronous_phase_deg=(0.0, float("inf"))), "synchronous_phase"),
        # a bool is no number: true was taken as 1
        (dict(mode="continuous", ip=True), "hwp ip must be a number"),
        (dict(mode="continuous", frequency_hz=True), "hwp frequency_hz must be a number"),
        # a string is no list: "045" was read as steps of 0, 4 and 5 deg
        (dict(mode="stepped", angles_deg="045"), "a list of numbers"),
        # past ten turns the modulo leaves no digits; 1e308 Hz overflowed
        (dict(mode="stepped", angles_deg=(0.0, 1e300)), "angles_deg must be >= -3600"),
        (dict(mode="continuous", phase_deg=1e300), "phase_deg must be >= -3600"),
        (dict(mode="continuous", frequency_hz=1e308), "frequency_hz must be >= 0"),
        (dict(mode="continuous", ip=1e300), "ip must be >= -1"),
        (dict(mode="continuous", synchronous_muk=(1e300, 1.0)), "synchronous_muk must be"),
    ],
)
def test_a_bad_hwp_is_one_clear_error(keys, message):
    with pytest.raises(ConfigError, match=message):
        HWP(**keys)


def test_hwp_moments_are_the_h_n_times_the_hwp_average_of_a_stepped_plate():
    """With the CES set repeated at one boresight angle and the HWP stepped per repeat, every
    pixel sees the same psi in each repeat, so h_{n,m} = h_n mean_k exp(i m chi_k) exactly; h_{n,0}
    is the fused kernel's h_n (scanstats.characterise_schedule)."""
    schedule = _schedule([0.0, 600.0], repeats=(0.0, 0.0))
    plate = HWP("stepped", angles_deg=(0.0, 30.0), step="repeat")
    hits, h = scanstats.hwp_moments(schedule, plate, 16)
    stats = scanstats.characterise_schedule(schedule, 16)
    np.testing.assert_array_equal(hits, stats.hits)
    seen = hits > 0
    for (n, m), moment in h.items():
        average = np.mean(np.exp(1j * m * np.radians([0.0, 30.0])))
        np.testing.assert_allclose(moment[seen], stats.h[n, seen] * average, atol=1e-12)
        assert np.all(moment[~seen] == 0)
    assert (
        np.abs(h[(2, 4)][seen]).max() > 0.1 and abs(np.mean(np.exp(4j * np.radians([0, 30])))) > 0.4
    )
    # four steps of 22.5 deg cancel m = 4 and 8 wherever the repeats see the sky alike
    four = dataclasses.replace(schedule, repeat_boresight_deg=(0.0,) * 4)
    _, h4 = scanstats.hwp_moments(four, HWP("stepped", step="repeat"), 16, terms=((2, -4), (1, 8)))
    assert max(np.abs(v).max() for v in h4.values()) < 1e-14


def test_hwp_moments_of_a_continuous_plate_bin_as_numpy_does():
    schedule = _schedule([0.0, 600.0])
    plate = HWP("continuous", frequency_hz=0.7, phase_deg=10.0)
    terms = ((2, -4), (0, 4), (3, 8))
    hits, h = scanstats.hwp_moments(schedule, plate, 16, terms, chunk_samples=33)
    theta, phi, psi, chi = (np.concatenate(x) for x in zip(*pointing.pointing(schedule, hwp=plate)))
    pix = hp.ang2pix(16, theta, phi)
    np.testing.assert_array_equal(hits, np.bincount(pix, minlength=hits.size))
    for n, m in terms:
        w = np.exp(1j * (n * psi + m * chi))
        sums = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
        np.testing.assert_allclose(
            h[(n, m)], np.where(hits > 0, sums / np.maximum(hits, 1), 0), atol=1e-12
        )
    with pytest.raises(ValueError, match="repeated"):
        scanstats.hwp_moments(schedule, plate, 16, ((2, -4), (2, -4)))
    with pytest.raises(ValueError, match="continuous or a stepped"):
        scanstats.hwp_moments(schedule, HWP(), 16)
    pairs = focalplane.hexagon(7, 10.0)
    for bad, words in (
        (dict(pair_weights=np.ones((7, 3))), "give focalplane"),
        (dict(focalplane=pairs, pair_weights=np.ones((7, 2))), r"pair_weights: shape \(7, 2\)"),
        (dict(focalplane=pairs, relative=True, pair_weights=np.ones((7, 3))), "not with pair"),
    ):
        with pytest.raises(ValueError, match=words):
            scanstats.hwp_moments(schedule, plate, 16, terms, **bad)


def _schedule_file(path):
    path.write_text(
        "sample_rate_hz = 2.0\nrepeat_boresight_deg = [0.0, 90.0]\n"
        + "".join(
            f"[[ces]]\nstart_unix = {T0 + 3600 * i}\nduration_s = 600\n"
            f"elevation_deg = 50\naz_centre_deg = {134 if i % 2 else 226}\naz_throw_deg = 40\n"
            for i in range(2)
        )
    )
    return str(path)


def test_scan_stats_writes_the_hwp_moments(tmp_path):
    """hwp_moments.fits holds the library's h_{n,m} (RE_2_M4 is Re h_{2,-4}); litebird_sim's
    layout holds them too, read as its load_h_map_from_file reads them."""
    import h5py
    from astropy.io import fits

    path = _schedule_file(tmp_path / "s.toml")
    flags = ["--nside", "16", "--hwp", "continuous", "--hwp-frequency", "0.7"]
    assert main(["-q", "scan-stats", path, "--out", str(tmp_path / "a"), *flags]) == 0
    plate = HWP("continuous", frequency_hz=0.7)
    hits, h = scanstats.hwp_moments(load_schedule(path), plate, 16)
    seen = hits > 0
    table = fits.getdata(tmp_path / "a" / "hwp_moments.fits", 1)
    for (n, m), name in (((2, -4), "2_M4"), ((4, 8), "4_8"), ((0, 4), "0_4")):
        re_, im_ = (table[f"{p}_{name}"].ravel().astype(float) for p in ("RE", "IM"))
        np.testing.assert_allclose(re_[seen] + 1j * im_[seen], h[(n, m)][seen], atol=1e-6)
        assert np.all(re_[~seen] == hp.UNSEEN)
    out = tmp_path / "lb"
    galactic = ["--format", "litebird", "--frame", "galactic", "--hwp", "stepped"]
    assert main(["-q", "scan-stats", path, "--out", str(out), "--nside", "16", *galactic]) == 0
    schedule = load_schedule(path, frame="galactic")
    hits, h = scanstats.hwp_moments(schedule, HWP("stepped"), 16)
    with h5py.File(out / "h_maps_det_boresight.h5", "r") as f:
        assert f.attrs["coordinate_system"] == "Galactic" and f.attrs["det"] == "boresight"
        assert f.attrs["sampling_rate_Hz"] == 2.0 and f.attrs["duration_s"] == 2 * 2 * 600
        assert {f.attrs["detector_split"], f.attrs["time_split"]} == {"full"}
        read = {tuple(map(int, k.split(","))): f[k]["Re"][:] + 1j * f[k]["Im"][:] for k in f}
    np.testing.assert_array_equal(read.pop((0, 0)).real, hits)
    assert set(read) == set(h) - {(0, 0)}
    for key, moment in read.items():
        np.testing.assert_allclose(moment, h[key], atol=1e-12)


def test_scan_stats_refuses_what_the_layouts_cannot_hold(tmp_path, capsys):
    path = _schedule_file(tmp_path / "s.toml")
    for flags, words in (
        (["--format", "litebird"], "Galactic"),
        (["--hwp", "stepped", "--format", "so"], "--hwp"),
        (["--hwp", "stepped", "--hwp-angles", "0,x"], "--hwp-angles"),
        (["--hwp", "continuous", "--hwp-frequency", "-1"], "frequency"),
    ):
        out = tmp_path / "bad"
        assert main(["-q", "scan-stats", path, "--out", str(out), "--nside", "8", *flags]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1 and not out.exists(), (flags, err)


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


def test_the_pointing_moments_behind_a_plate_are_its_hwp_moments():
    """scanstats.pointing_behind against scanstats.hwp_moments (the plate's angle chi, not
    chi - gamma) of each pair of a 7-pixel hexagon behind a spinning plate: exp(-i m gamma)
    h_{n,m} to 1e-12; and its offset-weighted moments against the samples' offsets binned by hand
    with numpy."""
    schedule = _wide_schedule(2)
    plate = HWP("continuous", frequency_hz=0.37)
    hexagon = focalplane.hexagon(7, 10.0)
    got = scanstats.pointing_behind(schedule, hexagon, plate, 16)
    plain = [(n, m) for n, m, offset in scanstats.POINTING_BEHIND_TERMS if offset is None]
    pairs = {}
    scanstats.hwp_moments(
        schedule, plate, 16, plain, focalplane=hexagon,
        each=lambda i, hits, h: pairs.update({i: (hits, h)}),
    )  # fmt: skip
    chunks = list(pointing.detector_pointing(schedule, hexagon, hwp=plate))
    for i, gamma in enumerate(np.radians(hexagon.gamma_deg)):
        hits, h = pairs[i]
        for k, (n, m, offset) in enumerate(scanstats.POINTING_BEHIND_TERMS):
            if offset is None:
                want = np.exp(-1j * m * gamma) * h[n, m]
                np.testing.assert_allclose(got[i, k], want, rtol=0, atol=1e-12)
        theta, phi, psi = (np.concatenate([c[j][i] for c in chunks]) for j in range(3))
        chi = np.concatenate([c[3] for c in chunks])
        pix = hp.ang2pix(16, theta, phi)
        c_theta, c_phi = hp.pix2ang(16, pix)
        delta = (theta - c_theta) + 1j * np.sin(c_theta) * (
            (phi - c_phi + np.pi) % (2 * np.pi) - np.pi
        )
        seen = hits > 0
        w = np.exp(1j * (psi + 4 * (chi - gamma))) * delta  # "g1 delta"
        want = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
        k = scanstats.POINTING_BEHIND_TERMS.index((1, 4, "delta"))
        np.testing.assert_allclose(
            got[i, k, seen], want[seen] / hits[seen], atol=hp.nside2resol(16) ** 2
        )
        assert np.abs(got[i, k]).max() > 0.01 * hp.nside2resol(16)


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
        predict_fp.ip_delta_p_across(sky, stats, HWP("stepped", ip=1e-3))
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


def test_the_beam_moments_behind_a_plate_are_its_hwp_moments():
    """scanstats.beams_behind's unweighted moments against scanstats.hwp_moments of each pair of
    a 7-pixel hexagon behind a spinning plate, exp(-i m gamma) h_{n,m}, to 1e-12; its offset
    weights are pointing_behind's (the same binning, tested above)."""
    schedule = _wide_schedule(2)
    plate = HWP("continuous", frequency_hz=0.37)
    hexagon = focalplane.hexagon(7, 10.0)
    got = scanstats.beams_behind(schedule, hexagon, plate, 16)
    plain = [
        (k, (n, m)) for k, (n, m, offset) in enumerate(scanstats.BEAM_BEHIND_TERMS) if not offset
    ]
    pairs = {}
    scanstats.hwp_moments(
        schedule, plate, 16, [nm for _, nm in plain], focalplane=hexagon,
        each=lambda i, hits, h: pairs.update({i: h}),
    )  # fmt: skip
    for i, gamma in enumerate(np.radians(hexagon.gamma_deg)):
        for k, (n, m) in plain:
            want = np.exp(-1j * m * gamma) * pairs[i][n, m]
            np.testing.assert_allclose(got[i, k], want, rtol=0, atol=1e-12)
    assert got.shape == (7, 44, 12 * 16**2) and np.abs(got[:, -1]).max() > 0


def test_the_focal_planes_moments_behind_a_plate_are_each_computed_once():
    """characterise_focalplane with the pointing's and the beams' moments keeps each (n, m,
    offset) once (the pointing's second order shares the beams' T part: 53 maps per pair, not
    75), and FocalPlaneStats.behind reads them as pointing_behind and beams_behind give them."""
    schedule = _wide_schedule(1)
    plate = HWP("continuous", frequency_hz=0.37)
    pairs = focalplane.hexagon(7, 10.0).subset([0, 3])
    stats = scanstats.characterise_focalplane(
        schedule, pairs, 16, per_pair=True, hwp=plate, pointing=True, beams=True
    )
    assert len(stats.behind_terms) == stats.pair_behind_h.shape[1] == 53
    for terms, alone in (
        (scanstats.POINTING_BEHIND_TERMS, scanstats.pointing_behind(schedule, pairs, plate, 16)),
        (scanstats.BEAM_BEHIND_TERMS, scanstats.beams_behind(schedule, pairs, plate, 16)),
    ):
        assert stats.has_behind(terms)
        for k, term in enumerate(terms):
            np.testing.assert_array_equal(stats.behind(*term), alone[:, k])


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


def test_the_reflected_angle_moments_are_the_hwp_moments():
    """A pair at gamma behind the HWP has moments <exp(i n (psi + 2 chi - 2 gamma))> =
    exp(-2 i n gamma) h_{n,2n}: the focal plane's fused kernel with the HWP against
    scanstats.hwp_moments, to rounding, for a continuous and a stepped plate."""
    schedule = _schedule([0.0, 600.0], repeats=(0.0, 90.0))
    pairs = focalplane.on_axis((0.0, 22.5, 45.0))
    for plate in (HWP("continuous", frequency_hz=0.61), HWP("stepped", step="ces")):
        stats = scanstats.characterise_focalplane(schedule, pairs, 16, per_pair=True, hwp=plate)
        hits, h = scanstats.hwp_moments(schedule, plate, 16, [(n, 2 * n) for n in range(1, 5)])
        for i, gamma in enumerate(np.radians(pairs.gamma_deg)):
            np.testing.assert_array_equal(stats.pair_hits[i], hits)
            for n in range(1, 5):
                turned = np.exp(-2j * n * gamma) * h[(n, 2 * n)]
                np.testing.assert_allclose(stats.pair_h[i, n], turned, atol=1e-12)


def test_the_hwp_moments_progress_ends_at_the_schedules_samples(capsys):
    """With the turnarounds excluded their samples are never yielded; the bar still ends full."""
    schedule = dataclasses.replace(_schedule([0.0, 600.0]), turnarounds="exclude")
    scanstats.hwp_moments(schedule, HWP("stepped"), 8, progress=True)
    err = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{schedule.n_samples}/{schedule.n_samples} " in err, err


def test_a_focal_planes_hwp_moments_are_its_pairs_own():
    """Off the axis each pair has its own samples: scanstats.hwp_moments with a focal plane (one
    pair at a time through detector_pointing) against the focal plane's fused kernel with the
    HWP (characterise_focalplane's reflected-angle moments, exp(-2 i n gamma) h_{n,2n} of each
    pair) to rounding, for every pair of a 7-pixel hexagon 10 deg wide; the combination is the
    hit-weighted mean of the pairs' own."""
    schedule = _schedule([0.0, 600.0], repeats=(0.0, 90.0))
    pairs = focalplane.hexagon(7, 10.0)
    plate = HWP("continuous", frequency_hz=0.61)
    stats = scanstats.characterise_focalplane(schedule, pairs, 16, per_pair=True, hwp=plate)
    terms = [(n, 2 * n) for n in range(1, 5)]
    own = {}
    hits, h = scanstats.hwp_moments(
        schedule, plate, 16, terms, focalplane=pairs, each=lambda i, n, m: own.update({i: (n, m)})
    )
    assert sorted(own) == list(range(7)) and len({int(o[0].sum()) for o in own.values()}) == 1
    np.testing.assert_array_equal(hits, stats.combined.hits)
    for i, gamma in enumerate(np.radians(pairs.gamma_deg)):
        np.testing.assert_array_equal(own[i][0], stats.pair_hits[i])
        for n in range(1, 5):
            turned = np.exp(-2j * n * gamma) * own[i][1][(n, 2 * n)]
            np.testing.assert_allclose(stats.pair_h[i, n], turned, atol=1e-12)
    weighted = sum(o[0] * o[1][(2, 4)] for o in own.values()) / np.maximum(hits, 1)
    np.testing.assert_allclose(h[(2, 4)], weighted, atol=1e-12)
    assert np.count_nonzero(own[0][0] != own[1][0]) > 5  # off the axis: their own pixels


def test_scan_stats_writes_each_detectors_hwp_moments_in_litebird_sims_layout(tmp_path):
    """scan-stats --focalplane --hwp --format litebird: one file per detector, both of a pair
    holding its moments, and the focal plane's combination as det "focalplane" (the writer's
    files against litebird_sim's own reader: tests/test_litebird_maps.py)."""
    import h5py

    path = _schedule_file(tmp_path / "s.toml")
    out = tmp_path / "lb"
    flags = ["--format", "litebird", "--frame", "galactic", "--hwp", "stepped"]
    flags += ["--focalplane", "hexagon:7:10", "--nside", "16"]
    assert main(["-q", "scan-stats", path, "--out", str(out), *flags]) == 0
    schedule = load_schedule(path, frame="galactic")
    pairs = focalplane.hexagon(7, 10.0)
    own = {}
    hits, h = scanstats.hwp_moments(
        schedule, HWP("stepped"), 16, focalplane=pairs, each=lambda i, n, m: own.update({i: (n, m)})
    )

    def read(det):
        with h5py.File(out / f"h_maps_det_{det}.h5", "r") as f:
            assert f.attrs["det"] == det
            return {tuple(map(int, k.split(","))): f[k]["Re"][:] + 1j * f[k]["Im"][:] for k in f}

    for i, detectors in enumerate(pairs.detectors):
        for det in detectors:
            got = read(det)
            np.testing.assert_array_equal(got.pop((0, 0)).real, own[i][0])
            for key, moment in got.items():
                np.testing.assert_allclose(moment, own[i][1][key], atol=1e-12)
    combined = read("focalplane")
    np.testing.assert_array_equal(combined.pop((0, 0)).real, hits)
    for key, moment in combined.items():
        np.testing.assert_allclose(moment, h[key], atol=1e-12)


def _study_behind(instrument, rotations=(0.0,)):
    from boresight.config import parse_study

    return parse_study(
        {
            "sky": {"nside": 64, "lmax": 191, "fwhm_arcmin": 60.0, "seed": 4},
            "scan": {"n_phi": 4, "range_rad": 0.7, "seed": 2, "rotations_deg": list(rotations)},
            "instrument": instrument,
            "systematics": {"dg": [0.01, -0.01]},
            "mask": {"survey": "deep"},
            "output": {"lmax": 128},
        }
    )


def test_a_study_behind_a_hwp_is_the_bare_study_that_sees_the_sky_alike():
    """[instrument] hwp: the pairs' angles mirrored, and psi + 2 chi uniform per hit
    (continuous) or each repeat turned by 2 chi_k (stepped). A continuous HWP takes the
    paper's gain leak down to its white floor (16x less at 30 <= ell < 50 here), predicted
    within 0.75-1.35 of the one simulated sky in every band (measured 0.90-1.24); four steps of
    22.5 deg over four repeats cancel it, as exp(4 i chi) and exp(8 i chi) average to 0."""
    from boresight import residual

    edges = np.array([30, 50, 80, 129])

    def leak(study):
        job, _, _ = residual.from_study(study)
        binned = (
            spectra.bin_spectrum(x, edges)[1] for x in (job.auto, job.total, job.predicted_cl)
        )
        return tuple(binned)

    continuous = _study_behind({"hwp": "continuous"})
    assert continuous.instrument.pair_angles_deg == (0.0, -45.0)
    assert continuous.scan.range_rad == 2 * np.pi and continuous.hwp.mode == "continuous"
    bare, _, _ = leak(_study_behind({}))
    auto, total, predicted = leak(continuous)
    assert auto[0] < bare[0] / 5
    assert np.all((0.75 < predicted / total) & (predicted / total < 1.35)), predicted / total
    steps = {"hwp": "stepped", "hwp_angles_deg": [0.0, 22.5, 45.0, 67.5]}
    stepped = _study_behind(steps, rotations=(0.0,) * 4)
    assert stepped.scan.rotations_deg == (0.0, 45.0, 90.0, 135.0)
    assert np.all(leak(stepped)[0] < 1e-25 * bare)


def test_a_study_refuses_what_its_hwp_cannot_carry(tmp_path, capsys):
    body = "[sky]\nnside = 16\nlmax = 32\n[systematics]\n{sys}\n[instrument]\n{inst}\n"
    for sys_, inst, words in (
        ("rho_arcmin = 1.0", "hwp = 'continuous'", "rho_arcmin behind a HWP"),
        ("dg = 0.01", "hwp = 'spinning'", "allowed"),
        ("dg = 0.01", "hwp_angles_deg = [0.0, 45.0]", "needs hwp = 'stepped'"),
        ("dg = 0.01", "hwp = 'stepped'\nhwp_angles_deg = []", "angles"),
    ):
        study = tmp_path / "s.toml"
        study.write_text(body.format(sys=sys_, inst=inst))
        assert main(["-q", "predict", str(study)]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, (inst, err)


def _wide_schedule(repeats):
    """One 10-minute CES over a 60 deg throw, its set repeated ``repeats`` times."""
    ces = (CES(T0, 600.0, 50.0, 180.0, 60.0, turnaround_s=2.0),)
    return Schedule(ces, Site(-22.958, -67.787, 5200.0), 2.0, repeat_boresight_deg=(0.0,) * repeats)


def _iqu(maps):
    return np.array([maps.i_obs, maps.q_obs, maps.u_obs])


@pytest.fixture(scope="module")
def plain_sky():
    return make_sky(SkyConfig(nside=16, lmax=32, fwhm_arcmin=120.0, seed=4))


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
            sky, _wide_schedule(4), pairs, evaluation="pixel", hwp=plate, mapmaker=mapmaker
        )
        valid = maps.q_obs != hp.UNSEEN
        assert maps.pixels.size > 15 and valid[maps.hits_obs >= 20].all(), mapmaker
        assert mapmaker == "detectors" or maps.rcond_obs.min() > 0.3
        want = sky.maps[:, maps.pixels[valid]]
        scale = np.abs(want).max()
        np.testing.assert_allclose(_iqu(maps)[:, valid], want, rtol=0, atol=1e-10 * scale)
    bare = engine.simulate_focalplane(
        sky, _wide_schedule(1), focalplane.on_axis((0.0,)), evaluation="pixel", mapmaker="single"
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
    schedule = _wide_schedule(1)
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
    schedule = _schedule([0.0])
    chunks = pointing.pointing(schedule, 1 << 16)
    with pytest.raises(ValueError, match="CPU backend only"):
        engine.simulate_samples(plain_sky, chunks, backend="gpu", mapmaker="detectors")
    with pytest.raises(ValueError, match="mapmaker must be one of"):
        engine.simulate_samples(plain_sky, chunks, mapmaker="demodulated")


IP = {"ip": 1e-3, "ip_phase_deg": 30.0}


@pytest.mark.parametrize(
    "plate",
    [HWP("continuous", frequency_hz=0.37, **IP), HWP("stepped", step="repeat", **IP)],
    ids=["continuous", "stepped"],
)
def test_the_plates_instrumental_polarisation_is_its_moments_prediction(plain_sky, plate):
    """The sky read in each sample's pixel: the TOD's spurious P of the plate's IP, in the pair
    differences' map and in both detectors' own, is predict.focalplane.ip_delta_p's from the
    boresight's h_{2,0}, h_{2,8} and h_{4,8} (scanstats.hwp_moments, a separate binning) to
    rounding; detector A alone's, which solves I beside P, is its 3x3 prediction (with h_{0,4}
    and h_{2,4}) to rounding too."""
    schedule = _wide_schedule(4)
    pairs = focalplane.on_axis((0.0, 30.0))

    def dp(mapmaker, with_plate):
        maps = engine.simulate_focalplane(
            plain_sky, schedule, pairs, evaluation="pixel", hwp=with_plate, mapmaker=mapmaker
        )
        return maps, maps.q_obs + 1j * maps.u_obs

    ideal = dataclasses.replace(plate, ip=0.0)
    hits, h = scanstats.hwp_moments(schedule, plate, 16, predict_fp.SINGLE_IP_TERMS)
    angles = pairs.pair_angles_deg
    for mapmaker in ("pairs", "detectors", "single"):
        want_all = predict_fp.ip_delta_p(
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
    schedule = _wide_schedule(2)
    hexagon = focalplane.hexagon(7, 10.0)
    ideal = dataclasses.replace(plate, ip=0.0)
    _, h = scanstats.hwp_moments(
        schedule, plate, 16, predict_fp.SINGLE_IP_TERMS, focalplane=hexagon, relative=True
    )
    _, boresight_h = scanstats.hwp_moments(schedule, plate, 16, predict_fp.SINGLE_IP_TERMS)
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
        want = predict_fp.ip_delta_p(plain_sky, h, plate, None, mapmaker=mapmaker, spread=False)
        assert np.abs(want).max() > 1e-3 * 1e-2, mapmaker
        np.testing.assert_allclose(got, want[pixels], rtol=0, atol=1e-9 * np.abs(want).max())
        on_axis = predict_fp.ip_delta_p(
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
    hits, h = scanstats.hwp_moments(schedule, plate, NSIDE, predict_fp.SINGLE_IP_TERMS)
    for mapmaker in ("pairs", "single"):
        predicted = predict_fp.ip_delta_p(sky, h, plate, pairs.pair_angles_deg, mapmaker=mapmaker)
        measured, bb = _ip_leak(schedule, sky, pairs, plate, mapmaker)
        if repeats == (0.0, 90.0):
            assert measured.max() < 1e-28, measured
            continue
        assert measured.min() > 1e-10, measured  # epsilon^2 T^2 h_{2,0}^2 of a 1e-3 plate
        np.testing.assert_allclose(bb(predicted) / measured, 1.0, atol=0.10)
    if plate.mode == "stepped":  # the pairs' 2x2 misses detector A's I row
        pairs_only = bb(predict_fp.ip_delta_p(sky, h, plate, pairs.pair_angles_deg)) / measured
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
        schedule, plate, NSIDE, predict_fp.SINGLE_IP_TERMS, focalplane=pairs, relative=True
    )
    for mapmaker in ("pairs", "single"):
        measured, bb = _ip_leak(schedule, sky, pairs, plate, mapmaker)
        predicted = bb(predict_fp.ip_delta_p(sky, h, plate, None, mapmaker=mapmaker))
        assert measured.min() > 1e-10, measured
        np.testing.assert_allclose(predicted / measured, 1.0, atol=0.10)


def test_a_plate_whose_modulation_aliases_to_a_constant_is_one_clear_error():
    """A 2 Hz plate sampled at 1 Hz (or 8 Hz) sits at one 4 chi in every sample: refused."""
    for rate in (1.0, 8.0):
        schedule = dataclasses.replace(_schedule([0.0]), sample_rate_hz=rate)
        with pytest.raises(ConfigError, match="aliases to a constant"):
            next(pointing.pointing(schedule, hwp=HWP("continuous", frequency_hz=2.0)))
    next(pointing.pointing(_schedule([0.0]), hwp=HWP("continuous", frequency_hz=0.37)))


def test_a_plate_angle_offset_turns_the_maps_by_four_times_it(plain_sky):
    """A plate whose true angle is delta = 0.5 deg off the map-maker's: behind it the maps are the
    sky's P turned by exp(-4 i delta) to rounding (the sky read in each sample's pixel), and
    predict.focalplane.delta_p, with the offset as a 2 delta angle error of every pair at its
    reflected angle, gives the same spurious P."""
    schedule = _wide_schedule(1)
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
    schedule = _wide_schedule(1)
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
    predict.focalplane.synchronous_delta_p's from h_{2,2}, h_{2,6} and h_{4,8} (a separate
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
        schedule = dataclasses.replace(
            _wide_schedule(1), repeat_boresight_deg=(0.0, 90.0)[:repeats]
        )
        if where == "on the axis":
            _, h = scanstats.hwp_moments(schedule, plate, 16, predict_fp.SYNCHRONOUS_TERMS)
            want_all = predict_fp.synchronous_delta_p(h, plate, pairs.pair_angles_deg)
        else:
            _, h = scanstats.hwp_moments(
                schedule, plate, 16, predict_fp.SYNCHRONOUS_TERMS, focalplane=pairs,
                pair_weights=predict_fp.synchronous_weights(pairs),
            )  # fmt: skip
            want_all = predict_fp.synchronous_delta_p(h, plate, None)
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
        hits, h = scanstats.hwp_moments(base, plate, NSIDE, predict_fp.JITTER_TERMS)
        angles = pairs.pair_angles_deg
    else:
        pairs = focalplane.hexagon(7, 20.0).subset([0, 1, 2])
        hits, h = scanstats.hwp_moments(
            base, plate, NSIDE, predict_fp.JITTER_TERMS, focalplane=pairs, relative=True
        )
        angles = None
    ref = engine.simulate_focalplane(sky, base, pairs, evaluation="pixel", hwp=ideal)
    mask = (ref.rcond > 0.05).astype(float)
    dp, variance, _ = predict_fp.angle_jitter_leak(
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
    schedule = _wide_schedule(1)
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
        engine, "angle_jitter", lambda hwp, seed, first, n: np.full(n, np.radians(0.5))
    )
    held = engine.simulate_focalplane(plain_sky, schedule, pairs, **run)
    offset = dataclasses.replace(plate, angle_jitter_deg=0.0, angle_offset_deg=0.5)
    want = engine.simulate_focalplane(plain_sky, schedule, pairs, evaluation="pixel", hwp=offset)
    np.testing.assert_allclose(held.q, want.q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(held.u, want.u, rtol=0, atol=1e-9)


def test_a_stepped_plate_of_thousands_of_angles_is_refused():
    """18,000 steps were taken and the design allocated 21.7 GiB for them."""
    with pytest.raises(ConfigError, match="721 values; at most 720"):
        HWP("stepped", angles_deg=tuple(np.linspace(0, 180, 721)))
    assert len(HWP("stepped", angles_deg=tuple(np.linspace(0, 180, 720))).angles_deg) == 720
