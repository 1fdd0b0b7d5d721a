"""The command line end to end, and its handling of bad input."""

import csv

import healpy as hp
import numpy as np
import pytest
from helpers import T0, toast_schedule

from boresight import cli
from boresight.cli import main
from boresight.jobs import paper
from boresight.schedule import toast


@pytest.mark.slow
def test_reproduce_quick_end_to_end(tmp_path):
    out = tmp_path / "paper"
    # Nside 256 is the lowest resolution at which every verdict holds (README); the quick
    # preset's own Nside 512 is the README's main command, run by `reproduce --quick`.
    assert main(["-q", "reproduce", "--quick", "--nside", "256", "--out", str(out)]) == 0
    for stem in (
        "fig1_pointing_wide",
        "fig2_gain_deep",
        "fig3_pointing_angles",
        "fig4_gain_angles",
        "fig5_wide_mask",
        "fig6_deep_mask",
    ):
        for ext in ("png", "pdf"):
            assert (out / f"{stem}.{ext}").stat().st_size > 1000
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert set(paper.CSV_COLUMNS) <= set(rows[0])
    assert {r["experiment"] for r in rows} == {"pointing_wide", "gain_deep"}
    assert {r["pbr_angle_deg"] for r in rows} == {
        "",
        "180.0",
        "179.0",
        "160.0",
        "90.0",
        "89.0",
        "70.0",
    }
    report = (out / "report.md").read_text()
    verdicts = [
        line.rsplit("|", 2)[-2].strip()
        for line in report.splitlines()
        if line.startswith("| pointing_wide") or line.startswith("| gain_deep")
    ]
    assert len(verdicts) == 18 and set(verdicts) == {"reproduced"}
    assert '"git_revision"' in (out / "manifest.json").read_text()
    # An existing directory is kept without --force.
    assert main(["-q", "reproduce", "--quick", "--nside", "256", "--out", str(out)]) == 2


BASE = {
    "sky": {"nside": 32, "lmax": 64, "fwhm_arcmin": 120.0},
    "scan": {"n_phi": 3, "range_rad": 0.5, "rotations_deg": [0.0, 90.0]},
    "systematics": {"dg": [0.01, -0.01]},
    "mask": {"survey": "deep"},
    "output": {"lmax": 60, "n_bands": 5},
}


def _toml(config):
    def value(v):
        return repr(v) if not isinstance(v, bool) else str(v).lower()

    return "".join(
        f"[{section}]\n" + "".join(f"{k} = {value(v)}\n" for k, v in body.items())
        for section, body in config.items()
    )


def _write(tmp_path, config):
    path = tmp_path / "study.toml"
    path.write_text(_toml(config))
    return str(path)


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        ("sky", "colour", 1, "unknown key sky.colour"),
        ("sky", "nside", "big", "sky.nside"),
        ("sky", "nside", 48, "nside must be a power of two"),
        ("systematics", "rho_arcmin", -0.1, "rho_arcmin must be >= 0"),
        ("scan", "rotations_deg", [], "rotations_deg"),
        ("mask", "file", "nowhere.fits", "file not found"),
        ("telescope", "x", 1, "unknown section [telescope]"),
        ("run", "evaluation", "magic", "run.evaluation"),
        ("run", "analysis", "fast", "run.analysis"),
    ],
)
def test_bad_config_exits_2_and_writes_nothing(tmp_path, capsys, section, key, value, message):
    config = {k: dict(v) for k, v in BASE.items()}
    config.setdefault(section, {})[key] = value
    if key == "file":
        del config["mask"]["survey"]
    out = tmp_path / "out"
    assert main(["simulate", _write(tmp_path, config), "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_simulate_writes_healpy_readable_maps(tmp_path):
    out = tmp_path / "sim"
    assert main(["-q", "simulate", _write(tmp_path, BASE), "--out", str(out)]) == 0
    q, u, hits = hp.read_map(str(out / "maps_systematics.fits"), field=(1, 2, 3))  # I, Q, U, HITS
    header = dict(hp.read_map(str(out / "maps_systematics.fits"), h=True)[1])
    assert header["POLCCONV"] == "COSMO" and header["ORDERING"] == "RING"
    assert q.size == 12 * 32**2 and np.all(hits[q != hp.UNSEEN] == 6)
    with open(out / "spectra.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 61 and "residual_bb" in rows[0]
    assert (out / "residual.png").exists() and (out / "manifest.json").exists()


def test_predict_and_scan_stats(tmp_path, capsys):
    path = _write(tmp_path, BASE)
    assert main(["-q", "predict", path]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "ell,predicted_bb" and len(lines) == 62
    assert main(["-q", "scan-stats", path, "--out", str(tmp_path / "stats")]) == 0
    re_h2 = hp.read_map(str(tmp_path / "stats" / "hn_maps.fits"), field=1)
    # With rotations (0, 90 deg) h_2 cancels in every observed pixel.
    assert np.max(np.abs(re_h2[re_h2 != hp.UNSEEN])) < 1e-15


def test_log_holds_only_boresight_lines(tmp_path, caplog):
    """healpy's graticule logs its spacing at INFO: the CLI's log shows boresight's lines only
    (the control, with every logger at INFO, shows the line the test looks for)."""
    import logging

    from boresight import cli
    from boresight.outputs import plots

    cli.configure_logging()
    logging.getLogger("boresight").info("own line")
    plots.footprint_figure(np.ones(12 * 16**2), "t", tmp_path / "f")
    messages = [r.getMessage() for r in caplog.records]
    assert "own line" in messages
    assert not any("interval between parallels" in m for m in messages)
    with caplog.at_level(logging.INFO):  # the control: every logger at INFO
        plots.footprint_figure(np.ones(12 * 16**2), "t", tmp_path / "f")
    assert any("interval between parallels" in r.getMessage() for r in caplog.records)


def _four_ces(path):
    path.write_text(
        "sample_rate_hz = 2.0\nrepeat_boresight_deg = [0.0, 90.0]\n"
        + "".join(
            f"[[ces]]\nstart_unix = {T0 + 3600 * i}\nduration_s = 600\n"
            f"elevation_deg = 50\naz_centre_deg = {134 if i % 2 else 226}\n"
            "az_throw_deg = 60\n"
            for i in range(4)
        )
    )
    return str(path)


def _scan_stats(out):
    lines = (out / "scan_stats.csv").read_text().splitlines()
    return [dict(zip(lines[0].split(","), line.split(","))) for line in lines[1:]]


def test_compare_scans_cli(tmp_path):
    from boresight.cli import main

    schedule = _four_ces(tmp_path / "s.toml")
    out = tmp_path / "cmp"
    assert main(["-q", "compare-scans", schedule, "--out", str(out), "--nside", "32"]) == 0
    assert (out / "compare.png").exists() and (out / "scan_maps.fits").exists()
    real, twin = _scan_stats(out)
    # A 90 deg repeat cancels h_2 in the real scan and in its twin alike.
    assert float(real["mean_abs_h2_sq"]) < 1e-25 and float(twin["mean_abs_h2_sq"]) < 1e-25
    assert (
        main(["-q", "compare-scans", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "x")])
        == 2
    )


@pytest.mark.slow
def test_compare_scans_with_a_focal_plane(tmp_path):
    """The real scans seen by every pair from its place: on the axis, today's numbers; a 10 deg
    hexagon keeps h_2 through a 0/90 repeat (its pairs move on the sky as the boresight turns),
    while the twin on the axis still cancels it."""
    schedule = _four_ces(tmp_path / "s.toml")
    args = ["-q", "compare-scans", schedule, "--nside", "16"]
    runs = {}
    for name, flags in (("boresight", []), ("axis", ["--focalplane", "axis"])):
        assert main([*args, "--out", str(tmp_path / name), *flags]) == 0
        with open(tmp_path / name / "compare.csv") as f:
            runs[name] = list(csv.DictReader(f))
    for a, b in zip(*runs.values()):
        for key in a:
            assert float(a[key]) == pytest.approx(float(b[key]), rel=1e-9, abs=1e-30), key
    out = tmp_path / "hex"
    assert main([*args, "--out", str(out), "--focalplane", "hexagon:7:20"]) == 0
    real, twin = _scan_stats(out)
    assert float(real["mean_abs_h2_sq"]) > 1e-3 and float(twin["mean_abs_h2_sq"]) < 1e-25
    manifest = (out / "manifest.json").read_text()
    assert '"focalplane": "hexagon:7:20"' in manifest
    bad = ["--out", str(tmp_path / "bad"), "--focalplane", "hexagon:7"]
    assert main([*args, *bad]) == 2 and not (tmp_path / "bad").exists()


def test_a_study_takes_a_focal_plane_on_the_axis_only(tmp_path, capsys):
    study = tmp_path / "study.toml"
    (tmp_path / "fp.csv").write_text(
        "name,xi_deg,eta_deg,gamma_deg,pol_angle_deg\n"
        "q_A,0,0,0,0\nq_B,0,0,90,90\nu_A,0,0,45,45\nu_B,0,0,135,135\n"
    )
    body = "[sky]\nnside = 16\nlmax = 32\n[scan]\nn_phi = 4\n[systematics]\ndg = 0.01\n"
    rows = {}
    for name, instrument in (("own", ""), ("file", "focalplane = 'fp.csv'\n")):
        study.write_text(body + "[instrument]\n" + instrument)
        assert main(["-q", "predict", str(study)]) == 0
        rows[name] = capsys.readouterr().out
    assert rows["own"] == rows["file"] and rows["own"].count("\n") == 34
    study.write_text(body + "[instrument]\nfocalplane = 'hexagon:7:20'\n")
    assert main(["-q", "predict", str(study)]) == 2
    err = capsys.readouterr().err
    assert "hexagon:7:20" in err and "off the boresight" in err and err.count("\n") == 1


def test_export_schedule_cli(tmp_path, capsys):
    src = tmp_path / "in.txt"
    toast.write(toast_schedule(), src)
    out = tmp_path / "out.txt"
    assert cli.main(["export-schedule", str(src), "--out", str(out)]) == 0
    assert "SimGround(" in capsys.readouterr().out
    assert out.read_text() == src.read_text()
    assert cli.main(["export-schedule", str(src), "--out", str(out)]) == 2  # exists
    assert cli.main(["export-schedule", str(src), "--out", str(out), "--force"]) == 0
