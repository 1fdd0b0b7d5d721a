"""SO/SMARTIES h_n maps: written and read back, in TOAST's psi convention (odd h_n change sign)."""

import healpy as hp
import numpy as np
import pytest
from astropy.io import fits
from helpers import EXAMPLES, toast_schedule

from boresight import cli, moments
from boresight.outputs import so as so_maps
from boresight.schedule import load_schedule, toast


def test_so_layout_round_trip_and_convention(tmp_path):
    """scan-stats --format so writes (-1)^n h_n as cos/sin maps, 0 where unobserved; reading
    them back gives boresight's h_n; and a uniform psi = 180 deg + a in boresight's convention is
    exp(i n a) in SO's."""
    schedule = toast_schedule()
    schedule_path = tmp_path / "s.txt"
    toast.write(schedule, schedule_path)
    out = tmp_path / "so"
    assert cli.main(["-q", "scan-stats", str(schedule_path), "--out", str(out), "--nside", "32",
                     "--format", "so", "--prefix", "p"]) == 0  # fmt: skip
    stats = moments.characterise_schedule(load_schedule(str(schedule_path)), 32)
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


@pytest.mark.parametrize("layout", [["--format", "so", "--per-detector"], []])
def test_partial_maps_hold_the_full_skys_values_on_the_observed_pixels(tmp_path, layout):
    """scan-stats --partial writes every FITS map as healpy's explicit-index partial map: healpy
    reads each back equal to the full-sky run's file on its pixels (the observed ones) with
    UNSEEN elsewhere, the SO reader gives the same h_n, and the files take far less room."""
    args = ["-q", "scan-stats", str(EXAMPLES / "schedule_deep_sat.toml"), "--nside", "32",
            "--focalplane", "hexagon:7:20", *layout]  # fmt: skip
    full, part = tmp_path / "full", tmp_path / "partial"
    assert cli.main([*args, "--out", str(full)]) == 0
    assert cli.main([*args, "--out", str(part), "--partial"]) == 0
    names = sorted(p.name for p in full.glob("*.fits"))
    assert names == sorted(p.name for p in part.glob("*.fits")) and len(names) >= 3
    for name in names:
        with fits.open(part / name) as f:
            assert f[1].header["INDXSCHM"] == "EXPLICIT" and f[1].columns.names[0] == "PIXEL"
            pixels = np.asarray(f[1].data["PIXEL"])
        whole = np.atleast_2d(hp.read_map(full / name, field=None, dtype=np.float64))
        got = np.atleast_2d(hp.read_map(part / name, field=None, dtype=np.float64))
        kept = np.zeros(whole.shape[1], dtype=bool)
        kept[pixels] = True
        np.testing.assert_array_equal(got[:, kept], whole[:, kept])
        assert np.all(got[:, ~kept] == hp.UNSEEN)
        assert np.all((whole[:, ~kept] == 0) | (whole[:, ~kept] == hp.UNSEEN))
    if layout:
        for n in range(1, 5):
            np.testing.assert_array_equal(
                so_maps.read(part, "hn_D0A", n), so_maps.read(full, "hn_D0A", n)
            )
    size = {d: sum(p.stat().st_size for p in d.glob("*.fits")) for d in (full, part)}
    assert size[part] < 0.5 * size[full]
