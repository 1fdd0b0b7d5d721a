"""Sweeps: serial and Dask give the same table, interrupted sweeps resume exactly."""

import json
import logging
import subprocess
import sys
import time

import healpy as hp
import numpy as np
import pytest
from helpers import FUZZ, FUZZ_STUDY, STUDY, scalars, sweep_file, values
from hypothesis import given
from hypothesis import strategies as st

from boresight import coupling, masks, predict, spectra
from boresight.cli import main
from boresight.config import ConfigError
from boresight.jobs import sweep

BASE_STUDY = """
[sky]
nside = 32
lmax = 64
fwhm_arcmin = 120.0
[scan]
n_phi = 3
range_rad = 0.5
[systematics]
dg = [0.01, -0.01]
[mask]
survey = "wide"
[output]
lmax = 60
n_bands = 4
"""


def _sweep_files(tmp_path, points='pbr_angle_deg = [0, 45, 90]\n"sky.seed" = [1, 2]'):
    (tmp_path / "study.toml").write_text(BASE_STUDY)
    path = tmp_path / "sweep.toml"
    path.write_text(f'base = "study.toml"\nmode = "grid"\n[parameters]\n{points}\n')
    return str(path)


def _table(out):
    return (out / "results.csv").read_text()


@pytest.mark.slow
def test_serial_and_local_cluster_give_identical_tables(tmp_path):
    path = _sweep_files(tmp_path)
    a = sweep.run_sweep(path, tmp_path / "serial", scheduler="serial")
    pytest.importorskip("dask.distributed")
    sweep.run_sweep(path, tmp_path / "dask", scheduler=None, workers=2)
    assert _table(tmp_path / "serial") == _table(tmp_path / "dask")
    assert len(a) == 6 * 4 and (tmp_path / "serial" / "results.parquet").exists()
    ens = (tmp_path / "serial" / "ensemble.csv").read_text().splitlines()
    assert len(ens) == 1 + 3 * 4 and "residual_bb_std" in ens[0]


def test_interrupted_sweep_resumes_to_the_same_rows(tmp_path):
    path = _sweep_files(tmp_path, "pbr_angle_deg = [0, 30, 60, 80, 89, 90]")
    whole = tmp_path / "whole"
    sweep.run_sweep(path, whole, scheduler="serial")
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "boresight.cli",
        "-q",
        "sweep",
        path,
        "--out",
        str(out),
        "--scheduler",
        "serial",
    ]
    proc = subprocess.Popen(cmd)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        done = list((out / "points").glob("*.json")) if (out / "points").exists() else []
        if len(done) >= 2:
            break
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    partial = len(list((out / "points").glob("*.json")))
    assert partial < 6, "the sweep finished before it could be interrupted"
    sweep.run_sweep(path, out, scheduler="serial")
    assert _table(out) == _table(whole)
    assert not [p for p in (out / "points").iterdir() if p.name.startswith(".")]


def test_sweep_validation(tmp_path):
    path = _sweep_files(tmp_path, '"sky.nside" = [32, 48]')
    with pytest.raises(ConfigError, match="power of two"):
        sweep.load_sweep(path)
    with pytest.raises(ConfigError, match="list"):
        sweep.expand({"a.b": [1, 2], "c.d": [1]}, "list")
    assert sweep.expand({"a.b": [1, 2], "c.d": [3, 4]}, "grid")[3] == {"a.b": 2, "c.d": 4}
    raw = sweep.apply_overrides({"scan": {"n_phi": 2}}, {"pbr_angle_deg": 90})
    assert raw["scan"]["rotations_deg"] == [0.0, 90.0]


@pytest.mark.slow
def test_delta_r_recovers_input_r(theory):
    """Pure tensor skies (r = 0.05, B only) through the deep mask: the estimator returns r.

    The template's weight sits at 30 <= ell <= 100, ~900 modes on fsky 0.1: one sky scatters by
    ~5 %; the mean of 8 skies by ~1.7 %, so 5 % is a 3 sigma bound.
    """
    nside, lmax = 256, 400
    mask = masks.survey_mask("deep", nside)
    couplings = coupling.mask_coupling(mask, lmax, band=3 * nside - 1)  # the sky's band
    beam = hp.gauss_beam(np.radians(7 / 60), lmax=3 * nside - 1, pol=True)[:, 2]
    # The template carries the package's pixel window; give the sky the same one.
    window = predict.pixel_window(nside, 3 * nside - 1)
    cl_bb = 0.05 * theory.bb_tensor[: 3 * nside] * (beam * window) ** 2
    zero = np.zeros_like(cl_bb)
    template = predict.tensor_template(couplings, theory, 7.0, nside)
    estimates = []
    for seed in range(8):
        np.random.seed(seed)
        maps = hp.synfast([zero, zero, cl_bb, zero], nside, new=True)
        estimates.append(predict.delta_r(spectra.pseudo_spectra(maps, mask, lmax)[2], template))
    assert abs(np.mean(estimates) / 0.05 - 1) < 0.05


def test_sweep_cli_writes_table_and_continuum_figure(tmp_path):

    path = _sweep_files(tmp_path, "pbr_angle_deg = [0, 60, 90]")
    out = tmp_path / "cli"
    assert main(["-q", "sweep", path, "--out", str(out), "--scheduler", "serial"]) == 0
    assert (out / "results.csv").exists() and (out / "suppression.png").stat().st_size > 1000


def test_mask_coupling_is_reused_for_the_same_mask(monkeypatch):
    calls, original = [], coupling.mask_coupling

    def counting(mask, lmax, nthreads, band):
        calls.append((lmax, band))
        return original(mask, lmax, nthreads, band=band)

    monkeypatch.setattr(sweep.coupling, "mask_coupling", counting)
    sweep._COUPLING.clear()
    mask = masks.survey_mask("deep", 32)
    first = sweep._mask_coupling(mask, 60, 95, 1)
    again = sweep._mask_coupling(mask.copy(), 60, 95, 1)
    assert again is first and calls == [(60, 95)]
    other = sweep._mask_coupling(mask, 50, 95, 1)
    sweep._mask_coupling(np.ones_like(mask), 50, 95, 1)
    sweep._mask_coupling(np.ones_like(mask), 50, 80, 1)
    assert calls == [(60, 95), (50, 95), (50, 95), (50, 80)] and other.lmax == 50


@FUZZ
@given(
    spec=st.dictionaries(
        st.sampled_from(["base", "mode", "parameters", "colour"]),
        st.one_of(
            values,
            st.just("study.toml"),
            st.sampled_from(["grid", "list"]),
            st.dictionaries(
                st.sampled_from(["pbr_angle_deg", "sky.seed", "scan.n_phi", "x", "a.b.c"]),
                st.one_of(st.lists(scalars, max_size=3), scalars),
                max_size=3,
            ),
        ),
        max_size=4,
    )
)
def test_any_sweep_file_loads_or_names_its_error(spec, tmp_path_factory):
    base = tmp_path_factory.mktemp("sw")
    (base / "study.toml").write_text(FUZZ_STUDY)
    path = base / "sweep.toml"
    path.write_text(
        "".join(
            f"{k} = {v!r}\n".replace("True", "true").replace("False", "false")
            for k, v in spec.items()
            if not isinstance(v, dict)
        )
        + "".join(
            f"[{k}]\n" + "".join(f'"{a}" = {b!r}\n' for a, b in v.items())
            for k, v in spec.items()
            if isinstance(v, dict)
        )
    )
    try:
        sweep.load_sweep(str(path))
    except ConfigError as err:
        assert "\n" not in str(err)


def test_editing_the_base_config_recomputes_every_point(tmp_path, caplog):
    path = sweep_file(tmp_path)
    out = tmp_path / "out"
    first = sweep.run_sweep(path, out, scheduler="serial")
    (tmp_path / "study.toml").write_text(STUDY.replace("0.01, -0.01", "0.05, -0.05"))
    with pytest.raises(FileExistsError, match="another sweep"):
        sweep.run_sweep(path, out, scheduler="serial")
    with caplog.at_level(logging.INFO, logger="boresight.jobs.sweep"):
        again = sweep.run_sweep(path, out, scheduler="serial", force=True)
    assert "0 already done" in caplog.records[0].getMessage()
    # The residual is quadratic in dg at no rotation: 25 times larger.
    ratio = again[0]["residual_auto_bb"] / first[0]["residual_auto_bb"]
    assert abs(ratio / 25 - 1) < 1e-6  # exact up to rounding: the same sky and scan


@pytest.mark.parametrize(
    "damage",
    [
        lambda text: text[: len(text) // 2],  # truncated by a kill
        lambda text: json.dumps({**json.loads(text), "rows": []}),
        lambda text: json.dumps({k: v for k, v in json.loads(text).items() if k != "rows"}),
    ],
)
def test_corrupt_point_file_is_named_and_repaired(tmp_path, damage):
    path = sweep_file(tmp_path)
    out = tmp_path / "out"
    sweep.run_sweep(path, out, scheduler="serial")
    whole = (out / "results.csv").read_text()
    victim = sorted((out / "points").glob("*.json"))[0]
    victim.write_text(damage(victim.read_text()))
    with pytest.raises(ConfigError, match=victim.name):
        sweep.run_sweep(path, out, scheduler="serial")
    sweep.run_sweep(path, out, scheduler="serial", repair=True)
    assert (out / "results.csv").read_text() == whole


def test_truncated_sweep_json_is_repaired_or_forced(tmp_path, caplog):
    path = sweep_file(tmp_path)
    out = tmp_path / "out"
    sweep.run_sweep(path, out, scheduler="serial")
    whole = (out / "results.csv").read_text()
    marker = out / "sweep.json"
    marker.write_text(marker.read_text()[:20])
    with pytest.raises(FileExistsError, match="unreadable"):
        sweep.run_sweep(path, out, scheduler="serial")
    with caplog.at_level(logging.INFO, logger="boresight.jobs.sweep"):
        sweep.run_sweep(path, out, scheduler="serial", repair=True)
    said = [r.getMessage() for r in caplog.records if r.name == "boresight.jobs.sweep"]
    assert any("2 already done" in m for m in said), said  # other loggers may speak first
    assert (out / "results.csv").read_text() == whole
    marker.write_text("{")
    sweep.run_sweep(path, out, scheduler="serial", force=True)
    assert (out / "results.csv").read_text() == whole
