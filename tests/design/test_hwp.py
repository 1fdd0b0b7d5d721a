"""The design behind a half-wave plate: the plate as the design sees it (its baselines' steps,
the pairs' reflected moments, the plate the TOD sees), and the command behind a stepped and a
continuous plate."""

import csv

import numpy as np
import pytest
from helpers import budget_file, run_design

from boresight import design
from boresight.design.exact import exact_objective
from boresight.design.hwp import Plate
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Systematics
from boresight.moments import unit_moments

NSIDE = 32


def test_the_plate_as_the_design_sees_it(tmp_path, schedule, moments):
    """No plate: the pairs' own h_n and no steps. A stepped plate: the baselines take its steps in
    turn, unit by unit, and the pairs' moments are those of their reflected angle a + 2 b, which
    turning every unit by 2 b gives; the plate the TOD sees steps per unit."""
    bare = Plate.of(design.load_budget(budget_file(tmp_path)), schedule, moments)
    angles = np.zeros(moments.n_units)
    assert bare.hwp is None and bare.baseline is None and bare.seen(moments, None) is None
    np.testing.assert_array_equal(bare.pairs_h(moments, angles, None), moments.h(angles))
    budget = design.load_budget(
        budget_file(
            tmp_path,
            systematics="dg = [0.005, -0.005]",
            hwp="mode = 'stepped'\nangles_deg = [0.0, 22.5, 45.0, 67.5]",
        )
    )
    plate = Plate.of(budget, schedule, moments)
    assert plate.allowed == (0.0, 22.5, 45.0, 67.5)
    want = np.array([0.0, 22.5, 45.0, 67.5] * moments.n_units)[: moments.n_units]
    np.testing.assert_array_equal(plate.baseline, want)
    np.testing.assert_array_equal(
        plate.pairs_h(moments, angles, plate.baseline), moments.h(2 * plate.baseline)
    )
    seen = plate.seen(moments, plate.baseline)
    assert isinstance(seen, HWP) and seen.stepped


@pytest.mark.slow
def test_design_behind_a_stepped_plate_chooses_its_steps(tmp_path, schedule):
    """A budget with a stepped HWP (its IP 5e-3) and a gain mismatch: the search chooses each
    unit's boresight angle and plate step. The IP needs the boresight (a 0/90 pair of repeats of
    one CES cancels its h_2), the gain the pairs' reflected angle a + 2 b, so the optimum is
    below every baseline (the plate's steps in turn) by more than 10x; units.csv has the steps;
    the IP-only budget is accepted; every strategy's TOD mean over 8 skies is the prediction
    within 3 standard errors or 10 %."""
    budget = budget_file(
        tmp_path,
        systematics="dg = [0.005, -0.005]",
        design=f"nside = {NSIDE}\nsweeps = 4\nangles_deg = [0.0, 45.0, 90.0]\nvalidation_skies = 8",
        hwp="mode = 'stepped'\nip = 5e-3\nip_phase_deg = 30.0",
    )  # fmt: skip
    out = run_design(tmp_path, schedule, budget)
    rows = {r["strategy"]: r for r in csv.DictReader(open(out / "strategies.csv"))}
    best = float(rows.pop("optimised")["delta_r"])
    assert all(abs(best) < 0.1 * float(r["delta_r"]) for r in rows.values())
    units = list(csv.DictReader(open(out / "units.csv")))
    assert {float(u["hwp_step_deg"]) for u in units} <= {0.0, 22.5, 45.0, 67.5}
    for row in csv.DictReader(open(out / "validation.csv")):
        mean, se = float(row["simulated_delta_r"]), float(row["simulated_delta_r_se"])
        predicted = float(row["predicted_delta_r"])
        assert abs(mean - predicted) < max(3 * se, 0.1 * abs(predicted)), row
    only_ip = design.load_budget(
        budget_file(tmp_path, systematics="dg = 0.0", hwp="mode = 'continuous'\nip = 1e-3")
    )
    assert only_ip.hwp.ip == 1e-3


@pytest.mark.slow
def test_design_behind_a_continuous_plate_is_its_objective(tmp_path, schedule, moments, theory):
    """Behind a plate spinning at 0.3 Hz (2 Hz samples), the command's delta_r of every
    strategy is the exact objective with the units' moments of psi + 2 chi, and the search
    cancels the IP's h_2 with the 0/90 repeats of each CES; no steps are written."""
    budget = budget_file(
        tmp_path,
        systematics="dg = [0.005, -0.005]",
        design=f"nside = {NSIDE}\nsweeps = 4\nangles_deg = [0.0, 90.0]",
        hwp="mode = 'continuous'\nfrequency_hz = 0.3\nip = 5e-3",
    )  # fmt: skip
    out = run_design(tmp_path, schedule, budget, "--no-validate")
    plate = design.load_budget(budget).hwp
    spun = unit_moments(schedule, NSIDE, "ces", hwp=plate)
    obj = exact_objective(
        moments, Systematics(dg=(0.005, -0.005)), theory, 30.0, hwp=plate, plate_moments=spun
    )
    rows = {r["strategy"]: r for r in csv.DictReader(open(out / "strategies.csv"))}
    for name, angles in design.baselines(moments.n_units, (0.0, 90.0)).items():
        assert float(rows[name]["delta_r"]) == pytest.approx(obj.delta_r(angles), rel=1e-9)
    units = list(csv.DictReader(open(out / "units.csv")))
    assert "hwp_step_deg" not in units[0]
    assert float(rows["optimised"]["delta_r"]) < 0.1 * float(rows["none"]["delta_r"])
