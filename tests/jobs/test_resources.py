"""The memory and time estimates: every command's estimate within a factor of 1.5 of the peak that
the kernel measures for a fresh process, across Nside (bench/bench_memory.py measures all of them
to Nside 512), with detector beams; and jobs too long or too large refused before any work."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from bench_memory import command_args, measure  # noqa: E402

from boresight import cli
from boresight.jobs import resources  # noqa: E402
from boresight.schedule import CES, Schedule, write_schedule

ROOT = Path(__file__).resolve().parents[2]
FACTOR = 1.5  #: the estimate may be this much above or below the measured peak
#: (command, Nside) measured here: every command at 64, a focal plane's at 128 (its per-pair sums
#: on the observed pixels), four of a few seconds at 256, one at 512
#: (bench_memory.py runs every command at 64, 128, 256 and 512)
CASES = [
    *((c, 64) for c in ("simulate", "simulate (beams)", "predict", "scan-stats (schedule)",
                        "scan-stats (focal plane)", "compare-scans", "design", "suppression",
                        "suppression (filter)", "suppression (deproject)", "reproduce")),
    *((c, 128) for c in ("scan-stats (focal plane)", "scan-stats (per detector)",
                         "scan-stats (per detector, a season)")),
    *((c, 256) for c in ("simulate", "predict (beams)", "scan-stats", "compare-scans",
                         "scan-stats (hwp)")),
    ("predict", 512),
]  # fmt: skip


def _peak_and_estimate(args, out):
    """(the fresh process's peak resident GiB, the estimate its manifest holds)."""
    peak, _, estimate = measure(args, out)
    return peak, estimate


@pytest.mark.parametrize("command, nside", CASES)
@pytest.mark.slow
def test_memory_estimate_is_within_1p5_of_the_measured_peak(command, nside, tmp_path):
    peak, estimate = _peak_and_estimate(command_args(command, tmp_path, nside), tmp_path / "o")
    ratio = estimate["memory_gib"] / peak
    assert 1 / FACTOR < ratio < FACTOR, (command, nside, peak, estimate)


@pytest.mark.slow
def test_beam_analysis_grids_and_convolution_cubes_are_estimated(tmp_path):
    """A narrow elliptical beam's analysis grid (it peaked at 6.8 GiB against an estimate of
    0.036 GiB) and one convolution cube per drawn beam (64 beams kept 19.7 GiB): each estimated
    within the factor."""
    study = (ROOT / "examples" / "gain_deep.toml").read_text()
    cases = {
        "grid": ("ellipticity_b = 0.6", 16, "predict"),
        "cubes": ("ellipticity_b = {mean = 0.03, rms = 0.01}", 32, "simulate"),
    }
    for name, (beam, nside, command) in cases.items():
        text = study.replace("dg = [0.01, -0.01]", beam).replace("nside = 256", f"nside = {nside}")
        text = text.replace("lmax = 767", f"lmax = {3 * nside - 1}")
        text = text.replace("lmax = 512", f"lmax = {2 * nside}")
        if name == "cubes":
            text = text.replace("fwhm_arcmin = 7.0", "fwhm_arcmin = 60.0")
            text = text.replace("[0.0, 45.0]", '"uniform"\nn_pairs = 16')
        path = tmp_path / f"{name}.toml"
        path.write_text(text)
        peak, estimate = _peak_and_estimate([command, str(path)], tmp_path / name)
        assert estimate["parts_gib"]["beams"] > 0.3 * peak, (name, estimate)
        assert 1 / FACTOR < estimate["memory_gib"] / peak < FACTOR, (name, peak, estimate)


def _long_schedule(tmp_path, days):
    ces = tuple(CES(1.79e9 + 86400 * d, 86000.0, 50.0, 140.0, 30.0) for d in range(days))
    path = tmp_path / "long.toml"
    write_schedule(Schedule(ces, sample_rate_hz=1000.0), path, "toml")
    return str(path)


def test_a_run_of_hours_is_refused_up_front_unless_yes(tmp_path, capsys, monkeypatch):
    """A schedule of 1e11 samples started and ran for hours: now refused at once with the
    estimate; --yes accepts it (the job is stopped here before its work)."""
    import time

    from boresight.validation import BoresightError

    path = _long_schedule(tmp_path, 1200)  # 1.0e11 samples at 1 kHz
    t0 = time.perf_counter()
    assert cli.main(["scan-stats", path, "--out", str(tmp_path / "o"), "--nside", "16"]) == 2
    err = capsys.readouterr().err
    assert "scan-stats would take about 115 min on this machine (1.03e+11" in err and "--yes" in err
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "o").exists()

    def stop(*args, **kwargs):
        raise BoresightError("stopped after the checks")

    monkeypatch.setattr("boresight.moments.characterise_schedule", stop)
    args = ["scan-stats", path, "--out", str(tmp_path / "o"), "--nside", "16", "--yes"]
    assert cli.main(args) == 2
    assert "stopped after the checks" in capsys.readouterr().err


def test_design_of_many_pairs_is_refused_for_its_validation(tmp_path, capsys):
    """design with 10^6 pairs was still in its TOD validation after 120 s; 10^5 pairs would take
    some 160 hours (the deep example's 1.4e6 samples per pair, 64 times: 8 strategies, the
    schedule as given among them, on 4 skies, each with and without the systematics)."""
    budget = (ROOT / "examples" / "budget_deep_sat.toml").read_text()
    budget = budget.replace("nside = 128", "nside = 32")
    budget += '\n[instrument]\npair_angles_deg = "uniform"\nn_pairs = 100000\n'
    budget = budget.replace("dg = [0.01, -0.01]", "dg = 0.01")
    path = tmp_path / "budget.toml"
    path.write_text(budget)
    schedule = str(ROOT / "examples" / "schedule_deep_sat.toml")
    assert cli.main(["design", str(path), schedule, "--out", str(tmp_path / "d")]) == 2
    assert "design would take about 160.0 h on this machine" in capsys.readouterr().err


def test_predict_of_many_pairs_is_not_refused_for_hits_it_never_makes(tmp_path):
    """predict with 10^5 pairs was refused at 1,172 GiB and ran in 0.29 GiB: a prediction holds
    no hits, so the pairs do not enter its memory."""
    from boresight.config import parse_study

    study = parse_study(
        {
            "sky": {"nside": 64, "lmax": 191},
            "instrument": {"pair_angles_deg": "uniform", "n_pairs": 100_000},
            "systematics": {"dg": 0.01},
        }
    )
    estimate = resources.study_estimate("predict", study)
    assert estimate.bytes < 1.0 * resources.GIB and estimate.seconds < 1.0
    assert resources.study_estimate("simulate", study).bytes > 100 * resources.GIB
