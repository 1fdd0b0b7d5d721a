"""The design's TOD check: its report's verdicts on rows made to need them, the paired
difference from the optimised strategy measured sky by sky, and its parts made by the one
residual job."""

import dataclasses

import numpy as np
import pytest
from helpers import EXAMPLES

from boresight import design, engine, masks, spectra
from boresight.design.tod_check import tod_parts, validation_report
from boresight.instrument.focalplane import load_focalplane, on_axis
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Systematics
from boresight.predict.focalplane import RCOND_EXPECTATION
from boresight.schedule import CES, Schedule, load_schedule
from boresight.sky import SkyConfig, make_sky


def test_the_report_warns_of_what_is_off_and_of_what_is_not_resolved():
    """A simulation 3 standard errors from its prediction is a warning that says its 4 skies'
    error is itself uncertain (Student's t at 95 %: 3.2), and the unresolved difference from the
    optimised strategy is named."""
    row = dict(skies=4, predicted_delta_r=1.0, simulated_delta_r=1.3, simulated_delta_r_se=0.1)
    made = [
        {**row, "strategy": "none", "difference_resolved": False},
        {**row, "strategy": "optimised", "simulated_delta_r": 1.05, "difference_resolved": False},
    ]
    lines, warnings = validation_report(made)
    assert len(lines) == 4 and "3.0s" in lines[2] and "not resolved" in lines[2]
    assert "none's simulated delta_r 1.3 +- 0.1 is 3.0 standard errors" in warnings[0]
    assert "from 4 skies the error is itself uncertain: 95 % of draws lie within 3.2" in warnings[0]
    assert "do not resolve the optimised strategy's difference from none" in warnings[1]
    assert len(warnings) == 2


def test_a_check_within_its_errors_and_resolved_says_nothing():
    row = dict(skies=16, predicted_delta_r=1.0, simulated_delta_r=1.1, simulated_delta_r_se=0.1)
    made = [
        {**row, "strategy": "none", "difference_resolved": True},
        {**row, "strategy": "optimised", "simulated_delta_r": 0.95, "difference_resolved": False},
    ]
    lines, warnings = validation_report(made)
    assert warnings == [] and "resolved" in lines[2] and "not resolved" not in lines[2]
    assert "1.0s" in lines[2] and "-0.5s" in lines[3]


@pytest.mark.parametrize(
    "case", ["focal plane", "continuous plate", "stepped plate"], ids=lambda c: c.replace(" ", "-")
)
def test_the_checks_parts_of_a_focal_plane_or_a_plate_are_those_of_its_maps(case):
    """Through the residual job, a focal plane's (or the pairs' behind a plate) TOD parts are,
    bit for bit, those of its maps made by the engine directly with the focal-plane prediction's
    rcond cut, the invalid pixels at 0, and the reference behind the plate without its IP."""
    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    ces = tuple(CES(**{**c.__dict__, "duration_s": 120.0}) for c in base.ces[::6])
    schedule = Schedule(ces, base.site, 2.0, repeat_boresight_deg=(0.0, 90.0))
    budget = design.load_budget(EXAMPLES / "budget_deep_sat.toml")
    nside, lmax = 16, 32
    mask = masks.survey_mask("deep", nside)
    sky = make_sky(SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=240.0, seed=3))
    systematics = Systematics(dg=0.01, rho_arcmin=0.5, chi_deg=30.0, seed=3)
    plate = None
    if case == "focal plane":
        budget = dataclasses.replace(budget, focalplane=load_focalplane("hexagon:7:20"))
        focal = budget.focalplane
    else:
        plate = HWP(case.split()[0], frequency_hz=0.3, step="ces", ip=5e-3)
        focal = on_axis(budget.instrument.pair_angles_deg)
    got = tod_parts(sky, schedule, systematics, budget, mask, lmax=lmax, hwp=plate)
    plates = (None, None) if plate is None else (dataclasses.replace(plate, ip=0.0), plate)
    maps = [
        engine.simulate_focalplane(
            sky,
            schedule,
            focal,
            s,
            rcond_min=RCOND_EXPECTATION,
            hwp=p,
            evaluation=budget.design.evaluation,
        )  # fmt: skip
        for s, p in zip((Systematics(), systematics), plates)
    ]
    assert any((~m.valid[m.hits > 0]).any() for m in maps) or case != "focal plane"
    ref, sys = (np.array([np.where(m.valid, m.q, 0.0), np.where(m.valid, m.u, 0.0)]) for m in maps)
    want = spectra.residual_bb_parts(sys, ref, mask, lmax)
    assert np.abs(want[1]).max() > 0
    for x, y in zip(got, want):
        np.testing.assert_array_equal(x, y)
