"""The design job as a library function: what ``boresight design`` writes is what
:func:`boresight.design.job.design` returns, and the job itself writes nothing."""

import csv
import logging
import os

import numpy as np
import pytest
from helpers import budget_file, run_design

from boresight import design
from boresight._util.provenance import Timer
from boresight.design.job import DesignResult
from boresight.design.job import design as design_job


def test_the_job_returns_what_the_command_writes_and_writes_nothing(
    tmp_path, schedule, monkeypatch
):
    """Every strategy's row, the optimised angles and the units, to the bit; the job run in an
    empty folder leaves it empty; the optimised strategy is the lowest."""
    budget_path = budget_file(tmp_path)
    out = run_design(tmp_path, schedule, budget_path, "--no-validate")
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    result = design_job(
        design.load_budget(budget_path),
        schedule,
        timer=Timer(logging.getLogger("test")),
        validate=False,
    )
    assert isinstance(result, DesignResult) and os.listdir(empty) == []
    assert result.validation == [] and result.checked == "skipped" and result.stopped is None
    written = list(csv.DictReader(open(out / "strategies.csv")))
    assert [r["strategy"] for r in written] == [r["strategy"] for r in result.rows]
    for row, mine in zip(written, result.rows):
        for key, value in mine.items():
            if key != "strategy":
                assert float(row[key]) == pytest.approx(float(value), rel=1e-15, nan_ok=True), key
    units = list(csv.DictReader(open(out / "units.csv")))
    np.testing.assert_array_equal(
        [float(u["angle_deg"]) for u in units], result.strategies["optimised"]
    )
    best = min(result.rows, key=lambda r: r["delta_r"])
    assert best["delta_r"] == pytest.approx(
        next(r for r in result.rows if r["strategy"] == "optimised")["delta_r"], rel=1e-12
    )
