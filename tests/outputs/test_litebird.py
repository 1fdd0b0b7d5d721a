"""h_{n,m} files in litebird_sim's layout, read back by litebird_sim's own reader (its
``load_h_maps_from_file``, where litebird_sim is installed) and as that reader reads them."""

import h5py
import numpy as np
import pytest

from boresight.outputs import litebird as litebird_maps
from boresight.validation import ConfigError


def _load_as_litebird_sim(path):
    """litebird_sim.mapmaking.h_maps.load_h_map_from_file's reading, without litebird_sim."""
    with h5py.File(path, "r") as f:
        maps = {}
        for key in f.keys():
            n, m = map(int, key.split(","))
            maps[n, m] = np.array(f[key]["Re"]) + 1j * np.array(f[key]["Im"])
        attrs = {k: f.attrs[k] for k in f.attrs}
    return maps, attrs


def test_a_written_file_reads_back_in_litebird_sims_layout(tmp_path):
    rng = np.random.default_rng(3)
    hits = rng.integers(0, 5, 48)
    h = {(2, -4): rng.normal(size=48) + 1j * rng.normal(size=48), (0, 0): np.ones(48)}
    path = litebird_maps.write(
        tmp_path, "boresight", hits, h, frame="galactic", duration_s=600.0, sample_rate_hz=20.0
    )
    assert path.name == "h_maps_det_boresight.h5"
    maps, attrs = _load_as_litebird_sim(path)
    assert set(maps) == {(0, 0), (2, -4)}
    np.testing.assert_array_equal(maps[0, 0], hits)  # (0, 0) holds the hits, as make_h_maps
    np.testing.assert_array_equal(maps[2, -4], h[(2, -4)])
    assert attrs["coordinate_system"] == "Galactic" and attrs["det"] == "boresight"
    assert attrs["duration_s"] == 600.0 and attrs["sampling_rate_Hz"] == 20.0
    assert attrs["detector_split"] == attrs["time_split"] == "full"
    assert "TOAST's psi + 180 deg" in attrs["psi_convention"]


def test_litebird_sims_own_reader_reads_them(tmp_path):
    h_maps = pytest.importorskip("litebird_sim.mapmaking.h_maps")
    hits = np.arange(48) % 3
    moment = np.exp(1j * np.arange(48.0)) * (hits > 0)
    path = litebird_maps.write(
        tmp_path,
        "D0A",
        hits,
        {(2, -4): moment},
        frame="galactic",
        duration_s=6.0,
        sample_rate_hz=2.0,
    )
    result = h_maps.load_h_maps_from_file(str(path))
    assert result.coordinate_system.name == "Galactic"
    assert result.duration_s == 6.0 and result.sampling_rate_Hz == 2.0
    maps = result.h_maps["D0A"]
    assert set(maps) == {(0, 0), (2, -4)}
    np.testing.assert_array_equal(maps[0, 0].real, hits)
    np.testing.assert_array_equal(maps[2, -4].real + 1j * maps[2, -4].imag, moment)


def test_litebird_sims_frames_only(tmp_path):
    with pytest.raises(ConfigError, match="Ecliptic or Galactic"):
        litebird_maps.write(
            tmp_path, "d", np.zeros(12), {}, frame="icrs", duration_s=1.0, sample_rate_hz=1.0
        )
    assert list(tmp_path.iterdir()) == []
