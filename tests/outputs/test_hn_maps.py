"""h_n maps in the layout chosen by name: each writer of WRITERS writes its own files, the SO
layout turns odd h_n to TOAST/SO's psi (its summary too), and a layout refuses what it cannot
hold before any work."""

import csv
import json

import healpy as hp
import numpy as np
import pytest

from boresight.instrument.focalplane import hexagon
from boresight.instrument.hwp import HWP
from boresight.jobs.resources import Estimate
from boresight.outputs import hn_maps
from boresight.outputs.hn_maps import WRITERS, Layout, ScanMaps
from boresight.validation import ConfigError

NSIDE = 4


def _maps():
    npix = 12 * NSIDE**2
    rng = np.random.default_rng(3)
    observed = np.arange(npix) % 3 > 0
    h = (rng.normal(size=(5, npix)) + 1j * rng.normal(size=(5, npix))) * observed
    h[0] = observed
    hits = np.where(observed, 10.0, 0.0)
    return ScanMaps(h, observed, hits, np.where(observed, 3, 0), np.where(observed, 1.0, 0))


def _summary(out):
    return {int(r["n"]): r for r in csv.DictReader(open(out / "hn_summary.csv"))}


def test_every_layout_has_a_writer_and_writes_its_own_files(tmp_path):
    assert set(WRITERS) == set(hn_maps.FORMATS)
    maps = _maps()
    config = {"frame": "galactic", "observing_s": 60.0, "sample_rate_hz": 2.0}
    files = {}
    for name in hn_maps.FORMATS:
        out = tmp_path / name
        hn_maps.write(
            out,
            maps,
            n_max=4,
            inputs=[],
            force=False,
            layout=Layout(name),
            config=dict(config),
            estimate=Estimate(name),
        )
        files[name] = {p.name for p in out.iterdir()}
        manifest = json.loads((out / "manifest.json").read_text())["config"]
        assert manifest["psi_convention"] == ("toast" if name == "so" else "boresight")
    assert "hn_maps.fits" in files["boresight"]
    assert {"hn_cos_1.fits", "hn_sin_4.fits", "hn_hits.fits"} <= files["so"]
    assert "h_maps_det_boresight.h5" in files["litebird"]
    re2 = hp.read_map(tmp_path / "boresight" / "hn_maps.fits", field=1)
    np.testing.assert_allclose(re2[maps.observed], maps.h[2].real[maps.observed], rtol=1e-6)
    # odd h_n change sign in TOAST/SO's psi, even ones do not, in the summary as in the maps
    bare, so = _summary(tmp_path / "boresight"), _summary(tmp_path / "so")
    for n in range(1, 5):
        sign = -1 if n % 2 else 1
        assert float(so[n]["mean_re"]) == pytest.approx(sign * float(bare[n]["mean_re"]))
        assert float(so[n]["mean_abs_h2"]) == pytest.approx(float(bare[n]["mean_abs_h2"]))


def test_a_layout_refuses_what_it_cannot_hold():
    plate = HWP("continuous")
    pairs = hexagon(7, 10.0)
    with pytest.raises(ConfigError, match="--per-detector needs --focalplane and --format so"):
        Layout("boresight").check_schedule_outputs(focalplane=pairs, per_detector=True, hwp=None)
    with pytest.raises(ConfigError, match="leave out --format so"):
        Layout("so").check_schedule_outputs(focalplane=None, per_detector=False, hwp=plate)
    with pytest.raises(ConfigError, match="Galactic"):
        Layout("litebird").check_frame("icrs")
    Layout("boresight").check_frame("icrs")
    Layout("so").check_schedule_outputs(focalplane=pairs, per_detector=True, hwp=None)
    assert Layout("litebird").files_per_pair and not Layout("so").files_per_pair
