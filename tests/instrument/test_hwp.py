"""The half-wave plate: its angles over a schedule, and a detector's I, Q, U weights through it
against TOAST's own StokesWeights with a continuous and a stepped HWP, on a schedule of December
2026; the files scan-stats writes behind a plate, and a study behind one. The TOAST tests skip
where it is not installed."""

import dataclasses

import healpy as hp
import numpy as np
import pytest
from helpers import T0, toast_december_schedule
from plates import minute_schedule

from boresight import moments as scanstats
from boresight import pointing, spectra
from boresight.cli import main
from boresight.instrument import focalplane, hwp
from boresight.instrument.hwp import HWP
from boresight.schedule import CES, Schedule, Site, load_schedule
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
    pi (the relation tests/instrument/test_focalplane.py checks against PointingDetectorSimple) equal TOAST's
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


def _chi_per_ces(schedule, one):
    """The HWP's angles of each (repeat, CES), from the pointing's own stream."""
    seen = {}
    for repeat, index, args in pointing.ces_chunks(schedule, 50):
        chi = hwp.chunk_angles(one, schedule, repeat, index, first=args[0], n=args[1])
        seen.setdefault((repeat, index), set()).update(np.round(np.degrees(chi), 9))
    return seen


def test_a_stepped_hwp_steps_per_ces_day_or_repeat():
    day = 86400.0
    schedule = minute_schedule([0.0, 3600.0, day, day + 3600.0], repeats=(0.0, 90.0))
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
    schedule = dataclasses.replace(minute_schedule([0.0, 600.0]), turnarounds="exclude")
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


def test_scan_stats_writes_each_detectors_hwp_moments_in_litebird_sims_layout(tmp_path):
    """scan-stats --focalplane --hwp --format litebird: one file per detector, both of a pair
    holding its moments, and the focal plane's combination as det "focalplane" (the writer's
    files against litebird_sim's own reader: tests/outputs/test_litebird.py)."""
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
    from boresight.jobs import residual

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


def test_a_plate_whose_modulation_aliases_to_a_constant_is_one_clear_error():
    """A 2 Hz plate sampled at 1 Hz (or 8 Hz) sits at one 4 chi in every sample: refused."""
    for rate in (1.0, 8.0):
        schedule = dataclasses.replace(minute_schedule([0.0]), sample_rate_hz=rate)
        with pytest.raises(ConfigError, match="aliases to a constant"):
            next(pointing.pointing(schedule, hwp=HWP("continuous", frequency_hz=2.0)))
    next(pointing.pointing(minute_schedule([0.0]), hwp=HWP("continuous", frequency_hz=0.37)))


def test_a_stepped_plate_of_thousands_of_angles_is_refused():
    """18,000 steps were taken and the design allocated 21.7 GiB for them."""
    with pytest.raises(ConfigError, match="721 values; at most 720"):
        HWP("stepped", angles_deg=tuple(np.linspace(0, 180, 721)))
    assert len(HWP("stepped", angles_deg=tuple(np.linspace(0, 180, 720))).angles_deg) == 720
