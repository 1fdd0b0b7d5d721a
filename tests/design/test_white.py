"""boresight design: per-unit moments, the white-h_n objective, the optimiser, baselines and
the command."""

import csv

import numpy as np
import pytest
from helpers import EXAMPLES, budget_file, run_design

from boresight import cli, design, predict
from boresight import moments as scanstats
from boresight.design.exact import exact_objective, search
from boresight.instrument.pairs import Instrument, Spread, Systematics
from boresight.schedule import load_schedule, write_schedule

ALLOWED = (-90.0, -45.0, 0.0, 45.0, 90.0)
NSIDE = 32


BUDGET = Systematics(dg=(0.01, -0.01), rho_arcmin=0.5, chi_deg=30.0)
BEAMS = Systematics(dg=(0.01, -0.01), dfwhm_b_arcmin=0.3, ellipticity_b=0.01, ellipticity_a=0.02)
SPREAD = Systematics(dg=Spread(0.002, 0.01), pol_angle_deg=Spread(0.0, 0.5), rho_arcmin=0.3)


@pytest.mark.parametrize(
    "budget, instrument",
    [(BUDGET, None), (BEAMS, None), (SPREAD, Instrument("uniform", 4))],
    ids=["gain+pointing", "beams", "rms over 4 pairs"],
)
def test_objective_is_the_prediction_of_the_designed_schedule(
    schedule, moments, theory, budget, instrument
):
    """For random angles, the objective's delta_r equals predict.delta_r of
    predict.residual_pseudo_bb on the h_n that scanstats measures on the written-out schedule
    (for {mean, rms} budgets, its expectation over the focal plane's draws)."""
    obj = design.objective(moments, budget, theory, 30.0, instrument=instrument)
    rng = np.random.default_rng(3)
    for _ in range(3):
        angles = rng.choice(ALLOWED, moments.n_units)
        designed = moments.schedule(schedule, angles)
        stats = scanstats.characterise_schedule(designed, NSIDE)
        mask = (stats.hits > 0).astype(float)
        np.testing.assert_array_equal(np.flatnonzero(mask), moments.pixels)
        np.testing.assert_allclose(moments.full_sky(moments.h(angles))[1:], stats.h[1:], atol=1e-13)
        res = predict.residual_pseudo_bb(
            stats.h,
            mask,
            predict.Prediction(theory, obj.coupling, 30.0),
            budget,
            instrument=instrument,
            expected=design.drawn(budget),
        )
        expected = predict.delta_r(res, obj.template)
        assert obj.delta_r(angles) == pytest.approx(expected, rel=1e-12)


def test_ellipticity_is_a_floor_no_schedule_moves_and_rms_falls_as_one_over_n(moments, theory):
    """An ellipticity's h_0 term is the same for every schedule (its first-order cross term with
    the sky's E, through TE and the mask's E-to-B leakage, makes it negative here); a zero-mean
    rms budget's delta_r falls as 1 / N_pairs exactly (every term is rms^2 / N)."""
    obj = design.objective(moments, Systematics(ellipticity_b=0.02), theory, 30.0)
    values = [obj.delta_r(a) for a in design.baselines(moments.n_units, ALLOWED).values()]
    assert abs(obj.leaked_const) > 1e-4
    assert np.ptp(values) < 0.02 * abs(obj.leaked_const)
    zero_mean = Systematics(dg=Spread(0.0, 0.01), rho_arcmin=Spread(0.0, 0.3))
    angles = np.zeros(moments.n_units)
    dr = {
        n: design.objective(moments, zero_mean, theory, 30.0, instrument=Instrument("uniform", n))
        for n in (4, 16)
    }
    assert dr[4].delta_r(angles) == pytest.approx(4 * dr[16].delta_r(angles), rel=1e-10)


@pytest.mark.slow
def test_gain_alone_is_cancelled_by_90_degree_pairs(moments, theory):
    """The design rule: with a gain error only, the search over {0, 90} makes h_2 vanish (each
    CES and its repeat at 0 and 90 deg), leaving the h_4 E-to-B term."""
    gain = Systematics(dg=(0.01, -0.01))
    obj = exact_objective(moments, gain, theory, 30.0)
    found = search(obj, (0.0, 90.0), np.zeros(moments.n_units), sweeps=10, seed=1)
    h = moments.h(found.angles_deg)
    assert np.mean(np.abs(h[2]) ** 2) < 1e-20
    for angles in design.baselines(moments.n_units, (0.0, 90.0)).values():
        assert found.value <= obj.delta_r(angles) + 1e-12


@pytest.mark.xdist_group("timing")  # not beside the signals test (its latency)
@pytest.mark.slow
def test_design_command_on_the_deep_example(tmp_path):
    """The check: the gain + pointing + ellipticity budget of examples/budget_deep_sat.toml on
    examples/schedule_deep_sat.toml, at Nside 64 with 2 skies per strategy (the bench runs the
    example itself, with 16). The optimised schedule's predicted delta_r is below every
    baseline's, and for every strategy the TOD's mean total and leaked delta_r follow the
    prediction within 20 % or 3 standard errors (two skies of one patch scatter by about 10 %,
    and their standard error is itself uncertain)."""

    budget = tmp_path / "budget.toml"
    text = open(EXAMPLES / "budget_deep_sat.toml").read().replace("nside = 128", "nside = 64")
    budget.write_text(text + "restarts = 1\nvalidation_skies = 2\n")
    out = tmp_path / "d"
    schedule = tmp_path / "deep.toml"  # at 4 Hz: about 4 samples per crossing of an Nside-64 pixel
    schedule.write_text(
        (EXAMPLES / "schedule_deep_sat.toml")
        .read_text()
        .replace("sample_rate_hz = 20.0", "sample_rate_hz = 4.0")
    )
    args = [str(budget), str(schedule), "--out", str(out)]
    assert cli.main(["-q", "design", *args]) == 0
    rows = {
        r["strategy"]: float(r["delta_r"]) for r in csv.DictReader(open(out / "strategies.csv"))
    }
    assert (
        min(rows, key=rows.get) == "optimised" and len(rows) == 8
    )  # 6 baselines, as given, optimised
    checked = list(csv.DictReader(open(out / "validation.csv")))
    assert {r["strategy"] for r in checked} == set(rows)
    for row in checked:
        for key in ("", "leaked_"):
            sim, pred = float(row[f"simulated_{key}delta_r"]), float(row[f"predicted_{key}delta_r"])
            se = float(row[f"simulated_{key}delta_r_se"])
            assert abs(sim - pred) < max(0.2 * abs(pred), 3 * se), (row["strategy"], key)
    designed = load_schedule(str(out / "schedule_designed.toml"))
    assert len(designed.ces) == 48 and designed.site == load_schedule(args[1]).site
    assert (out / "design.png").stat().st_size > 0 and (out / "hn_before_after.png").is_file()


@pytest.mark.slow
def test_design_command_speaks_toast_and_refuses_bad_budgets(tmp_path, schedule):
    from boresight.schedule import toast

    src = tmp_path / "in.txt"
    toast.write(schedule, src)
    out = tmp_path / "d"
    args = ["--sample-rate", "2", "--no-validate"]
    assert (
        cli.main(["-q", "design", budget_file(tmp_path), str(src), "--out", str(out), *args]) == 0
    )
    designed = load_schedule(str(out / "schedule_designed.txt"))
    assert len(designed.ces) == 2 * len(schedule.ces) and not (out / "validation.csv").exists()
    assert cli.main(["-q", "design", budget_file(tmp_path, design="angles_deg = []"), str(src),
                     "--out", str(tmp_path / "e")]) == 2  # fmt: skip
    assert not (tmp_path / "e").exists()


def test_ctrl_c_during_the_search_keeps_the_best_schedule(tmp_path, schedule, monkeypatch):
    """An interrupt in the coordinate descent still writes the best schedule so far (and says
    so in the manifest), skips the TOD check and exits 130."""
    import json

    original = search
    calls = []

    def interrupting(*args, **kwargs):
        def stop(_):
            calls.append(1)
            if len(calls) == 3:
                raise KeyboardInterrupt

        return original(*args, **{**kwargs, "progress": stop})

    monkeypatch.setattr("boresight.design.job.search", interrupting)
    src = tmp_path / "s.toml"
    write_schedule(schedule, str(src), "toml")
    out = tmp_path / "d"
    assert cli.main(["-q", "design", budget_file(tmp_path), str(src), "--out", str(out)]) == 130
    assert load_schedule(str(out / "schedule_designed.toml")).ces
    config = json.loads((out / "manifest.json").read_text())["config"]
    assert config["search_interrupted"] is True and config["validation"] == "skipped"
    assert not (out / "validation.csv").exists()


@pytest.mark.slow
def test_interrupt_during_the_validation_keeps_the_finished_design(
    tmp_path, schedule, monkeypatch, capsys
):
    """After --force over an older design, Ctrl-C in the TOD validation writes the finished search
    (not the older design, and not nothing), says so, and exits 130; SIGTERM exits 143."""
    import json
    import signal

    from boresight._util import interrupts

    src = tmp_path / "s.toml"
    write_schedule(schedule, str(src), "toml")
    out = tmp_path / "d"
    budget = budget_file(tmp_path)
    assert cli.main(["-q", "design", budget, str(src), "--out", str(out), "--no-validate"]) == 0
    (out / "strategies.csv").write_text("an older design\n")
    for signum, code in ((signal.SIGINT, 130), (signal.SIGTERM, 143)):

        def stopped(*args, signum=signum, **options):
            raise interrupts.Interrupted(signum)

        monkeypatch.setattr("boresight.design.job.tod_check", stopped)
        args = ["-q", "design", budget, str(src), "--out", str(out), "--force"]
        assert cli.main(args) == code
        err = capsys.readouterr().err
        assert f"the finished design is in {out}, without its TOD validation" in err
        config = json.loads((out / "manifest.json").read_text())["config"]
        assert config["search_interrupted"] is False and config["validation"] == "interrupted"
        assert "optimised" in (out / "strategies.csv").read_text()
        assert not (out / "validation.csv").exists()


@pytest.mark.slow
@pytest.mark.parametrize("evaluation", ["interp", "exact"])
def test_design_on_the_axis_focal_plane_is_the_on_axis_design(tmp_path, schedule, evaluation):
    """`[instrument] focalplane = "axis"` (the paper's pairs on the boresight, each pair on its
    own samples) gives every strategy the on-axis objective's delta_r, to rounding: the
    focal-plane expectation reduces to the shared-h_n one; read exactly, each pair's samples'
    offsets from their pixel centres give the on-axis objective's offset terms."""

    budget = budget_file(
        tmp_path,
        design="nside = 16\nsweeps = 2\nrestarts = 0\nangles_deg = [0.0, 90.0]\n"
        f'evaluation = "{evaluation}"',
        instrument='focalplane = "axis"',
    )
    out = run_design(tmp_path, schedule, budget, "--no-validate")
    rows = list(csv.DictReader(open(out / "strategies.csv")))
    assert len(rows) == 8
    for row in rows:
        total, axis = float(row["delta_r"]), float(row["delta_r_on_axis"])
        assert abs(total - axis) < 1e-8 * abs(axis), row["strategy"]
        parts = float(row["fp_delta_r_coherent"]) + float(row["fp_delta_r_scattered"])
        assert abs(parts - total) < 1e-12 * abs(total)


@pytest.mark.slow
def test_design_on_a_hexagon_focal_plane_reports_every_strategy_on_it(tmp_path, schedule):
    """TOAST's 7-pixel, 20 deg hexagon, a gain drawn per pair, a pointing offset and an
    elliptical beam: every strategy gets the focal plane's delta_r, its coherent and scattered
    parts adding up, beside the on-axis search objective's, and validation.csv runs every
    strategy's TOD on the focal plane (engine.simulate_focalplane, each detector through its own
    beam) against that prediction. The search runs on the focal plane's own per-angle moments
    (the beams' terms through each pair's own h_n) and ends at or below every baseline it could
    start from."""

    budget = budget_file(
        tmp_path,
        systematics="dg = {mean = 0.002, rms = 0.002}\nrho_arcmin = 0.5\nellipticity_a = 0.02\n"
        "seed = 3",
        design="nside = 16\nsweeps = 4\nrestarts = 1\nvalidation_skies = 2\n"
        "angles_deg = [0.0, 45.0, 90.0]",
        instrument='focalplane = "hexagon:7:20"',
    )
    out = run_design(tmp_path, schedule, budget)
    rows = {r["strategy"]: r for r in csv.DictReader(open(out / "strategies.csv"))}
    for row in rows.values():
        coherent, scattered = float(row["fp_delta_r_coherent"]), float(row["fp_delta_r_scattered"])
        assert coherent > 0 and scattered > 0
        assert abs(coherent + scattered - float(row["delta_r"])) < 1e-12 * coherent
    # the search on the focal plane's own moments beats every baseline it could start from
    startable = ("none", "paper 0/90", "stepped", "random")  # within the allowed 0, 45, 90
    best = min(float(rows[k]["delta_r"]) for k in startable)
    assert float(rows["optimised"]["delta_r"]) <= best
    history = list(csv.DictReader(open(out / "history.csv")))
    assert {"round"} <= set(history[0]) and len(history) > 2
    checked = list(csv.DictReader(open(out / "validation.csv")))
    assert {r["strategy"] for r in checked} == set(rows)
    for row in checked:
        assert float(row["predicted_delta_r"]) == float(rows[row["strategy"]]["delta_r"])
        assert (
            np.isfinite(float(row["simulated_delta_r"]))
            and float(row["simulated_leaked_delta_r"]) > 0
        )


@pytest.mark.slow
def test_a_design_read_exactly_validates_with_the_samples_offsets(tmp_path, schedule):
    """`evaluation = "exact"`: the TOD check reads the band-limited sky at every sample, and
    the prediction it is checked against carries the samples' offsets from their pixel centres,
    as the search's objective does (the same number to rounding); the manifest records the
    reading."""
    import json

    budget = budget_file(
        tmp_path,
        systematics="rho_arcmin = 3.0\nchi_deg = 30.0",
        design="nside = 16\nsweeps = 2\nrestarts = 0\nangles_deg = [0.0, 90.0]\n"
        'validation_skies = 2\nevaluation = "exact"',
    )
    out = run_design(tmp_path, schedule, budget)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["design"]["evaluation"] == "exact"
    objective = {
        r["strategy"]: float(r["delta_r"]) for r in csv.DictReader(open(out / "strategies.csv"))
    }
    checked = list(csv.DictReader(open(out / "validation.csv")))
    assert len(checked) == 8
    for row in checked:
        assert float(row["predicted_delta_r"]) == pytest.approx(
            objective[row["strategy"]], rel=1e-9, abs=1e-15
        )


def test_a_design_of_thousands_of_allowed_angles_is_refused_and_units_are_estimated():
    """7,200 allowed angles ran for hours; 4,000 units died allocating their alm after the search
    began: the angles are bounded, and each unit's alm is in the estimate."""
    from boresight.design.white import DesignOptions
    from boresight.jobs import resources

    with pytest.raises(ValueError, match="lists 7200 angles; at most 720"):
        DesignOptions(angles_deg=tuple(np.arange(7200) * 0.05))
    schedule = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    few, many = (
        resources.schedule_estimate("design", schedule, 128, design_units=n) for n in (48, 4000)
    )
    # 4 channels x (E, B) x the alm to 2 lmax, complex: 1.1 MB a unit at Nside 128
    assert many.parts["unit alm"] / 4000 == few.parts["unit alm"] / 48
    assert many.parts["unit alm"] / 4000 == pytest.approx(16 * 8 * 513 * 514 / 2)
