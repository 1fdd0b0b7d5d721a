"""A boresight rotation about a point off the focal plane's centre: every pair's pointing and
crossing angle equal sotodlib's ``sat_v1`` model (``coords.pointing_model.model_sat_v1`` with its
``fp_rot_xi0``, ``fp_rot_eta0``; so3g's quaternion algebra reproduced here from
``so3g/proj/quat.py``), a pair at the centre of rotation stays put, and the offset reaches the
pipelines through the focal plane's flags and tables."""

import dataclasses

import numpy as np
import pytest

from boresight import pointing
from boresight.instrument import focalplane
from boresight.instrument.focalplane import FocalPlaneError, off_centre, xieta_vectors
from boresight.pointing import offset_sample
from boresight.schedule import CES, Schedule

# so3g.proj.quat, components (1, i, j, k), on numpy arrays


def mult(p, q):
    a1, b1, c1, d1 = p
    a2, b2, c2, d2 = q
    return np.array(
        [
            a1 * a2 - b1 * b2 - c1 * c2 - d1 * d2,
            a1 * b2 + b1 * a2 + c1 * d2 - d1 * c2,
            a1 * c2 - b1 * d2 + c1 * a2 + d1 * b2,
            a1 * d2 + b1 * c2 - c1 * b2 + d1 * a2,
        ]
    )


def conj(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def euler(axis, angle):
    q = np.zeros(4)
    q[0], q[axis + 1] = np.cos(angle / 2), np.sin(angle / 2)
    return q


def rotation_iso(theta, phi, psi=None):
    out = mult(euler(2, phi), euler(1, theta))
    return out if psi is None else mult(out, euler(2, psi))


def rotation_lonlat(lon, lat, psi=0.0):
    return rotation_iso(np.pi / 2 - lat, lon, psi)


def rotation_xieta(xi, eta, gamma=0.0):
    phi = np.arctan2(-xi, -eta)
    theta = np.arcsin(np.sqrt(xi**2 + eta**2))
    return rotation_iso(theta, phi, gamma - phi)


def decompose_lonlat(q):
    a, b, c, d = q
    psi = np.arctan2(a * b + c * d, a * c - b * d)
    phi = np.arctan2(c * d - a * b, a * c + b * d)
    theta = 2 * np.arctan2((b**2 + c**2) ** 0.5, (a**2 + d**2) ** 0.5)
    return phi, np.pi / 2 - theta, psi


def model_sat_v1(az, el, roll, fp_rot_xi0, fp_rot_eta0):
    """sotodlib's model_sat_v1 with every parameter but the rotation centre zero: the encoder
    offsets, tilts and az terms vanish, fp_offset is 0."""
    q_fp_rot = conj(rotation_xieta(fp_rot_xi0, fp_rot_eta0))
    q_fp_offset = rotation_xieta(0.0, 0.0)
    q_hs = mult(
        mult(mult(mult(rotation_lonlat(-az, el), q_fp_offset), conj(q_fp_rot)), euler(2, roll)),
        q_fp_rot,
    )
    neg_az, el, roll = decompose_lonlat(q_hs)
    change = ((-neg_az - az) + np.pi) % (2 * np.pi) - np.pi
    return az + change, el, roll


def wrap(x):
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


@pytest.mark.parametrize("centre_deg", [(1.5, -0.7), (-4.0, 2.5)])
@pytest.mark.parametrize("angle_deg", [30.0, -75.0, 180.0])
def test_pairs_point_as_sotodlibs_sat_v1(centre_deg, angle_deg):
    """Detectors scattered over 15 deg, the boresight at a horizon position: boresight's
    direction equals sotodlib's (the corrected boresight times the detector's quaternion) to
    1e-12 rad and its crossing angle is sotodlib's + 180 deg (boresight's convention) to 1e-12."""
    rng = np.random.default_rng(7)
    xi, eta = rng.uniform(-0.13, 0.13, (2, 40))
    az, el = 2.1, 0.85
    roll = np.radians(angle_deg)  # boresight's angle is sotodlib's roll, TOAST's rotation
    az1, el1, roll1 = model_sat_v1(az, el, roll, *np.radians(centre_deg))
    vectors = off_centre(xieta_vectors(xi, eta), centre_deg, angle_deg)
    theta0, phi0, psi0 = np.pi / 2 - el, -az, np.pi + roll  # so3g's lon is -az
    for k in range(xi.size):
        lon, lat, psi = decompose_lonlat(
            mult(rotation_lonlat(-az1, el1, roll1), rotation_xieta(xi[k], eta[k]))
        )
        z, r, phi, c, s = offset_sample(
            np.cos(theta0), np.sin(theta0), np.cos(phi0), np.sin(phi0), np.cos(psi0),
            np.sin(psi0), vectors[k],
        )  # fmt: skip
        assert abs(np.arctan2(r, z) - (np.pi / 2 - lat)) < 1e-12
        assert abs(wrap(phi - lon)) < 1e-12
        assert abs(wrap(np.arctan2(s, c) - psi - np.pi)) < 1e-12
    # without the offset the pairs turn about the boresight: the model's identity
    assert np.array_equal(off_centre(xieta_vectors(xi, eta), (0.0, 0.0), angle_deg),
                          xieta_vectors(xi, eta))  # fmt: skip
    moved = np.abs(vectors - xieta_vectors(xi, eta)).max()
    assert moved > 1e-3  # the offset moves them


def test_the_centre_of_rotation_stays_put():
    """Through the whole pointing chain: a pair at the rotation centre points at the same sky
    at every boresight angle, its crossing angle turned by the angle; a pair at the focal
    plane's centre moves."""
    ces = tuple(
        CES(1.8e9, 600.0, 50.0, 180.0, 20.0, speed_deg_s=1.0, boresight_deg=a)
        for a in (0.0, 45.0, 120.0)
    )
    centre = (2.0, -1.0)
    fp = focalplane.FocalPlane(
        names=("at_centre", "middle"),
        detectors=(("a1", "b1"), ("a2", "b2")),
        xi_deg=np.array([centre[0], 0.0]),
        eta_deg=np.array([centre[1], 0.0]),
        gamma_deg=np.zeros(2),
        hn_offset_deg=np.zeros((2, 2)),
        rotation_centre_deg=centre,
    )
    runs = []
    for c in ces:
        theta, phi, psi = next(pointing.detector_pointing(Schedule((c,), sample_rate_hz=2.0), fp))
        runs.append((theta, phi, psi))
    for (theta, phi, psi), angle in zip(runs[1:], (45.0, 120.0)):
        np.testing.assert_allclose(theta[0], runs[0][0][0], atol=1e-12)
        np.testing.assert_allclose(wrap(phi[0] - runs[0][1][0]), 0, atol=1e-12)
        np.testing.assert_allclose(wrap(psi[0] - runs[0][2][0] - np.radians(angle)), 0, atol=1e-9)
        assert np.abs(theta[1] - runs[0][0][1]).max() > 1e-3  # the middle moves
    # a focal plane turning about its centre keeps its pairs where the schedule had them
    centred = dataclasses.replace(fp, rotation_centre_deg=(0.0, 0.0))
    theta, phi, _ = next(
        pointing.detector_pointing(Schedule(ces[1:2], sample_rate_hz=2.0), centred)
    )
    base, *_ = next(pointing.detector_pointing(Schedule(ces[:1], sample_rate_hz=2.0), centred))
    np.testing.assert_allclose(theta[1], base[1], atol=1e-12)


def test_the_offset_reaches_every_input(tmp_path):
    """A TOML focal plane's rotation_centre_deg, [instrument] rotation_centre_deg beside
    focalplane (a study's or a budget's), --rotation-centre, and clear errors for a bad one."""
    from helpers import budget_file

    from boresight import cli
    from boresight.design import budget as budget_module

    toml = tmp_path / "fp.toml"
    rows = "".join(
        f'[[detector]]\nname = "{n}"\nxi_deg = 1.0\neta_deg = 0.5\ngamma_deg = {g}\n'
        for n, g in (("p0A", 0.0), ("p0B", 90.0))
    )
    toml.write_text("rotation_centre_deg = [0.3, -0.2]\n" + rows)
    assert focalplane.load_focalplane(str(toml)).rotation_centre_deg == (0.3, -0.2)
    assert focalplane.focalplane_of_table(
        {"focalplane": "fp.toml"}, tmp_path
    ).rotation_centre_deg == (0.3, -0.2)
    table = {"focalplane": "hexagon:7:10", "rotation_centre_deg": [0.5, -0.25]}
    assert focalplane.focalplane_of_table(table, tmp_path).rotation_centre_deg == (0.5, -0.25)
    with pytest.raises(FocalPlaneError, match="rotation_centre_deg"):
        focalplane.focalplane_of_table({**table, "rotation_centre_deg": [1.0]}, tmp_path)
    with pytest.raises(FocalPlaneError, match="rotation_centre_deg"):
        focalplane.focalplane_of_table({**table, "rotation_centre_deg": 3.0}, tmp_path)
    budget = budget_file(
        tmp_path,
        systematics="dg = 0.01",
        instrument='focalplane = "hexagon:7:10"\nrotation_centre_deg = [0.5, 0.0]',
    )
    assert budget_module.load_budget(budget).focalplane.rotation_centre_deg == (0.5, 0.0)
    src = tmp_path / "s.toml"
    src.write_text("[[ces]]\nstart_unix = 1.8e9\nduration_s = 60\nelevation_deg = 50\n"
                   "az_centre_deg = 180\naz_throw_deg = 10\n")  # fmt: skip
    out = tmp_path / "stats"
    args = ["-q", "scan-stats", str(src), "--nside", "16", "--out", str(out)]
    assert cli.main([*args, "--rotation-centre", "0.5"]) == 2
    assert cli.main([*args, "--rotation-centre", "0.5,0"]) == 2  # needs --focalplane
    assert cli.main([*args, "--focalplane", "hexagon:7:10", "--rotation-centre", "0.5,0"]) == 0


def test_a_design_of_an_off_centre_focal_plane_scans_each_angle():
    """The focal-plane design builds every unit's sums at every allowed angle with the pairs'
    own pointing (moments.unit_sums): with the rotation centre off the middle, the
    sums at 0 deg are the centred plane's and those at 90 deg are not."""
    from boresight.moments import unit_moments, unit_sums

    ces = (CES(1.8e9, 300.0, 50.0, 150.0, 20.0, speed_deg_s=1.0),)
    schedule = Schedule(ces, sample_rate_hz=2.0)
    moments = unit_moments(schedule, 32, "ces")
    plane = focalplane.hexagon(7, 10.0)
    off = dataclasses.replace(plane, rotation_centre_deg=(3.0, -2.0))
    centred = unit_sums(moments, schedule, plane, (0.0, 90.0))
    turned = unit_sums(moments, schedule, off, (0.0, 90.0))
    assert np.array_equal(centred.pixels[0][0], turned.pixels[0][0])
    assert np.array_equal(centred.sums[0][0], turned.sums[0][0])
    assert not np.array_equal(centred.pixels[0][1], turned.pixels[0][1])


def test_the_quaternion_algebra_is_so3gs():
    """The reproduction above against so3g itself (so3g.proj.quat, spt3g's quaternions):
    products, rotation_xieta, rotation_lonlat and decompose_lonlat equal to 1e-12."""
    quat = pytest.importorskip("so3g.proj.quat")
    rng = np.random.default_rng(3)

    def array(q):
        return np.array([q.a, q.b, q.c, q.d])

    for xi, eta, gamma, lon, lat, psi in rng.uniform(-0.3, 0.3, (20, 6)):
        theirs = quat.rotation_lonlat(lon, lat, psi) * quat.rotation_xieta(xi, eta, gamma)
        ours = mult(rotation_lonlat(lon, lat, psi), rotation_xieta(xi, eta, gamma))
        np.testing.assert_allclose(array(theirs), ours, atol=1e-12)
        np.testing.assert_allclose(array(quat.euler(2, psi)), euler(2, psi), atol=1e-15)
        np.testing.assert_allclose(
            wrap(np.array(quat.decompose_lonlat(theirs)) - np.array(decompose_lonlat(ours))),
            0,
            atol=1e-12,
        )
