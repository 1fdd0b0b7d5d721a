"""Focal planes: TOAST's geometry (its hexagon, quaternions and HDF5 file), tables, pairing and the
errors of bad files; per-detector pointing against TOAST's SimGround and PointingDetectorSimple in
December 2026, where ICRS and the frame of date are 0.15 deg apart. The TOAST tests skip where it
is not installed."""

import dataclasses

import h5py
import healpy as hp
import numpy as np
import pytest
from helpers import toast_december_schedule

from boresight import cli, pointing
from boresight.instrument import focalplane
from boresight.instrument.focalplane import FocalPlaneError
from boresight.schedule import ScanMotion, Schedule, load_schedule

ARCSEC = np.pi / 180 / 3600
RATE = 5.0  #: samples per second of the TOAST simulations
#: pixels of TOAST's 37-pixel, 35 deg hexagon: the centre, 10.1 deg and 17.5 deg off the axis
PIXELS = ("D00", "D08", "D19")


def _wrap(x):
    return (x + np.pi) % (2 * np.pi) - np.pi


def test_hexagon_is_toasts_fake_hexagon():
    """Positions, gamma and pairs of the preset equal TOAST's fake_hexagon_focalplane."""
    pytest.importorskip("toast")
    from astropy import units as u
    from toast.instrument_coords import quat_to_xieta
    from toast.instrument_sim import fake_hexagon_focalplane

    table = fake_hexagon_focalplane(n_pix=37, width=35 * u.deg).detector_data
    names = list(table["name"])
    xi, eta, gamma = quat_to_xieta(np.array(table["quat"]))
    ours = focalplane.hexagon(37, 35.0)
    assert ours.n_pairs == 37
    for i, (a, b) in enumerate(ours.detectors):
        ia, ib = names.index(f"{a}-150"), names.index(f"{b}-150")
        assert table["pixel"][ia] == table["pixel"][ib] == ours.names[i]
        np.testing.assert_allclose(np.radians(ours.xi_deg[i]), xi[ia], atol=1e-14)
        np.testing.assert_allclose(np.radians(ours.eta_deg[i]), eta[ia], atol=1e-14)
        assert abs(_wrap(np.radians(ours.gamma_deg[i]) - gamma[ia])) < 1e-12
        assert abs(_wrap(np.radians(ours.gamma_deg[i] + 90) - gamma[ib])) < 1e-12
    assert ours.radius_deg.max() == pytest.approx(17.5, abs=1e-12)  # half the width
    assert ours.radius_deg[0] == 0.0


def test_quaternions_and_xieta_round_trip_as_toasts():
    """quaternion_xieta inverts TOAST's xieta_to_quat, on the axis too, and xieta_vectors are the
    z and x axes TOAST's quaternion rotates to."""
    pytest.importorskip("toast")
    from toast import qarray
    from toast.instrument_coords import xieta_to_quat

    rng = np.random.default_rng(1)
    xi, eta = rng.uniform(-0.4, 0.4, (2, 50))
    xi[0] = eta[0] = 0.0
    gamma = rng.uniform(-np.pi, np.pi, 50)
    quats = xieta_to_quat(xi, eta, gamma)
    got = focalplane.quaternion_xieta(quats)
    for a, b in zip(got, (xi, eta, gamma)):
        assert np.max(np.abs(_wrap(a - b))) < 1e-13
    flat = xieta_to_quat(xi, eta, np.zeros(50))
    vectors = focalplane.xieta_vectors(xi, eta)
    np.testing.assert_allclose(vectors[:, :3], qarray.rotate(flat, [0.0, 0.0, 1.0]), atol=1e-15)
    np.testing.assert_allclose(vectors[:, 3:], qarray.rotate(flat, [1.0, 0.0, 0.0]), atol=1e-15)
    v = np.array([0.2, -0.5, 0.8]) / np.linalg.norm([0.2, -0.5, 0.8])
    np.testing.assert_allclose(
        focalplane.quaternion_matrices(quats) @ v, qarray.rotate(quats, v), atol=1e-15
    )
    np.testing.assert_allclose(
        focalplane.toast_pol_angles(quats),
        [np.arctan2(2 * q[3] * q[2], q[3] ** 2 - q[2] ** 2) % np.pi for q in quats],
    )


def test_pairs_on_the_axis_point_as_the_boresight():
    """A focal plane on the axis gives every pair the boresight's pointing, to rounding."""
    schedule = _short_schedule()
    ours = pointing.detector_pointing(schedule, focalplane.on_axis((0.0, 45.0)))
    for (theta, phi, psi), (t0, p0, s0) in zip(ours, pointing.pointing(schedule)):
        assert theta.shape == (2, t0.size)
        for d in range(2):
            assert np.max(np.abs(theta[d] - t0)) < 1e-12
            assert np.max(np.abs(_wrap(phi[d] - p0))) < 1e-12
            assert np.max(np.abs(_wrap(psi[d] - s0))) < 1e-12


def test_detector_pointing_does_not_depend_on_chunks():
    schedule = _short_schedule()
    fp = focalplane.hexagon(7, 20.0)
    a = [np.concatenate(x, axis=1) for x in zip(*pointing.detector_pointing(schedule, fp))]
    b = [np.concatenate(x, axis=1) for x in zip(*pointing.detector_pointing(schedule, fp, 777))]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def _short_schedule():
    from helpers import toast_schedule

    return toast_schedule()


@pytest.fixture(scope="module")
def toast_run(tmp_path_factory):
    """TOAST's scheduler's file, a focal plane of three pairs of its hexagon written with its
    save_hdf5, and its SimGround + PointingDetectorSimple over the schedule; and astropy's
    UT1 - UTC for the day."""
    pytest.importorskip("toast")
    import toast
    import toast.ops
    from astropy import units as u
    from astropy.time import Time
    from toast.instrument import Focalplane, GroundSite, Telescope
    from toast.instrument_sim import fake_hexagon_focalplane

    d = tmp_path_factory.mktemp("toast_fp")
    schedule = toast_december_schedule(d)
    for i, scan in enumerate(schedule.scans):  # a boresight angle of -90..90 deg per CES
        scan.boresight_angle = (45.0 * (i % 5) - 90.0) * u.deg
    schedule.write(str(d / "schedule.ecsv"))
    full = fake_hexagon_focalplane(n_pix=37, width=35 * u.deg, sample_rate=RATE * u.Hz)
    rows = [i for i, p in enumerate(full.detector_data["pixel"]) if p in PIXELS]
    fp = Focalplane(
        detector_data=full.detector_data[rows],
        sample_rate=RATE * u.Hz,
        field_of_view=full.field_of_view,
    )
    with h5py.File(d / "focalplane.h5", "w") as handle:
        fp.save_hdf5(handle)
    site = GroundSite(schedule.site_name, schedule.site_lat, schedule.site_lon, schedule.site_alt)
    data = toast.Data(toast.mpi.Comm())
    toast.ops.SimGround(
        telescope=Telescope("sat", focalplane=fp, site=site), schedule=schedule
    ).apply(data)
    toast.ops.PointingDetectorSimple().apply(data)
    start = np.asarray(data.obs[0].shared["times"])[0]
    return d, data, fp, float(Time(start, format="unix").delta_ut1_utc)


@pytest.mark.slow
def test_toast_hdf5_focal_plane_reads_without_toast(toast_run):
    """TOAST's own file gives its positions, angles and pairs (TOAST's 'pixel' column)."""
    d, _, fp, _ = toast_run
    ours = focalplane.read_focalplane(d / "focalplane.h5")
    assert ours.names == PIXELS
    assert ours.detectors == tuple((f"{p}A-150", f"{p}B-150") for p in PIXELS)
    hexagon = focalplane.hexagon(37, 35.0)
    idx = [hexagon.names.index(p) for p in PIXELS]
    np.testing.assert_allclose(ours.xi_deg, hexagon.xi_deg[idx], atol=1e-12)
    np.testing.assert_allclose(ours.eta_deg, hexagon.eta_deg[idx], atol=1e-12)
    assert np.all(np.abs((ours.gamma_deg - hexagon.gamma_deg[idx] + 180) % 360 - 180) < 1e-9)
    # TOAST's pol_angle is gamma modulo 180 deg: sotodlib's Hn psi is the pair's, to rounding
    assert np.all(np.abs((ours.hn_offset_deg + 1e-9) % 180) < 1e-8)


def test_detector_pointing_matches_toast(toast_run):
    """Each detector's position within 1 arcsec and psi within 0.01 deg of TOAST's
    PointingDetectorSimple on the axis and 10 and 17.5 deg off it, at every boresight angle of
    the schedule, once both are in one frame: TOAST's boresight (its pyephem path, 30-45 arcsec
    from ICRS) is rotated onto boresight's, and the same rotation is applied to its detectors."""
    from toast import qarray

    d, data, fp, dut1 = toast_run
    ours = load_schedule(str(d / "schedule.ecsv"), ScanMotion(sample_rate_hz=RATE))
    ours = dataclasses.replace(ours, dut1_s=dut1)
    plane = focalplane.read_focalplane(d / "focalplane.h5")
    assert len(data.obs) == len(ours.ces) and len({c.boresight_deg for c in ours.ces}) == 5
    assert plane.radius_deg.max() > 17 and np.sort(plane.radius_deg)[1] > 10
    for ob, ces in zip(data.obs, ours.ces):
        one = Schedule((ces,), ours.site, RATE, dut1_s=dut1)
        theta_b, phi_b, psi_b = (np.concatenate(x) for x in zip(*pointing.pointing(one)))
        theta, phi, psi = (
            np.concatenate(x, axis=1) for x in zip(*pointing.detector_pointing(one, plane))
        )
        n = theta_b.size
        ours_bore = qarray.from_iso_angles(theta_b, phi_b, psi_b - np.pi)
        frame = qarray.mult(ours_bore, qarray.inv(np.asarray(ob.shared["boresight_radec"])[:n]))
        for i, (a, b) in enumerate(plane.detectors):
            for det, turn in ((a, 0.0), (b, np.pi / 2)):
                q = qarray.mult(frame, np.asarray(ob.detdata["quats"][det])[:n])
                th_t, ph_t, psi_t = qarray.to_iso_angles(q)
                gap = hp.rotator.angdist([theta[i], phi[i]], [th_t, ph_t]) / ARCSEC
                assert gap.max() < 1.0, (det, ces.boresight_deg, gap.max())
                # TOAST's detector psi is its gamma on top of the focal plane's, less pi
                gamma = np.radians(plane.gamma_deg[i]) + turn
                offset = np.degrees(np.abs(_wrap(psi[i] - np.pi - (psi_t - gamma))))
                assert offset.max() < 0.01, (det, ces.boresight_deg, offset.max())


def _write_table(path, rows, header="name,xi_deg,eta_deg,gamma_deg,pol_angle_deg"):
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


TABLE = "name,xi_deg,eta_deg,gamma_deg"
GOOD_ROWS = ["A0A,0,0,0,0", "A0B,0,0,90,90", "X1A,5,-3,45,45", "X1B,5,-3,135,135"]


def test_csv_and_toml_tables_pair_by_name_or_column(tmp_path):
    csv_fp = focalplane.read_focalplane(_write_table(tmp_path / "fp.csv", GOOD_ROWS))
    assert csv_fp.names == ("A0", "X1") and csv_fp.detectors == (("A0A", "A0B"), ("X1A", "X1B"))
    assert csv_fp.pair_angles_deg == (0.0, 45.0)
    toml = "".join(
        f'[[detector]]\nname = "{n}"\nxi_deg = {x}\neta_deg = {e}\ngamma_deg = {g}\npair = "{p}"\n'
        for n, x, e, g, p in (
            ("left", 5, -3, 135, "p"),
            ("right", 5, -3, 45, "p"),
        )
    )
    (tmp_path / "fp.toml").write_text(toml)
    toml_fp = focalplane.read_focalplane(tmp_path / "fp.toml")
    assert toml_fp.names == ("p",) and toml_fp.detectors == (("left", "right"),)
    assert toml_fp.gamma_deg[0] == 135.0 and toml_fp.xi_deg[0] == 5.0
    assert focalplane.load_focalplane("hexagon:7:10").n_pairs == 7
    assert focalplane.load_focalplane("axis").is_on_axis


@pytest.mark.parametrize(
    "rows, header, message",
    [
        (GOOD_ROWS, "name,xi_deg,gamma_deg", "missing column 'eta_deg'"),
        (["A0A,0,0,0", "A0B,0,0,nan"], TABLE, "detector A0B"),
        (["A0A,0,0,0", "A0B,0,0,90", "Q1A,1,0,0"], TABLE, "detector Q1A: no partner"),
        (["A0A,0,0,0", "A0B,0,0,90", "Z9,1,0,0"], TABLE, "detector Z9: no partner: its name"),
        (["A0A,0,0,0", "A0A,0,0,90"], TABLE, "A0A: the name appears"),
        (["A0A,0,0,0", "A0B,0,0,60"], TABLE, "A0B: 60 deg from"),
        (["A0A,0,0,0", "A0B,0,1,90"], TABLE, "A0B: 3.6e.03 arcsec from its partner"),
        (["A0A,40,30,0", "A0B,40,30,90"], TABLE, "A0A: offset 60.77 deg .* beyond the limit"),
    ],
)
def test_bad_tables_name_the_file_and_detector(tmp_path, rows, header, message):
    path = _write_table(tmp_path / "bad.csv", rows, header)
    with pytest.raises(FocalPlaneError, match=message) as err:
        focalplane.read_focalplane(path)
    assert str(path) in str(err.value)


def _toast_like_file(path, quats, names, fov_deg=10.0):
    from astropy import units as u
    from astropy.io.misc.hdf5 import write_table_hdf5
    from astropy.table import QTable

    table = QTable({"name": names, "quat": np.asarray(quats, dtype=np.float64)})
    table.meta["field_of_view"] = fov_deg * u.deg
    table.meta["sample_rate"] = 10.0 * u.Hz
    write_table_hdf5(table, str(path), path="focalplane", serialize_meta=True)
    return path


def test_bad_toast_files_name_the_file_and_detector(tmp_path):
    pytest.importorskip("toast")
    from toast.instrument_coords import xieta_to_quat

    quats = xieta_to_quat(np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.radians([0.0, 90.0]))
    names = ["D0A", "D0B"]
    bad = quats.copy()
    bad[1] *= 1.01
    path = _toast_like_file(tmp_path / "norm.h5", bad, names)
    with pytest.raises(FocalPlaneError, match="detector D0B: quat .* not a unit quaternion"):
        focalplane.read_focalplane(path)
    far = xieta_to_quat(np.radians([8.0, 8.0]), np.zeros(2), np.radians([0.0, 90.0]))
    path = _toast_like_file(tmp_path / "far.h5", far, names)
    with pytest.raises(FocalPlaneError, match="D0A: offset 8.026 deg .* field of view the file"):
        focalplane.read_focalplane(path)
    nan = quats.copy()
    nan[0, 0] = np.nan
    path = _toast_like_file(tmp_path / "nan.h5", nan, names)
    with pytest.raises(FocalPlaneError, match="detector D0A: quat .* not finite"):
        focalplane.read_focalplane(path)
    (tmp_path / "empty.h5").write_bytes(b"not hdf5")
    with pytest.raises(FocalPlaneError, match="empty.h5: not a readable HDF5"):
        focalplane.read_focalplane(tmp_path / "empty.h5")


def test_a_bad_focal_plane_exits_2_naming_it(tmp_path, capsys):
    from helpers import toast_schedule

    from boresight.schedule import write_schedule

    write_schedule(toast_schedule(), tmp_path / "s.toml", "toml")
    path = _write_table(tmp_path / "bad.csv", ["A0A,0,0,0"], "name,xi_deg,eta_deg,gamma_deg")
    args = ["scan-stats", str(tmp_path / "s.toml"), "--focalplane", str(path)]
    assert cli.main([*args, "--out", str(tmp_path / "out"), "--nside", "16"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "A0A: no partner" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_per_detector_so_maps_match_toasts_own_hn(toast_run, tmp_path):
    """scan-stats --focalplane (TOAST's HDF5) --format so --per-detector of TOAST's schedule writes
    each detector's maps as sotodlib's Hn bins TOAST's own pointing (psi = the ISO angle of the
    detector quaternion less its pol_angle): hits on the same pixels and rms |dh_n| below 0.025
    at Nside 64 (measured 0.002-0.007 off the axis, 0.014-0.020 on it over these three hours),
    what TOAST's 30-45 arcsec from ICRS leaves at pixel edges (as for the boresight,
    tests/schedule/test_toast.py); the combined maps are the hit-weighted mean of the pairs'."""
    from astropy import units as u
    from toast import qarray

    from boresight.schedule import write_schedule

    d, data, fp, dut1 = toast_run
    schedule = load_schedule(str(d / "schedule.ecsv"), ScanMotion(sample_rate_hz=RATE))
    write_schedule(dataclasses.replace(schedule, dut1_s=dut1), tmp_path / "s.toml", "toml")
    out = tmp_path / "out"
    args = ["-q", "scan-stats", str(tmp_path / "s.toml"), "--out", str(out), "--nside", "64"]
    args += ["--focalplane", str(d / "focalplane.h5"), "--format", "so", "--per-detector"]
    args += ["--sample-rate", str(RATE), "--prefix", "w"]
    assert cli.main(args) == 0
    npix = hp.nside2npix(64)
    total_hits, total = np.zeros(npix), np.zeros((5, npix), complex)
    for det in fp.detector_data["name"]:
        hits, sums = np.zeros(npix), np.zeros((5, npix), complex)
        for ob in data.obs:
            theta, phi, psi = qarray.to_iso_angles(ob.detdata["quats"][det])
            psi = psi - fp[det]["pol_angle"].to_value(u.rad)
            pix = hp.ang2pix(64, theta, phi)
            hits += np.bincount(pix, minlength=npix)
            for n in range(5):
                w = np.exp(1j * n * psi)
                sums[n] += np.bincount(pix, w.real, npix) + 1j * np.bincount(pix, w.imag, npix)
        theirs = np.where(hits > 0, sums / np.maximum(hits, 1), 0)
        ours_hits = hp.read_map(out / f"w_{det}_hits.fits")
        both = (ours_hits > 0) & (hits > 0)
        assert ours_hits.sum() == hits.sum()
        assert both.sum() > 0.97 * max((ours_hits > 0).sum(), (hits > 0).sum()), det
        for n in range(1, 5):
            cos, sin = (hp.read_map(out / f"w_{det}_{p}_{n}.fits") for p in ("cos", "sin"))
            rms = np.sqrt(np.mean(np.abs(cos + 1j * sin - theirs[n])[both] ** 2))
            assert rms < 0.025, (det, n, rms)
        if det.endswith("A-150"):  # one detector per pair in the focal plane's combination
            total_hits += ours_hits
            for n in range(1, 5):
                cos, sin = (hp.read_map(out / f"w_{det}_{p}_{n}.fits") for p in ("cos", "sin"))
                total[n] += ours_hits * (cos + 1j * sin)
    combined_hits = hp.read_map(out / "w_hits.fits")
    np.testing.assert_array_equal(combined_hits, total_hits)
    seen = combined_hits > 0
    for n in range(1, 5):
        cos, sin = (hp.read_map(out / f"w_{p}_{n}.fits") for p in ("cos", "sin"))
        expected = total[n][seen] / combined_hits[seen]
        np.testing.assert_allclose(cos[seen] + 1j * sin[seen], expected, atol=1e-6)  # float32
    rows = (out / "pairs.csv").read_text().splitlines()
    assert rows[0].startswith("pair,radius_deg,hits,abs_h1_sq") and len(rows) == 4


def test_per_detector_files_refuse_names_no_file_can_take(tmp_path, capsys):
    from helpers import toast_schedule

    from boresight.schedule import write_schedule

    write_schedule(toast_schedule(), tmp_path / "s.toml", "toml")
    path = _write_table(tmp_path / "fp.csv", ["a/1A,0,0,0", "a/1B,0,0,90"], TABLE)
    args = ["scan-stats", str(tmp_path / "s.toml"), "--focalplane", str(path), "--format", "so"]
    args += ["--per-detector", "--out", str(tmp_path / "out"), "--nside", "16"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert "detector 'a/1A'" in err and "cannot name a file" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_scan_stats_runs_a_focal_planes_blocks_on_a_local_cluster(tmp_path):
    """--scheduler local writes the maps --scheduler serial writes."""
    pytest.importorskip("dask.distributed")
    from helpers import toast_schedule

    from boresight.schedule import write_schedule

    write_schedule(toast_schedule(), tmp_path / "s.toml", "toml")
    maps = {}
    for scheduler in ("serial", "local"):
        out = tmp_path / scheduler
        args = ["-q", "scan-stats", str(tmp_path / "s.toml"), "--out", str(out)]
        args += ["--nside", "16", "--focalplane", "hexagon:7:10", "--scheduler", scheduler]
        assert cli.main(args) == 0
        maps[scheduler] = [hp.read_map(out / name) for name in ("hn_maps.fits", "hn_scatter.fits")]
    for a, b in zip(maps["serial"], maps["local"]):
        np.testing.assert_array_equal(a, b)


GOOD_CSV = "name,xi_deg,eta_deg,gamma_deg\nA0A,0,0,0\nA0B,0,0,90\n"


@pytest.mark.parametrize(
    "kind, message",
    [
        ("directory", "not a regular file"),
        ("fifo", "not a regular file"),  # the reader would block on it
        ("gzip", "gzip-compressed"),
        ("utf16", "binary .or UTF-16."),
        ("binary", "binary"),
        ("latin1", "not UTF-8 text"),
        ("toml", "not valid TOML"),
        ("both A", "PA1, P1A: both are detector A of pair P1"),  # they were paired
    ],
)
def test_focal_plane_files_no_reader_can_read_are_one_clear_error(tmp_path, kind, message):
    import gzip
    import os

    path = tmp_path / ("fp.toml" if kind == "toml" else "fp.csv")
    if kind == "directory":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    else:
        data = {
            "gzip": gzip.compress(GOOD_CSV.encode()),
            "utf16": GOOD_CSV.encode("utf-16"),
            "binary": bytes(range(256)),
            "latin1": ("# \xe9t\xe9\n" + GOOD_CSV).encode("latin-1"),
            "toml": b"[[detector]\nname = 1\n",
            "both A": b"name,xi_deg,eta_deg,gamma_deg\nPA1,0,0,0\nP1A,0,0,90\n",
        }[kind]
        path.write_bytes(data)
    with pytest.raises(FocalPlaneError, match=message):
        focalplane.read_focalplane(path)


def test_a_csv_with_a_byte_order_mark_keeps_its_name_column(tmp_path):
    path = tmp_path / "fp.csv"
    path.write_bytes(GOOD_CSV.encode("utf-8-sig"))
    assert focalplane.read_focalplane(path).detectors == (("A0A", "A0B"),)


@pytest.mark.parametrize(
    "spec, message",
    [
        ("hexagon:7:20:1", "a hexagon is 'hexagon:N:WIDTH_DEG'"),  # a fourth field was taken
        ("hexagon:9997351:20", "at most 20000"),  # was built pixel by pixel
        ("hexagon:0:20", "at most 20000"),
    ],
)
def test_a_bad_hexagon_is_refused_before_it_is_built(spec, message):
    import time

    start = time.perf_counter()
    with pytest.raises(FocalPlaneError, match=message):
        focalplane.load_focalplane(spec)
    assert time.perf_counter() - start < 0.5


def test_toast_files_with_bad_columns_are_one_clear_error(tmp_path):
    from astropy import units as u
    from astropy.io.misc.hdf5 import write_table_hdf5
    from astropy.table import QTable

    pytest.importorskip("toast")
    from toast.instrument_coords import xieta_to_quat

    quats = xieta_to_quat(np.zeros(2), np.zeros(2), np.radians([0.0, 90.0]))
    names = ["D0A", "D0B"]

    def write(name, **columns):
        table = QTable({"name": names, "quat": quats, **columns})
        table.meta["field_of_view"] = 10.0 * u.deg
        write_table_hdf5(table, str(tmp_path / name), path="focalplane", serialize_meta=True)
        return tmp_path / name

    with pytest.raises(FocalPlaneError, match="column 'pol_angle' must be an angle"):
        focalplane.read_focalplane(write("metres.h5", pol_angle=[0.0, 1.0] * u.m))
    with pytest.raises(FocalPlaneError, match="D0B: pol_angle nan is not finite"):
        focalplane.read_focalplane(write("nan.h5", pol_angle=[0.0, np.nan] * u.rad))
    with pytest.raises(FocalPlaneError, match="D0A: pol_angle inf is not finite"):
        focalplane.read_focalplane(write("inf.h5", pol_angle=[np.inf, 0.0] * u.rad))
    empty = QTable({"name": np.array([], dtype="U3"), "quat": np.zeros((0, 4))})
    write_table_hdf5(empty, str(tmp_path / "empty.h5"), path="focalplane", serialize_meta=True)
    with pytest.raises(FocalPlaneError, match="has no detectors"):
        focalplane.read_focalplane(tmp_path / "empty.h5")
    text = QTable({"name": names, "quat": np.array([["a", "b", "c", "d"]] * 2)})
    write_table_hdf5(text, str(tmp_path / "text.h5"), path="focalplane", serialize_meta=True)
    with pytest.raises(FocalPlaneError, match="'quat' must hold numbers"):
        focalplane.read_focalplane(tmp_path / "text.h5")


def test_a_focal_plane_without_pairs_or_off_the_hemisphere_is_refused():
    """They returned empty or NaN results: no pairs, a pair at 80 deg in sine units (xi = sin
    of 80 deg in radians > 1), angles that are no sequence."""
    with pytest.raises(FocalPlaneError, match="one pair or more"):
        focalplane.on_axis([])
    with pytest.raises(TypeError, match="a sequence of angles"):
        focalplane.on_axis(None)
    with pytest.raises(TypeError, match="a sequence of angles"):
        focalplane.on_axis("045")
    one = focalplane.on_axis((0.0,))
    with pytest.raises(FocalPlaneError, match="off the boresight's hemisphere"):
        dataclasses.replace(one, xi_deg=np.array([80.0]))
    with pytest.raises(FocalPlaneError, match="gamma_deg: NaN"):
        dataclasses.replace(one, gamma_deg=np.array([np.nan]))
    with pytest.raises(FocalPlaneError, match=r"shape \(1,\) expected"):
        dataclasses.replace(one, eta_deg=np.zeros(2))
