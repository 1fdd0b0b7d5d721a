"""A design for a pipeline that deprojects templates of T: the objective leaves out the leaks they
fit, the command says so, and its TOD check deprojects."""

import csv
import json
import logging

import pytest
from helpers import budget_file, run_design

from boresight import cli, design
from boresight.schedule import write_schedule

NSIDE = 32


def _budget(tmp_path, deprojection=None, skies=4, evaluation="interp"):
    tmp_path.mkdir(exist_ok=True)
    design = f'nside = {NSIDE}\nsweeps = 4\nvalidation_skies = {skies}\nevaluation = "{evaluation}"'
    return budget_file(
        tmp_path,
        systematics="dg = [0.01, -0.01]\nrho_arcmin = 0.5\nchi_deg = 30.0",
        design=design,
        **({} if deprojection is None else {"deprojection": deprojection}),
    )


def test_a_design_that_deprojects_the_gain_leaves_it_out(tmp_path, schedule, caplog):
    """Deprojecting the gain takes its leak of T (h_2 T) out of every strategy's delta_r, which
    falls by more than 3x without rotation, and the search then turns against the pointing's
    leak; the manifest and the log say what the pipeline deprojects."""
    plain = tmp_path / "plain"
    plain = run_design(plain, schedule, _budget(plain), "--no-validate")
    budget = _budget(tmp_path / "dep", "templates = ['gain']")
    src, out = tmp_path / "dep" / "s.toml", tmp_path / "dep" / "d"
    write_schedule(schedule, str(src), "toml")
    with caplog.at_level(logging.INFO, logger="boresight"):
        assert cli.main(["design", budget, str(src), "--out", str(out), "--no-validate"]) == 0
    assert "the pipeline deprojects gain: the objective leaves out h_2 T, h_2 S" in caplog.text
    rows = {
        name: {r["strategy"]: float(r["delta_r"]) for r in csv.DictReader(open(d / "strategies.csv"))}
        for name, d in (("plain", plain), ("deprojected", out))
    }  # fmt: skip
    assert rows["deprojected"]["none"] < rows["plain"]["none"] / 3
    assert rows["deprojected"]["optimised"] <= min(rows["deprojected"].values())
    manifest = json.load(open(out / "manifest.json"))["config"]
    assert manifest["deprojection"]["templates"] == ["gain"]
    assert json.load(open(plain / "manifest.json"))["config"]["deprojection"] is None
    assert design.load_budget(budget).deprojected == ("gain",)


@pytest.mark.slow
def test_its_tod_check_deprojects_and_agrees(tmp_path, schedule):
    """The TOD check runs the pipeline that deprojects (the gain template per CES), the sky read
    exactly (an interpolated TOD smooths the pointing's gradient, which the deprojected strategies
    leak): every strategy's TOD mean over 8 skies is its prediction within 3 standard errors."""
    budget = _budget(tmp_path, "templates = ['gain']", skies=8, evaluation="exact")
    out = run_design(tmp_path, schedule, budget)
    for row in csv.DictReader(open(out / "validation.csv")):
        mean, se = float(row["simulated_delta_r"]), float(row["simulated_delta_r_se"])
        predicted = float(row["predicted_delta_r"])
        assert abs(mean - predicted) < 3 * se, row
