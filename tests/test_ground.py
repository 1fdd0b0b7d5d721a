"""Real ground scans: pointing against astropy, geometry, rotation schedules, twins (issue 5)."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import rel_max

from boresight import engine, frames, pointing, scanstats
from boresight.constants import DEG
from boresight.instrument import Systematics
from boresight.kernels import cpu
from boresight.scan import SyntheticScan
from boresight.schedule import CES, Schedule, ScheduleError, Site, load_schedule, write_schedule

T0 = 1.79e9  # 2026-09-21, inside the IERS tables astropy ships


def _night(site=Site(), rate=10.0, n=6, el=50.0):
    ces = tuple(
        CES(
            start_unix=T0 + i * 3600,
            duration_s=1800,
            elevation_deg=el,
            az_centre_deg=140 if i < n // 2 else 220,
            az_throw_deg=30,
        )
        for i in range(n)
    )
    return Schedule(ces, site, sample_rate_hz=rate)


#: 2026-12-15, where ICRS and the frame of date differ by 0.15 deg
T_FRAMES = 1.7981676e9


@pytest.mark.parametrize("frame", ["icrs", "galactic", "cirs"])
def test_pointing_matches_astropy(frame):
    """<= 0.5 arcsec in position and <= 0.001 deg in crossing angle against astropy's AltAz ->
    ICRS, Galactic and topocentric CIRS, on a date where ICRS and CIRS are 0.15 deg apart (what is
    left is polar motion, which boresight leaves out, and 4 mas of first-order aberration)."""
    u = pytest.importorskip("astropy.units")
    from astropy.coordinates import CIRS, ICRS, AltAz, EarthLocation, Galactic, SkyCoord
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False
    iers.conf.auto_max_age = None  # astropy's own tables, no download
    site = Site()
    ces = CES(
        start_unix=T_FRAMES,
        duration_s=7200,
        elevation_deg=40,
        az_centre_deg=100,
        az_throw_deg=60,
        boresight_deg=30,
    )
    t, az, el, _ = pointing.ces_samples(ces, Schedule((ces,), site, 0.05))
    times = Time(t, format="unix")
    sched = Schedule(
        (ces,), site, sample_rate_hz=0.05, dut1_s=float(np.mean(times.delta_ut1_utc)), frame=frame
    )
    theta, phi, psi = (np.concatenate(x) for x in zip(*pointing.pointing(sched)))
    loc = EarthLocation(lat=site.lat_deg * u.deg, lon=site.lon_deg * u.deg, height=site.alt_m * u.m)
    target = {"icrs": ICRS(), "galactic": Galactic(), "cirs": CIRS(obstime=times, location=loc)}
    altaz = AltAz(obstime=times, location=loc, pressure=0 * u.hPa)
    ref = SkyCoord(az=az * u.rad, alt=el * u.rad, frame=altaz).transform_to(target[frame])
    up = SkyCoord(az=az * u.rad, alt=(el + 1e-5) * u.rad, frame=altaz).transform_to(target[frame])
    ours = SkyCoord(phi, np.pi / 2 - theta, unit="rad", frame=target[frame])
    assert ours.separation(ref).arcsec.max() < 0.5
    psi_astropy = np.pi - ref.position_angle(up).rad + 30 * DEG
    assert np.degrees(np.abs(np.angle(np.exp(1j * (psi - psi_astropy))))).max() < 1e-3
    if frame == "icrs":  # the frames' offset, which a test dated 2000-01-01 could not see
        of_date = SkyCoord(az=az * u.rad, alt=el * u.rad, frame=altaz).transform_to(target["cirs"])
        gap = SkyCoord(phi, np.pi / 2 - theta, unit="rad").separation(
            SkyCoord(of_date.ra, of_date.dec)  # the numbers of date read as ICRS
        )
        assert 0.13 < gap.deg.max() < 0.16  # 0.15 deg of RA at Dec 0, less at this Dec


def test_geometry_at_pole_and_equator():
    """In the frame of date at a pole every elevation is a declination; at the equator the
    east point rises with RA = local ERA + 90 deg."""
    chunk = np.zeros(pointing.N_CHUNK)
    chunk[[1, 7]] = 1.0, pointing.UNIX_EPOCH_JD  # rate; start at the Unix epoch
    terms = frames.frame_terms(np.zeros(1), 0.0, "cirs")[0]
    for lat, az, el in (
        (-90.0, [0, 45, 90, 180, 300.0], [10, 30, 50, 70, 89.0]),
        (0.0, [90.0], [0.0]),
    ):
        for a, e in zip(az, el):
            chunk[[2, 6, 9]] = a * DEG, e * DEG, lat * DEG
            chunk[3:5] = 0.0, 1.0  # no throw: the azimuth stays at the centre
            z, r, phi, c, s, _ = pointing.sample_pointing(0, chunk, terms)
            era = pointing.earth_rotation_angle(pointing.UNIX_EPOCH_JD)
            if lat == -90.0:
                assert np.isclose(np.arcsin(z), -e * DEG)  # dec = -el whatever the azimuth
            else:
                assert np.isclose(z, 0.0, atol=1e-12)
                assert np.isclose(np.cos(phi - era), 0.0, atol=1e-12) and np.sin(phi - era) > 0
                assert np.isclose(abs(s), 1.0)  # the zenith points east or west of north there


def test_repeat_at_180_cancels_h1_h3():
    stats = scanstats.characterise(pointing.pointing(_night(rate=4).repeated([0, 180])), 64)
    obs = stats.observed
    assert obs.sum() > 300
    assert np.abs(stats.h[1, obs]).max() < 1e-13 and np.abs(stats.h[3, obs]).max() < 1e-13
    # h_2 survives a 180 deg repeat (except where rising and setting scans cross near 90 deg).
    assert np.median(np.abs(stats.h[2, obs])) > 0.5


def test_twin_reproduces_hn_power():
    stats = scanstats.characterise(pointing.pointing(_night()), 64)
    twin = stats.synthetic_twin(seed=1)
    h, _ = engine.scan_moments(twin, 64, pixels=stats.observed)
    means = stats.survey_means()
    for n in range(1, 5):
        twin_mean = np.mean(np.abs(h[n, stats.observed]) ** 2)
        assert abs(twin_mean / means[f"mean_abs_h{n}_sq"] - 1) < 0.10, n


def test_distinct_angles_and_range():
    """Known angles in one pixel: 3 separated values, two of them closer than the tolerance."""
    nside = 8
    theta = np.full(5, 1.0)
    phi = np.full(5, 1.0)
    psi = np.radians([10.0, 10.5, 50.0, 120.0, 10.2])
    stats = scanstats.characterise([(theta, phi, psi)], nside, tolerance_deg=1.0)
    p = np.flatnonzero(stats.observed)[0]
    assert stats.n_distinct[p] == 3
    assert abs(np.degrees(stats.range_rad[p]) - 110.0) <= 1.0  # 10 .. 120 deg, to a bin
    assert abs(np.degrees(stats.centre_rad[p]) - 65.0) <= 1.0


@pytest.mark.parametrize(
    "sysm",
    [
        Systematics(dg=(0.01, -0.01), rho_arcmin=1.0),
        Systematics(rho_arcmin=1.0, dfwhm_b_arcmin=2.0, ellipticity_a=0.03),  # beams too
    ],
)
def test_sample_stream_uses_the_same_pipeline(small_sky, sysm):
    """Synthetic hits fed as a sample stream give the synthetic engine's maps (to rounding)."""
    scan = SyntheticScan(n_phi=3, range_rad=0.6, seed=4)
    pix = np.arange(12 * 64**2, dtype=np.int64)
    offsets = np.arange(pix.size + 1, dtype=np.int64) * 3
    n_phi, rng_rad, centre = scan.per_pixel(pix, pix.size)
    theta, phi, psi = cpu.generate_hits(4, 64, pix, offsets, rng_rad, centre, False)
    order = np.random.default_rng(0).permutation(theta.size)  # any order, any chunking
    chunks = [
        (theta[order[s : s + 10000]], phi[order[s : s + 10000]], psi[order[s : s + 10000]])
        for s in range(0, theta.size, 10000)
    ]
    stream = engine.simulate_samples(small_sky, chunks, systematics=sysm)
    direct = engine.simulate(small_sky, scan, systematics=sysm)
    assert rel_max(stream.q, direct.q) < 1e-12 and rel_max(stream.u, direct.u) < 1e-12
    assert np.array_equal(stream.hits, direct.hits)


def test_turnaround_profile():
    """Constant speed across the throw, a smooth reversal that overshoots by v tau / 4."""
    ces = CES(
        start_unix=T0,
        duration_s=100,
        elevation_deg=45,
        az_centre_deg=180,
        az_throw_deg=10,
        speed_deg_s=2.0,
        turnaround_s=1.0,
    )
    _, az, _, _ = pointing.ces_samples(ces, Schedule((ces,), sample_rate_hz=1000.0))
    offset = np.degrees(az) - 180
    assert np.isclose(offset.min(), -5 - 0.5, atol=1e-3) and np.isclose(
        offset.max(), 5.5, atol=1e-3
    )
    speed = np.abs(np.diff(offset)) * 1000.0
    assert np.isclose(np.median(speed), 2.0, rtol=1e-6)  # the constant-speed legs
    assert np.max(speed) <= 2.0 + 1e-6  # never faster than the scan speed
    period = 2 * (5.0 + 1.0)  # two legs of throw / speed and two turnarounds [s]
    assert np.allclose(offset[:1000], offset[int(period * 1000) : int(period * 1000) + 1000])


def test_schedule_files(tmp_path):
    (tmp_path / "s.toml").write_text(
        "sample_rate_hz = 5.0\nrepeat_boresight_deg = [0.0, 90.0]\n[site]\nlat_deg = -22.96\n"
        "[[ces]]\nstart_unix = 1.79e9\nduration_s = 60\nelevation_deg = 45\n"
        "az_centre_deg = 180\naz_throw_deg = 20\n"
    )
    sched = load_schedule(str(tmp_path / "s.toml"))
    assert sched.repeat_boresight_deg == (0.0, 90.0) and sched.n_samples == 600
    psi = np.concatenate([c[2] for c in pointing.pointing(sched)])
    assert np.allclose(psi[300:] - psi[:300], np.pi / 2)  # the repeat: same track, rotated
    (tmp_path / "s.csv").write_text(
        "start_unix,duration_s,elevation_deg,az_centre_deg,az_throw_deg\n1.79e9,60,45,180,20\n"
    )
    assert load_schedule(str(tmp_path / "s.csv")).ces[0].az_throw_deg == 20
    with pytest.raises(ValueError, match="elevation_deg"):
        CES(start_unix=0, duration_s=1, elevation_deg=95, az_centre_deg=0, az_throw_deg=1)


def test_turnarounds_are_left_out_of_every_path_alike(tmp_path):
    """``turnarounds = "exclude"``: the pointing stream, the fused characterisation and the
    design's unit moments keep the same samples, those ces_samples does not flag; a TOML
    schedule keeps its frame and turnarounds through writing and reading."""
    from boresight import design

    ces = CES(T0, 300.0, 50.0, 180.0, 20.0, speed_deg_s=1.0, turnaround_s=4.0)
    every = Schedule((ces,), sample_rate_hz=10.0, frame="galactic")
    kept = replace(every, turnarounds="exclude")
    _, _, _, turning = pointing.ces_samples(ces, every)
    assert 0.1 < turning.mean() < 0.5  # 2 x 4 s of every 2 x (20 + 4) s
    streamed = sum(chunk[0].size for chunk in pointing.pointing(kept))
    assert streamed == (~turning).sum() == scanstats.characterise_schedule(kept, 32).hits.sum()
    assert design.unit_moments(kept, 32).hits.sum() == streamed
    assert scanstats.characterise_schedule(every, 32).hits.sum() == turning.size
    write_schedule(kept, tmp_path / "k.toml", "toml")
    back = load_schedule(str(tmp_path / "k.toml"))
    assert (back.frame, back.turnarounds) == ("galactic", "exclude")
    assert load_schedule(str(tmp_path / "k.toml"), frame="icrs").frame == "icrs"
    with pytest.raises(ScheduleError, match="turnarounds"):
        load_schedule(str(tmp_path / "k.toml"), turnarounds="drop")


def test_compare_scans_cli(tmp_path):
    from boresight.cli import main

    (tmp_path / "s.toml").write_text(
        "sample_rate_hz = 2.0\nrepeat_boresight_deg = [0.0, 90.0]\n"
        + "".join(
            f"[[ces]]\nstart_unix = {T0 + 3600 * i}\nduration_s = 1800\n"
            f"elevation_deg = 50\naz_centre_deg = {134 if i % 2 else 226}\n"
            "az_throw_deg = 60\n"
            for i in range(4)
        )
    )
    out = tmp_path / "cmp"
    assert (
        main(["-q", "compare-scans", str(tmp_path / "s.toml"), "--out", str(out), "--nside", "32"])
        == 0
    )
    assert (out / "compare.png").exists() and (out / "scan_maps.fits").exists()
    lines = (out / "scan_stats.csv").read_text().splitlines()
    real, twin = (dict(zip(lines[0].split(","), line.split(","))) for line in lines[1:])
    # A 90 deg repeat cancels h_2 in the real scan and in its twin alike.
    assert float(real["mean_abs_h2_sq"]) < 1e-25 and float(twin["mean_abs_h2_sq"]) < 1e-25
    assert (
        main(["-q", "compare-scans", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "x")])
        == 2
    )


def test_fused_schedule_characterisation_equals_streamed():
    sched = _night(rate=4).repeated([0, 90])
    a = scanstats.characterise(pointing.pointing(sched), 128)
    b = scanstats.characterise_schedule(sched, 128)
    assert np.array_equal(a.hits, b.hits)
    assert np.max(np.abs(a.h - b.h)) < 1e-12
    # Angle bins agree except where rounding moves an angle across a bin edge (1e-16 of 1 deg).
    assert np.mean(a.n_distinct != b.n_distinct) < 1e-3
