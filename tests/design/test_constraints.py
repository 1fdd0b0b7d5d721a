"""The mount's constraints: angles allowed per elevation range and patch, the most changes per
day; the search never leaves them, and the table says what each one costs."""

import csv
import logging
from dataclasses import replace

import numpy as np
import pytest
from helpers import budget_file, run_design

from boresight._util.provenance import Timer
from boresight.config import ConfigError
from boresight.design import budget as budget_module
from boresight.design.constraints import AngleRule, Constraints, Feasibility
from boresight.design.job import design as design_job
from boresight.moments.units import units_of
from boresight.schedule import CES, Schedule, load_schedule

LOW_ZERO = "[[constraints.angles]]\nelevation_deg = [0, 45]\nangles_deg = [0.0]"


def rows_at(elevations, names=None, hours=1.0):
    names = names or ["ces"] * len(elevations)
    return tuple(
        CES(1.8e9 + 3600.0 * hours * i, 1800.0, el, 180.0, 30.0, name=name)
        for i, (el, name) in enumerate(zip(elevations, names))
    )


def test_rules_bind_units_by_elevation_and_patch():
    rows = rows_at([40, 50, 44.9, 45, 60], ["a", "a", "b", "b", "b"])
    rules = (AngleRule((0, 45), (0.0,)), AngleRule((45, 90), (0.0, 90.0), patch="b"))
    feas = Feasibility(Constraints(rules), rows, [[i] for i in range(5)])
    assert feas.allowed == [{0.0}, None, {0.0}, {0.0, 90.0}, {0.0, 90.0}]
    assert feas.ok([0, 45, 0, 90, 0]) and feas.violations([45, 45, 90, 45, 0]) == 3
    day = Feasibility(Constraints(rules), rows, [[0, 1], [2, 3, 4]])  # units of CESs
    assert day.allowed == [{0.0}, {0.0}]
    with pytest.raises(ValueError, match="no common angle"):
        Feasibility(Constraints((AngleRule((0, 90), (0.0,)), AngleRule((0, 90), (90.0,)))),
                    rows, [[0]])  # fmt: skip


def test_changes_per_day_by_hand():
    """Eight CESs four hours apart from midnight: the first six on day one, the rest on day
    two; changes over the 1-degree tolerance count on the later CES's day; a repeat is a session
    of its own."""
    midnight = 1.8e9 - 1.8e9 % 86400
    rows = tuple(
        replace(c, start_unix=midnight + 4 * 3600.0 * i) for i, c in enumerate(rows_at([50] * 8))
    )
    feas = Feasibility(Constraints(max_changes_per_day=2), rows, [[i] for i in range(8)])
    angles = np.array([0, 45, 45, 0, 0.5, 90, 0, 0])
    np.testing.assert_array_equal(feas.changes_per_day(angles), [3, 1])
    assert feas.violations(angles) == 1 and not feas.days_ok(angles)
    assert feas.days_ok(np.where(angles == 90, 0.5, angles))
    assert feas.ok(np.where(angles == 90, 0.5, angles))  # 0.5 -> 0 is within the tolerance
    assert feas.ok([0, 45, 45, 45, 45, 90, 90, 90])
    repeated = Schedule(rows[:2], repeat_boresight_deg=(0.0, 90.0)).expanded()
    feas = Feasibility(Constraints(max_changes_per_day=0), repeated, [[i] for i in range(4)])
    assert feas.ok([0, 0, 90, 90]) and not feas.ok([0, 90, 90, 90])


@pytest.fixture(scope="module")
def mixed(schedule):
    """The design tests' schedule with every other CES at 40 deg elevation."""
    ces = tuple(
        replace(c, elevation_deg=40.0 if i % 2 else 50.0) for i, c in enumerate(schedule.ces)
    )
    return replace(schedule, ces=ces)


def test_design_keeps_the_constraints_and_prices_them(tmp_path, mixed):
    """ "Boresight 0 only below 45 deg" and at most 3 changes a day: the designed schedule breaks
    neither, each baseline's violations are counted, and constraints.csv says what each costs
    (the objective without it is no higher)."""
    budget = budget_file(
        tmp_path, constraints=f"max_changes_per_day = 3\n{LOW_ZERO}", operations='preset = "so-sat"'
    )
    out = run_design(tmp_path, mixed, budget, "--no-validate")
    designed = load_schedule(out / "schedule_designed.toml")
    assert all(c.boresight_deg == 0 for c in designed.ces if c.elevation_deg < 45)
    rows = mixed.expanded()
    units = units_of(rows, "ces")
    loaded = budget_module.load_budget(budget)
    feas = Feasibility(loaded.constraints, rows, units)
    angles = [float(u["angle_deg"]) for u in csv.DictReader(open(out / "units.csv"))]
    assert feas.ok(angles)
    strategies = {r["strategy"]: r for r in csv.DictReader(open(out / "strategies.csv"))}
    assert strategies["optimised"]["violations"] == "0"
    assert int(strategies["paper 0/90"]["violations"]) > 0  # 90 deg at 40 deg elevation
    costs = list(csv.DictReader(open(out / "constraints.csv")))
    assert [c["constraint"] for c in costs] == [
        "angles {0} deg at elevation [0, 45) deg",
        "at most 3 changes per day",
    ]
    for c in costs:
        assert float(c["objective_without"]) <= float(c["objective"])
        assert float(c["cost"]) == pytest.approx(
            float(c["objective"]) - float(c["objective_without"]), abs=1e-15
        )


@pytest.mark.parametrize("seed", range(3))
def test_the_search_never_leaves_the_constraints(tmp_path, mixed, seed):
    """From random starts, with and without a price on time: every sweep's end point keeps the
    rules (its objective is finite: a broken rule costs infinity)."""
    budget = budget_file(
        tmp_path,
        constraints=f"max_changes_per_day = 2\n{LOW_ZERO}",
        design=f"nside = 32\nsweeps = 3\nrestarts = 3\nseed = {seed}",
    )
    out = run_design(tmp_path, mixed, budget, "--no-validate")
    history = list(csv.DictReader(open(out / "history.csv")))
    assert all(np.isfinite(float(h["objective"])) for h in history)
    angles = [float(u["angle_deg"]) for u in csv.DictReader(open(out / "units.csv"))]
    rows = mixed.expanded()
    feas = Feasibility(budget_module.load_budget(budget).constraints, rows, units_of(rows, "ces"))
    assert feas.ok(angles)


def test_budget_constraints_table(tmp_path):
    loaded = budget_module.load_budget(budget_file(tmp_path, constraints=LOW_ZERO))
    assert loaded.constraints.angles == (AngleRule((0.0, 45.0), (0.0,)),)
    bad = {
        "max_changes_per_day = -1": "max_changes_per_day",
        "[[constraints.angles]]\nelevation_deg = [50, 40]\nangles_deg = [0.0]": "lo < hi",
        "[[constraints.angles]]\nangles_deg = [0.0]": "missing keys .'elevation_deg'.",
        "[[constraints.angles]]\nelevation_deg = [0, 45]\nangles_deg = [0.0]\nel = 1": "unknown",
        "most = 3": "unknown key constraints.most",
    }
    for text, message in bad.items():
        with pytest.raises(ConfigError, match=message):
            budget_module.load_budget(budget_file(tmp_path, constraints=text))
    path = budget_file(tmp_path, constraints=LOW_ZERO.replace("[0.0]", "[30.0]"))
    schedule = Schedule(rows_at([40, 50]), sample_rate_hz=1.0)
    with pytest.raises(ConfigError, match="none of the design's angles_deg"):
        design_job(budget_module.load_budget(path), schedule, timer=Timer(logging.getLogger("t")))


def test_a_plan_that_breaks_a_rule_is_named(tmp_path, mixed, caplog, capsys):
    """Scored as given (--no-search), a CES whose own angle breaks a rule is one error naming
    the file, the CES, its elevation and its angle; a search warns and gives it an allowed one."""
    from boresight import cli
    from boresight.schedule import write_schedule

    ces = tuple(replace(c, boresight_deg=45.0) for c in mixed.ces)
    src = tmp_path / "plan.toml"
    write_schedule(replace(mixed, ces=ces, repeat_boresight_deg=(0.0,)), str(src), "toml")
    budget = budget_file(tmp_path, constraints=LOW_ZERO, design="nside = 32\nsweeps = 2")
    args = ["-q", "design", budget, str(src), "--no-validate"]
    assert cli.main([*args, "--out", str(tmp_path / "a"), "--no-search"]) == 2
    error = capsys.readouterr().err
    assert (
        f"schedule {src}, CES 2 (start" in error and "elevation 40 deg), rotation 45 deg" in error
    )
    assert not (tmp_path / "a").exists()
    assert cli.main([*args, "--out", str(tmp_path / "b")]) == 0
    assert (
        "CES 2 (start" in caplog.text
        and "rotation 45 deg: outside the budget's angles {0}" in caplog.text
    )
