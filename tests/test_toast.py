"""TOAST schedules in and out, SO/SMARTIES h_n maps, and boresight's pointing against TOAST's own
SimGround (issue 16). The tests that run TOAST skip where it is not installed."""

import healpy as hp
import numpy as np
import pytest

from boresight import cli, ground, scanstats, so_maps, toast_schedule
from boresight.toast_schedule import ScanMotion

SITE = ["--site-name", "atacama", "--telescope", "SAT", "--site-lat", " -22.958"]
SITE += ["--site-lon", " -67.787", "--site-alt", "5200"]
#: a day of 10-minute CESs of one patch, stepping the boresight by 45 deg every hour; starting
#: 2000-01-01 so that TOAST's J2000 coordinates and boresight's coordinates of date coincide to
#: nutation and aberration (< 30 arcsec), and the crossing angles can be compared
PATCH = ["--patch", "deep,1,30,-45,10", "--el-min-deg", "45", "--el-max-deg", "60"]
PATCH += ["--start", "2000-01-01 00:00:00", "--stop", "2000-01-02 00:00:00"]
PATCH += ["--boresight-angle-step-deg", "45", "--boresight-angle-min-deg", "-90"]
PATCH += ["--boresight-angle-max-deg", "90", "--boresight-angle-time-min", "60"]
PATCH += ["--ces-max-time-s", "600", "--sun-avoidance-angle-deg", "0"]
PATCH += ["--moon-avoidance-angle-deg", "0"]
ARCSEC = np.pi / 180 / 3600


@pytest.fixture(scope="module")
def toast_files(tmp_path_factory):
    """TOAST's scheduler's own files: each text version and the ECSV form of one schedule."""
    pytest.importorskip("toast")
    from toast.schedule_sim_ground import (
        run_scheduler,  # what toast_ground_schedule runs
    )

    d = tmp_path_factory.mktemp("toast")
    flags = {
        "v3": [],  # the scheduler's default: whitespace-separated, dates and times apart
        "v4": ["--field-separator", "|"],
        "v1": ["--verbose-schedule"],
        "v2": ["--verbose-schedule", "--field-separator", "|"],
    }
    files = {}
    for version, extra in flags.items():
        files[version] = d / f"{version}.txt"
        run_scheduler(opts=[*SITE, *PATCH, *extra, "--out", str(files[version])])
    from toast.schedule import GroundSchedule

    schedule = GroundSchedule()
    schedule.read(str(files["v3"]))
    files["ecsv"] = d / "v5.ecsv"
    schedule.write(str(files["ecsv"]))
    return files


def test_every_toast_version_reads_to_the_same_schedule(toast_files):
    """Text versions 1-4 and ECSV, as TOAST's own tools write them, give identical CESs."""
    read = {v: ground.load_schedule(str(p)) for v, p in toast_files.items()}
    first = read["v3"]
    assert len(first.ces) >= 10 and len({c.boresight_deg for c in first.ces}) >= 3
    assert (first.site.name, first.site.telescope, first.site.lat_deg) == (
        "atacama",
        "SAT",
        -22.958,
    )
    for version, schedule in read.items():
        assert schedule.site == first.site, version
        for a, b in zip(schedule.ces, first.ces, strict=True):
            assert a == b, version  # exactly: every version holds the same decimals
    c = first.ces[0]
    assert c.name == "deep" and (c.scan_index, c.subscan_index) == (0, 0)
    # SimGround's defaults: 1 deg/s on the sky, 1 deg/s^2
    assert c.speed_deg_s == pytest.approx(1 / np.cos(np.radians(c.elevation_deg)), rel=1e-14)
    assert c.turnaround_s == pytest.approx(2 * c.speed_deg_s, rel=1e-14)


def test_toast_reads_the_schedules_boresight_writes(toast_files, tmp_path):
    """TOAST's reader takes boresight's text and ECSV files, the rotated repeats as rows."""
    from astropy import units as u
    from toast.schedule import GroundSchedule

    schedule = ground.load_schedule(str(toast_files["v3"])).repeated([0.0, 90.0])
    for name in ("out.txt", "out.ecsv"):
        toast_schedule.write(schedule, tmp_path / name)
        theirs = GroundSchedule()
        theirs.read(str(tmp_path / name))
        ours = toast_schedule.rows(schedule)
        assert len(theirs.scans) == len(ours) == 2 * len(schedule.ces)
        for scan, row in zip(theirs.scans, ours):
            assert scan.start.timestamp() == row["start"].timestamp()
            assert scan.stop.timestamp() == row["stop"].timestamp()
            assert scan.boresight_angle.to_value(u.deg) == pytest.approx(row["rotation"], abs=1e-8)
            assert scan.az_min.to_value(u.deg) == pytest.approx(row["azmin"], abs=1e-8)
            assert scan.az_max.to_value(u.deg) == pytest.approx(row["azmax"], abs=1e-8)
            assert scan.el.to_value(u.deg) == pytest.approx(row["el"], abs=1e-8)
            assert scan.name == row["name"]
        assert theirs.site_lat.to_value(u.deg) == schedule.site.lat_deg
        assert theirs.site_name == schedule.site.name


def test_pointing_matches_toast_simground(toast_files):
    """Azimuth within 0.01 arcsec (the issue asks 1) and psi_boresight - psi_TOAST within 0.02 deg
    (the issue asks 0.1) of 180 deg, on CESs at three boresight angles; the positions agree to
    TOAST's J2000 vs boresight's frame of date at 2000-01-01 (nutation and aberration, < 40")."""
    import toast
    import toast.ops
    from astropy import units as u
    from toast import qarray
    from toast.instrument import GroundSite, Telescope
    from toast.instrument_sim import fake_boresight_focalplane
    from toast.schedule import GroundSchedule

    rate = 5.0
    theirs = GroundSchedule()
    theirs.read(str(toast_files["v3"]))
    angles = [s.boresight_angle.to_value(u.deg) for s in theirs.scans]
    picked = [angles.index(a) for a in sorted(set(angles))][:3]
    theirs.scans = [theirs.scans[i] for i in picked]
    focalplane = fake_boresight_focalplane(n_pix=1, sample_rate=rate * u.Hz)
    site = GroundSite(theirs.site_name, theirs.site_lat, theirs.site_lon, theirs.site_alt)
    data = toast.Data(toast.mpi.Comm())
    toast.ops.SimGround(
        telescope=Telescope("sat", focalplane=focalplane, site=site),
        schedule=theirs,
        detset_key="pixel",
    ).apply(data)

    ours = ground.load_schedule(str(toast_files["v3"]), ScanMotion(sample_rate_hz=rate))
    assert len(data.obs) == 3
    for ob, i in zip(data.obs, picked):
        ces = ours.ces[i]
        one = ground.Schedule((ces,), ours.site, rate)
        t, az, _ = ground.ces_samples(ces, one)
        theta, phi, psi = next(ground.pointing(one, chunk_samples=1 << 30))
        t_toast = np.asarray(ob.shared["times"])
        n = min(t.size, t_toast.size)
        assert n > 0.99 * t.size
        np.testing.assert_array_equal(t_toast[:n], t[:n])
        wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
        az_toast = np.asarray(ob.shared["azimuth"])[:n]
        assert np.max(np.abs(wrap(az_toast - az[:n]))) < 0.01 * ARCSEC
        th_t, ph_t, psi_t = qarray.to_iso_angles(np.asarray(ob.shared["boresight_radec"])[:n])
        offset = np.degrees(wrap(psi[:n] - psi_t - np.pi))
        assert np.max(np.abs(offset)) < 0.02, ces.boresight_deg
        assert np.max(np.abs(theta[:n] - th_t)) < 40 * ARCSEC
        assert np.max(np.abs(wrap(phi[:n] - ph_t)) * np.sin(th_t)) < 40 * ARCSEC


def test_a_fresh_toast_schedule_runs_end_to_end(toast_files, tmp_path):
    """scan-stats (both layouts) and compare-scans on the scheduler's own output."""
    path = str(toast_files["v3"])
    assert cli.main(["-q", "scan-stats", path, "--out", str(tmp_path / "s"), "--nside", "32"]) == 0
    assert (tmp_path / "s" / "hn_maps.png").stat().st_size > 0
    args = ["--format", "so", "--prefix", "sat_A", "--scan-rate", "2", "--rate-on", "mount"]
    assert cli.main(["-q", "scan-stats", path, "--out", str(tmp_path / "so"), *args]) == 0
    assert (tmp_path / "so" / "sat_A_sin_3.fits").is_file()
    out = str(tmp_path / "c")
    assert cli.main(["-q", "compare-scans", path, "--out", out, "--nside", "16"]) == 0
    assert (tmp_path / "c" / "compare.png").stat().st_size > 0


# --- without TOAST -------------------------------------------------------------------------------


def _schedule():
    ces = (
        ground.CES(9.466848e8 + 3000.5, 600.0, 50.0, 355.0, 20.0, 1.5, -45.0, 3.0, "field a", 2, 1),
        ground.CES(9.466848e8 + 4000.0, 450.0, 60.0, 120.0, 10.0, 1.5, 30.0, 3.0, "b", 3, 0),
    )
    return ground.Schedule(ces, ground.Site(-22.9, -67.8, 5190.0, "chajnantor", "sat1"), 5.0)


@pytest.mark.parametrize("name", ["s.txt", "s.ecsv"])
def test_written_schedules_read_back_to_the_same_pointing(tmp_path, name):
    """boresight -> TOAST file -> boresight keeps every CES (the repeats as rows, the azimuth range
    across north kept whole) and so the pointing, with the motion supplied on reading."""
    schedule = _schedule().repeated([0.0, 90.0])
    toast_schedule.write(schedule, tmp_path / name)
    assert ground.is_schedule(str(tmp_path / name))
    motion = ScanMotion(1.5, rate_on_sky=False, accel_deg_s2=1.0, sample_rate_hz=5.0)
    back = ground.load_schedule(str(tmp_path / name), motion)
    assert len(back.ces) == 4 and back.repeat_boresight_deg == (0.0,) and back.site == schedule.site
    expanded = [
        (c, rep) for rep in schedule.repeat_boresight_deg for c in schedule.ces
    ]  # observing order
    for b, (c, rep) in zip(back.ces, expanded):
        assert (b.name, b.scan_index, b.subscan_index) == (c.name, c.scan_index, c.subscan_index)
        assert b.boresight_deg == pytest.approx(c.boresight_deg + rep, abs=1e-8)
        assert b.start_unix == c.start_unix and b.duration_s == pytest.approx(c.duration_s)
        assert b.az_throw_deg == pytest.approx(c.az_throw_deg, abs=1e-8)
        assert b.az_centre_deg == pytest.approx(c.az_centre_deg, abs=1e-8)
        assert (b.speed_deg_s, b.turnaround_s) == (1.5, 3.0)
    ours = np.concatenate([np.stack(x) for x in ground.pointing(schedule)], axis=1)
    theirs = np.concatenate([np.stack(x) for x in ground.pointing(back)], axis=1)
    assert ours.shape == theirs.shape
    assert np.max(np.abs(ours - theirs)) < 1e-9


def test_scan_motion_and_simground_settings():
    """Rate on the sky -> mount speed 1 / cos(el); turnaround 2 v / a; settings read back."""
    m = ScanMotion(rate_deg_s=0.5, accel_deg_s2=2.0)
    assert m.mount_speed(60.0) == pytest.approx(1.0, rel=1e-15)
    assert m.turnaround_s(60.0) == pytest.approx(1.0, rel=1e-15)
    assert ScanMotion(0.5, rate_on_sky=False).mount_speed(60.0) == 0.5
    across_north = toast_schedule._ces(m, 0.0, 600.0, 0.0, "p", 350.0, 10.0, 50.0, 0, 0)
    assert (across_north.az_centre_deg, across_north.az_throw_deg) == (360.0, 20.0)
    ces = tuple(
        toast_schedule._ces(m, 0.0, 600.0, 0.0, "p", 10.0, 40.0, el, 0, 0) for el in (40.0, 60.0)
    )
    settings, notes = toast_schedule.simground_settings(ground.Schedule(ces))
    assert notes == []
    assert settings["fix_rate_on_sky"] is True
    assert settings["scan_rate_az"] == pytest.approx(0.5, rel=1e-12)
    assert settings["scan_accel_az"] == pytest.approx(2.0, rel=1e-12)
    _, notes = toast_schedule.simground_settings(_schedule())
    assert notes == []  # equal mount speeds: the rate is the mount's
    mixed = ground.Schedule((ces[0], ground.CES(0.0, 60.0, 50.0, 0.0, 10.0, 3.0)))
    _, notes = toast_schedule.simground_settings(mixed)
    assert any("different rates" in n for n in notes) and any("instantly" in n for n in notes)


@pytest.mark.parametrize(
    "text, message",
    [
        ("#Site\nsite tel -22 -67\n", "site line needs 5 fields"),
        ("#Site\nsite tel -22 -67 5200\n", "no CES rows"),
        ("#Site\ns t -22 -67 5200\n2026-01-01 00:00:00 2026-01-01 00:10:00 0 p 1 2 3\n", "line 3"),
        (
            "#Site\ns t -22 -67 5200\n2026-01-01 00:00:00|2026-13-01 00:10:00|0|p|1|2|50|0|0\n",
            "month",
        ),
        (
            "#Site\ns t -22 -67 5200\n2026-01-01 00:10:00|2026-01-01 00:00:00|0|p|1|2|50|0|0\n",
            "duration",
        ),
        (
            "#Site\ns t -22 -67 5200\n2026-01-01 00:00:00|2026-01-01 00:10:00|0|p|1|2|95|0|0\n",
            "elevation",
        ),
    ],
)
def test_bad_toast_schedules_name_the_line(tmp_path, text, message):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(ground.ScheduleError, match=message):
        ground.load_schedule(str(path))


def test_so_layout_round_trip_and_convention(tmp_path):
    """scan-stats --format so writes (-1)^n h_n as cos/sin maps, 0 where unobserved; reading
    them back gives boresight's h_n; and a uniform psi = 180 deg + a in boresight's convention is
    exp(i n a) in SO's."""
    schedule = _schedule()
    schedule_path = tmp_path / "s.txt"
    toast_schedule.write(schedule, schedule_path)
    out = tmp_path / "so"
    assert cli.main(["-q", "scan-stats", str(schedule_path), "--out", str(out), "--nside", "32",
                     "--format", "so", "--prefix", "p"]) == 0  # fmt: skip
    stats = scanstats.characterise_schedule(ground.load_schedule(str(schedule_path)), 32)
    seen = stats.observed
    hits = hp.read_map(out / "p_hits.fits")
    np.testing.assert_array_equal(hits, stats.hits)
    for n in range(1, 5):
        cos = hp.read_map(out / f"p_cos_{n}.fits", dtype=np.float64)
        assert np.all(cos[~seen] == 0)
        np.testing.assert_allclose(cos[seen], (-1) ** n * stats.h[n, seen].real, atol=1e-14)
        np.testing.assert_allclose(so_maps.read(out, "p", n), stats.h[n], atol=1e-14)
    a = 0.3
    h = np.exp(1j * np.arange(5) * (np.pi + a))[:, None] * np.ones((5, 12))
    so_maps.write(tmp_path, "u", h, np.ones(12))
    for n in range(1, 5):
        got = hp.read_map(tmp_path / f"u_cos_{n}.fits") + 1j * hp.read_map(
            tmp_path / f"u_sin_{n}.fits"
        )
        np.testing.assert_allclose(got, np.exp(1j * n * a), atol=1e-14)


def test_export_schedule_cli(tmp_path, capsys):
    src = tmp_path / "in.txt"
    toast_schedule.write(_schedule(), src)
    out = tmp_path / "out.txt"
    assert cli.main(["export-schedule", str(src), str(out)]) == 0
    assert "SimGround(" in capsys.readouterr().out
    assert out.read_text() == src.read_text()
    assert cli.main(["export-schedule", str(src), str(out)]) == 2  # exists
    assert cli.main(["export-schedule", str(src), str(out), "--force"]) == 0
