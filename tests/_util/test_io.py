"""Output files: written whole or not at all, maps readable by healpy with their frame stated,
an output directory replaced only by a finished job and never one boresight did not write."""

import csv
import json

import healpy as hp
import numpy as np
import pytest
from astropy.io import fits

from boresight._util import io
from boresight.validation import OutputError, OutputExistsError


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "table.csv"
    io.write_csv(path, [{"a": 1, "b": 2}], ["a", "b"])
    with pytest.raises(ValueError):
        with io.atomic_path(path) as tmp:
            open(tmp, "w").write("half")
            raise ValueError("the job failed")
    assert list(csv.DictReader(path.open())) == [{"a": "1", "b": "2"}]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.csv"]


@pytest.mark.parametrize("frame, coordsys", [("icrs", "C"), ("galactic", "G")])
def test_maps_read_back_in_healpy_with_their_frame(tmp_path, frame, coordsys):
    rng = np.random.default_rng(0)
    maps = rng.normal(size=(2, 12 * 8**2))
    io.write_maps(tmp_path / "m.fits", list(maps), ["Q", "U"], ["uK", "uK"], frame=frame)
    np.testing.assert_array_equal(hp.read_map(tmp_path / "m.fits", field=(0, 1)), maps)
    header = fits.getheader(tmp_path / "m.fits", 1)
    assert header["COORDSYS"] == coordsys and header["TUNIT1"] == "uK"
    assert io.fits_map_shape(str(tmp_path / "m.fits")) == (2, 12 * 8**2)


def test_a_staged_directory_replaces_the_output_only_when_the_job_finishes(tmp_path):
    out = tmp_path / "out"
    with io.staged_dir(out) as stage:
        io.write_json(stage / "a.json", {"x": 1.5, "y": np.float64(2.0)})
    assert json.loads((out / "a.json").read_text()) == {"x": 1.5, "y": 2.0}
    with pytest.raises(OutputExistsError, match="--force"):
        io.check_output_dir(out, force=False)
    with pytest.raises(RuntimeError):
        with io.staged_dir(out, force=True) as stage:
            io.write_text(stage / "b.txt", "new")
            raise RuntimeError("killed")
    assert sorted(p.name for p in out.iterdir()) == [io.MARKER, "a.json"]  # the old output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging left


def test_a_directory_boresight_did_not_write_is_never_removed(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    with pytest.raises(OutputError, match="not written by boresight"):
        io.remove_output_dir(mine)
    with pytest.raises(OutputError):
        with io.staged_dir(mine, force=True):
            pass
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_an_output_may_not_hold_an_input(tmp_path):
    (tmp_path / "study.toml").write_text("[sky]\nnside = 16\n")
    with pytest.raises(OutputError, match="holds the input"):
        io.check_output_dir(tmp_path, force=True, inputs=[str(tmp_path / "study.toml")])


def test_a_run_does_not_replace_an_output_another_run_wrote_meanwhile(tmp_path):
    """Two runs into one --out at once: the checks pass for both, the first to finish writes, the
    second is refused at the swap (not replacing it without --force) and leaves nothing behind."""
    out = tmp_path / "out"
    with pytest.raises(OutputExistsError, match="gained files while this run ran"):
        with io.staged_dir(out) as stage:
            (stage / "mine.txt").write_text("second")
            with io.staged_dir(out) as other:  # the other run, finishing first
                (other / "theirs.txt").write_text("first")
    assert sorted(p.name for p in out.iterdir()) == [io.MARKER, "theirs.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging directory left
    with io.staged_dir(out, force=True) as stage:  # --force still replaces it
        (stage / "mine.txt").write_text("forced")
    assert sorted(p.name for p in out.iterdir()) == [io.MARKER, "mine.txt"]
