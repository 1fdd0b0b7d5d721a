"""The design objective of a pipeline that filters before binning: each unit's filtered leak,
solved for its moments from a few angles, turned by an assignment, equals the filtered TOD of
that assignment on the same skies; the command designs for it and checks it against fresh skies."""

import csv
import dataclasses
import json

import numpy as np
import pytest
from helpers import budget_file, run_design

from boresight import design, predict
from boresight.design.filtered import (
    FIRST_SEED,
    filtered_objective,
    moments_of,
    objective_alm,
    objective_runs,
    probe_angles,
)
from boresight.design.tod_check import tod_parts
from boresight.instrument.pairs import Systematics
from boresight.sky import SkyConfig, make_sky

NSIDE = 32
ANGLES = (-90.0, -45.0, 0.0, 45.0, 90.0)


def _budget(tmp_path, systematics, *, evaluation="interp", skies=2, deprojection=None):
    tmp_path.mkdir(parents=True, exist_ok=True)
    return design.load_budget(
        budget_file(
            tmp_path,
            systematics=systematics,
            design=f'nside = {NSIDE}\nsweeps = 4\nevaluation = "{evaluation}"',
            filter=f"poly_order = 1\nground_order = 3\nskies = {skies}",
            deprojection=deprojection,
        )
    )


def _tod_delta_r(obj, budget, moments, schedule, angles):
    """Each objective sky's filtered TOD delta_r of the total residual, corrected by F_BB."""
    scan = moments.schedule(schedule, angles)
    out = []
    for k in range(obj.sky_alm.shape[0]):
        seed = FIRST_SEED + k
        sky = make_sky(SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=30.0, seed=seed))
        systematics = dataclasses.replace(budget.systematics, seed=seed)
        cross, auto = tod_parts(sky, scan, systematics, budget, moments.mask, lmax=2 * NSIDE)
        out.append(predict.delta_r((cross + auto) / obj.kept_bb, obj.template))
    return np.array(out)


def test_the_moments_a_budget_reaches_and_the_angles_that_resolve_them():
    """A gain or an angle error reaches h_0, h_2, h_4; a pointing offset h_-1 .. h_5 (its leak of
    P through h_-1 and h_5); a beam h_-2 .. h_6; the probe angles resolve them."""
    assert moments_of(Systematics(dg=0.01, pol_angle_deg=1.0)) == (0, 1, 2, 3, 4)
    assert moments_of(Systematics(rho_arcmin=1.0)) == tuple(range(-1, 6))
    assert moments_of(Systematics(ellipticity_b=0.01)) == tuple(range(-2, 7))
    for ns in ((0, 1, 2, 3, 4), tuple(range(-2, 7))):
        a = probe_angles(ns)
        assert (
            len(a) == len(ns)
            and np.linalg.cond(np.exp(1j * np.outer(a, ns) * np.pi / 180)) < 1 + 1e-9
        )


def test_an_assignment_s_filtered_leak_is_its_units_turned(tmp_path, schedule, moments, theory):
    """On 16 units (8 CESs at two repeats) filtered by p1+ground3, the units' moments turned by a
    drawn assignment give each of the objective's skies its filtered TOD's total residual of that
    assignment: a gain and an angle error to rounding (1e-9; their leaks are exact in the
    moments), a pointing offset of 0.5 arcmin to 3e-4 (measured 1.1e-4: the offsets' higher orders
    that the moments h_-1 .. h_5 do not all carry), and a pipeline that filters and then
    deprojects the gain's template per CES (BICEP/Keck's) to rounding too. The sky's own filtered
    map does not turn, and a second assignment agrees alike. The objective (its skies' leaks and the cross term of the
    moment that does not turn) is the mean of its expected residual's."""
    rng = np.random.default_rng(1)
    cases = (
        ("dg = [0.01, -0.01]\npol_angle_deg = 1.0", "interp", 1e-9, None),
        ("rho_arcmin = 0.5\nchi_deg = 30.0", "exact", 3e-4, None),
        ("dg = [0.01, -0.01]\npol_angle_deg = 1.0", "interp", 1e-9, "templates = ['gain']"),
    )
    for k, (systematics, evaluation, tol, deprojection) in enumerate(cases):
        budget = _budget(
            tmp_path / str(k), systematics, evaluation=evaluation, deprojection=deprojection
        )
        obj = filtered_objective(moments, schedule, budget, theory)
        assert obj.unit_alm.shape[:2] == (
            moments.n_units,
            2 * (len(moments_of(budget.systematics)) + 1),
        )
        for _ in range(2):
            angles = rng.choice(ANGLES, moments.n_units)
            tod = _tod_delta_r(obj, budget, moments, schedule, angles)
            every = obj.per_sky(angles, chance=True)
            per_sky = [predict.delta_r(t, obj.template) for _, t in every]
            np.testing.assert_allclose(per_sky, tod, rtol=tol)
            expected = obj.expected(angles)
            assert predict.delta_r(expected.residual, obj.template) == pytest.approx(
                obj.delta_r(angles), rel=1e-12
            )
            assert obj.delta_r_se(angles) > 0


def test_the_design_of_a_filtering_pipeline(tmp_path, schedule):
    """`boresight design` with [filter] p1+ground3 (gain and pointing, 4 objective skies):
    the optimised assignment's objective is the least of every strategy's, the white
    approximation (which knows no filter) is left blank, the manifest names the pipeline, the
    estimate counts the objective's runs and the alm it holds, and the TOD check, on 4 fresh skies through the same
    filter, carries the objective's own error: every strategy within 3 of their errors added in
    quadrature."""
    systematics = "dg = [0.01, -0.01]\nrho_arcmin = 0.5\nchi_deg = 30.0"
    path = budget_file(
        tmp_path,
        systematics=systematics,
        design=f"nside = {NSIDE}\nsweeps = 4\nvalidation_skies = 4",
        filter="poly_order = 1\nground_order = 3\nskies = 4",
    )
    out = run_design(tmp_path, schedule, path)
    rows = {r["strategy"]: r for r in csv.DictReader(open(out / "strategies.csv"))}
    values = {name: float(r["delta_r"]) for name, r in rows.items()}
    assert values["optimised"] <= min(values.values())
    assert all(r["delta_r_white_approximation"] == "nan" for r in rows.values())
    assert (out / "design.png").exists() and (out / "validation.csv").exists()
    manifest = json.load(open(out / "manifest.json"))
    assert manifest["config"]["filter"] == {"pipeline": "p1+ground3", "skies": 4}
    budget = design.load_budget(path)
    assert objective_runs(budget) == 4 * 8 + 16  # each sky 7 moments and its map, the transfer
    assert objective_alm(budget) == dict(design_channels=4 * 8, design_band=2 * NSIDE)
    held = 16 * 16 * (4 * 8) * 2 * (2 * NSIDE + 1) * (2 * NSIDE + 2) // 2  # the units' alm
    assert manifest["estimate"]["parts_gib"]["unit alm"] == pytest.approx(held / 2**30, abs=1e-4)
    for row in csv.DictReader(open(out / "validation.csv")):
        se = np.hypot(float(row["simulated_delta_r_se"]), float(row["predicted_delta_r_se"]))
        assert float(row["predicted_delta_r_se"]) > 0
        off = abs(float(row["simulated_delta_r"]) - float(row["predicted_delta_r"]))
        assert off < 3 * se, row["strategy"]


def test_without_a_filter_it_is_the_exact_expectation(tmp_path, schedule, moments, theory):
    """The same route without a filter (F_BB = 1) against the raw pipeline's closed form
    (:func:`boresight.design.exact.exact_objective`), a gain and an angle error: the mean over 16
    skies of each assignment's leak and its sky's cross term is the exact expectation within 3 of
    its standard errors (one sky scatters by 30 % on this small footprint), and so is the
    difference between two assignments, sky by sky."""
    budget = _budget(tmp_path, "dg = [0.01, -0.01]\npol_angle_deg = 0.5")
    budget = dataclasses.replace(budget, filtering=None)
    obj = filtered_objective(moments, schedule, budget, theory, skies=16)
    np.testing.assert_allclose(obj.kept_bb, 1.0, atol=1e-12)
    exact = design.exact.exact_objective(
        moments, budget.systematics, theory, budget.noise.fwhm_arcmin, instrument=budget.instrument
    )
    rng = np.random.default_rng(2)
    first, second = np.zeros(moments.n_units), rng.choice(ANGLES, moments.n_units)
    for angles in (first, second):
        assert abs(obj.delta_r(angles) - exact.delta_r(angles)) < 3 * obj.delta_r_se(angles)
    totals = [
        [predict.delta_r(t, obj.template) for _, t in obj.per_sky(a)] for a in (first, second)
    ]
    change = np.subtract(*totals)
    se = np.std(change, ddof=1) / np.sqrt(change.size)
    assert abs(np.mean(change) - (exact.delta_r(first) - exact.delta_r(second))) < 3 * se
