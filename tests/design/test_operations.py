"""Observing time as the price of a rotation: the operations before each CES are schedlib's own
(its SAT operations reproduced here from ``schedlib.policies.sat`` and ``policies.tel``), the
time they eat follows the gaps by hand, sigma(r) with lost time is the Fisher sum of a shallower
survey, and the search's incremental price equals the whole objective's change."""

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from helpers import EXAMPLES, budget_file, run_design

from boresight import cosmology, noise
from boresight.config import ConfigError
from boresight.design import budget as budget_module
from boresight.design.exact import change_cost_delta, exact_objective, pair_change_cost_delta
from boresight.design.operations import NAMES, Operations, TimePrice, shortened
from boresight.design.white import baselines
from boresight.moments.units import units_of
from boresight.predict import R_RANGE
from boresight.schedule import CES, Schedule, load_schedule

MASTER = Path(__file__).parents[1] / "schedule" / "data" / "so_master_sat.txt"
EDGES = np.array([R_RANGE[0], R_RANGE[1] + 1])
NOISE = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=3.0)

# schedlib.policies.sat's durations [s]
HWP_SPIN_UP, HWP_SPIN_DOWN, BORESIGHT_DURATION, DET_SETUP = 7 * 60, 15 * 60, 60, 20 * 60


@dataclass
class State:
    """The parts of schedlib's SAT state its three operations read and write."""

    boresight_rot_now: float = 0.0  # SATPolicy.init_state
    hwp_spinning: bool = False
    hwp_dir: bool | None = None
    is_det_setup: bool = False
    last_iv: float | None = None
    last_iv_elevation: float | None = None
    last_iv_boresight: float | None = None


def setup_boresight(state, block):
    """schedlib.policies.sat.setup_boresight (apply_boresight_rot, no cryo wait)."""
    duration = 0
    if state.boresight_rot_now is None or not np.isclose(
        state.boresight_rot_now, block["boresight_angle"], atol=1
    ):
        if state.hwp_spinning:
            state.hwp_spinning = False
            duration += HWP_SPIN_DOWN
        state.boresight_rot_now = block["boresight_angle"]
        duration += BORESIGHT_DURATION
    return duration


def det_setup(state, block):
    """schedlib.policies.tel.det_setup (apply_rot, no IV cadence, not a calibration)."""
    doit = (not state.is_det_setup) or (state.last_iv is None)
    if not doit:
        if state.last_iv_elevation is not None:
            doit = doit or not np.isclose(state.last_iv_elevation, block["alt"], atol=1)
        if state.last_iv_boresight is not None:
            doit = doit or not np.isclose(state.last_iv_boresight, block["boresight_angle"], atol=1)
    if doit:
        state.is_det_setup, state.last_iv = True, 0.0
        state.last_iv_elevation = block["alt"]
        state.last_iv_boresight = block["boresight_angle"]
        return DET_SETUP
    return 0


def hwp_spin_up(state, block):
    """schedlib.policies.sat.hwp_spin_up (the plate enabled)."""
    duration = 0
    if state.hwp_spinning:
        if block["hwp_dir"] is not None and state.hwp_dir != block["hwp_dir"]:
            duration += HWP_SPIN_DOWN
        else:
            return 0
    state.hwp_dir = block["hwp_dir"] if block["hwp_dir"] is not None else state.hwp_dir
    state.hwp_spinning = True
    return duration + HWP_SPIN_UP


def schedlib_durations(blocks):
    """Each CMB block's pre-observation operations [s], in SATPolicy.make_operations' order."""
    state = State()
    return [setup_boresight(state, b) + det_setup(state, b) + hwp_spin_up(state, b) for b in blocks]


def blocks_of(rows, angles):
    return [
        dict(boresight_angle=a, alt=c.elevation_deg, hwp_dir=c.hwp_dir == 1)
        for c, a in zip(rows, angles)
    ]


def price_of(rows, units=None, operations=Operations()):
    units = units or [[i] for i in range(len(rows))]
    return TimePrice(rows, units, operations, NOISE, cosmology.load_spectra(), EDGES)


def test_fixture_operations_are_schedlibs():
    """The master fixture at its own angles: a rotation with the plate spinning (15 + 1 + 20 +
    7), a change of the plate's direction (15 + 7), a change of elevation with a rotation (the
    set-up once), each CES's minutes equal to schedlib's."""
    rows = load_schedule(MASTER).ces
    angles = [c.boresight_deg for c in rows]
    line = price_of(rows).timeline(angles)
    theirs = schedlib_durations(blocks_of(rows, angles))
    np.testing.assert_array_equal(line.overhead_s, theirs)
    assert list(line.overhead_s / 60) == [27, 0, 43, 22, 43, 22]
    assert [NAMES[k] for k in np.flatnonzero(line.counts[4])] == list(NAMES)


@pytest.mark.parametrize("seed", range(4))
def test_random_sequences_are_schedlibs(seed):
    """Angles within and beyond the 1-degree tolerance, the plate's direction and the
    elevation changing at random: every CES's operations equal schedlib's."""
    rng = np.random.default_rng(seed)
    n = 60
    rows = tuple(
        CES(1.8e9 + 3600.0 * i, 3000.0, float(rng.choice([45.0, 45.6, 50.0, 60.0])), 180.0, 30.0,
            turnaround_s=2.0, hwp_dir=int(rng.integers(2)))
        for i in range(n)
    )  # fmt: skip
    angles = rng.choice([-45.0, 0.0, 0.4, 0.9, 1.5, 45.0, 90.0], n)
    line = price_of(rows).timeline(angles)
    np.testing.assert_array_equal(line.overhead_s, schedlib_durations(blocks_of(rows, angles)))


def test_deep_example_strategies_are_schedlibs():
    """Every baseline of the deep example (48 CESs, the repeat a session of its own): the
    operations design counts equal schedlib's sum, far within a minute per day."""
    schedule = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    rows = schedule.expanded()
    units = units_of(rows, "ces")
    price = price_of(rows, units)
    for name, angles in baselines(len(units), (-90.0, -45.0, 0.0, 45.0, 90.0)).items():
        ours = price.timeline(angles).overhead_s.sum()
        per_row = np.empty(len(rows))
        for u, idx in enumerate(units):  # units in time order; rows in observing order
            per_row[idx] = angles[u]
        theirs = sum(schedlib_durations(blocks_of(rows, per_row)))
        assert abs(ours - theirs) < 60.0, name
        assert ours == theirs, name


def test_lost_time_by_hand():
    """25-minute CESs 5 minutes apart: a rotation (43 min) eats the next CES whole and 13 of the
    following minutes: 8 minutes of the CES after; an hour's gap holds it; a repeat observed on
    another day loses nothing."""
    minute = 60.0
    rows = tuple(
        CES(1.8e9 + 30 * minute * i, 25 * minute, 50.0, 180.0, 30.0, turnaround_s=2.0)
        for i in range(4)
    )
    line = price_of(rows).timeline([0.0, 45.0, 45.0, 45.0])
    assert list(line.overhead_s / minute) == [27, 43, 0, 0]
    assert list(line.lost_s / minute) == [0, 25, 8, 0]
    assert line.lost_fraction == pytest.approx(33 / 100)
    kept = shortened(rows, line.lost_s)
    assert len(kept) == 3 and kept[1].start_unix == rows[2].start_unix + 8 * minute
    assert kept[1].duration_s == 17 * minute
    spaced = tuple(replace(c, start_unix=1.8e9 + 90 * minute * i) for i, c in enumerate(rows))
    assert price_of(spaced).timeline([0.0, 45.0, 0.0, 45.0]).lost_s.sum() == 0
    repeated = Schedule(rows[:2], repeat_boresight_deg=(0.0, 90.0)).expanded()
    line = price_of(repeated).timeline([0.0, 0.0, 90.0, 90.0])
    assert list(line.overhead_s / minute) == [27, 0, 43, 0]
    assert line.lost_s.sum() == 0


def test_sigma_with_lost_time_is_a_shallower_survey():
    """Losing a fraction f of the time is the survey at depth / sqrt(1 - f) (its Fisher sum,
    an independent route through the map depth); sigma(r) given as a number scales as
    (1 - f)^(-1/2)."""
    theory = cosmology.load_spectra()
    for f in (0.05, 0.3):
        shallower = replace(NOISE, depth_uk_arcmin=3.0 / np.sqrt(1 - f))
        assert noise.sigma_r(NOISE, theory, EDGES, time_fraction=1 - f) == pytest.approx(
            noise.sigma_r(shallower, theory, EDGES), rel=1e-12
        )
    given = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, sigma_r=0.002)
    assert noise.sigma_r(given, theory, EDGES, time_fraction=0.64) == pytest.approx(0.0025)
    rows = load_schedule(MASTER).ces
    price = price_of(rows)
    line = price.timeline([c.boresight_deg for c in rows])
    assert price.value([c.boresight_deg for c in rows]) == pytest.approx(
        noise.sigma_r(NOISE, theory, EDGES, time_fraction=1 - line.lost_fraction)
        - noise.sigma_r(NOISE, theory, EDGES),
        rel=1e-12,
    )


def test_search_price_steps_equal_the_objective(schedule, moments, theory):
    """change_cost_delta and pair_change_cost_delta, with the lost time's price and a change
    cost, equal the whole objective's change for every option of every unit."""
    from boresight.instrument.pairs import Systematics

    rows = moments.rows
    price = TimePrice(rows, moments.units, Operations(), NOISE, theory, EDGES)
    obj = exact_objective(
        moments, Systematics(dg=(0.01, -0.01)), theory, 30.0, change_cost=1e-4, time_price=price
    )
    opts = np.array([-45.0, 0.0, 45.0, 90.0])
    rng = np.random.default_rng(1)
    choice = rng.choice(opts, moments.n_units)
    base = obj(choice)
    for u in (0, 3, moments.n_units - 2):
        single = change_cost_delta(obj, choice, u, opts)
        pair = pair_change_cost_delta(obj, choice, u, opts)
        for i, a in enumerate(opts):
            trial = choice.copy()
            trial[u] = a
            assert single[i] == pytest.approx(
                obj(trial) - base - (obj.delta_r(trial) - obj.delta_r(choice)), abs=1e-15
            )
            for j, b in enumerate(opts):
                trial[u + 1] = b
                assert pair[i, j] == pytest.approx(
                    obj(trial) - base - (obj.delta_r(trial) - obj.delta_r(choice)), abs=1e-15
                )
            trial[u + 1] = choice[u + 1]


def test_budget_operations_table(tmp_path):
    path = budget_file(tmp_path, operations='preset = "so-sat"\ndet_setup_min = 10')
    ops = budget_module.load_budget(path).operations
    assert (ops.hwp_spin_down_min, ops.rotation_min, ops.det_setup_min) == (15.0, 1.0, 10.0)
    assert budget_module.load_budget(budget_file(tmp_path)).operations is None
    with pytest.raises(ConfigError, match="unknown key operations.spin_min"):
        budget_module.load_budget(budget_file(tmp_path, operations="spin_min = 3"))
    with pytest.raises(ConfigError, match=r"\[operations\] operations preset 'act'"):
        budget_module.load_budget(budget_file(tmp_path, operations='preset = "act"'))
    with pytest.raises(ConfigError, match="rotation_min"):
        budget_module.load_budget(budget_file(tmp_path, operations="rotation_min = -1"))


def test_design_prices_time_and_writes_what_it_costs(tmp_path, schedule):
    """With [operations]: every strategy's row carries its lost minutes, sigma(r) with them and
    the total; operations.csv lists each CES's operations; the designed schedule's CESs lose
    what the operations eat; the schedule as given is a strategy of its own."""
    import csv

    budget = budget_file(tmp_path, operations='preset = "so-sat"')
    out = run_design(tmp_path, schedule, budget, "--no-validate")
    rows = {r["strategy"]: r for r in csv.DictReader(open(out / "strategies.csv"))}
    assert set(rows) >= {"none", "as given", "optimised"}
    for r in rows.values():
        total = float(r["delta_r"]) + float(r["delta_r_lost_time"])
        assert float(r["delta_r_total"]) == pytest.approx(total, rel=1e-12)
    assert float(rows["none"]["lost_min"]) == 0  # one set-up before each session
    ops = list(csv.DictReader(open(out / "operations.csv")))
    assert len(ops) == len(schedule.expanded())
    lost = sum(float(r["lost_min"]) for r in ops)
    assert lost == pytest.approx(float(rows["optimised"]["lost_min"]))
    designed = load_schedule(out / "schedule_designed.toml")
    before = sum(c.duration_s for c in schedule.expanded())
    assert sum(c.duration_s for c in designed.ces) == pytest.approx(before - 60 * lost)
    best = min(rows.values(), key=lambda r: float(r["delta_r_total"]))
    assert float(best["delta_r_total"]) == pytest.approx(
        float(rows["optimised"]["delta_r_total"]), rel=1e-9
    )
    # scoring without a search: the schedule as given, the same row, and no schedule written
    (tmp_path / "scored").mkdir()
    scored = run_design(tmp_path / "scored", schedule, budget, "--no-validate", "--no-search")
    again = {r["strategy"]: r for r in csv.DictReader(open(scored / "strategies.csv"))}
    assert "optimised" not in again and not list(scored.glob("schedule_designed*"))
    assert again["as given"] == rows["as given"]


def test_design_of_a_master_schedule_writes_one(tmp_path):
    """A master schedule in, a master schedule out: every CES's labels and the idle block kept,
    the designed angles and the shortened CESs in it."""
    import csv

    from boresight import cli

    budget = budget_file(tmp_path, operations='preset = "so-sat"')
    text = Path(budget).read_text().replace("sweeps = 4", "sweeps = 2\nrestarts = 1")
    Path(budget).write_text(text)
    out = tmp_path / "d"
    args = ["-q", "design", budget, str(MASTER), "--out", str(out), "--no-validate"]
    assert cli.main([*args, "--sample-rate", "2"]) == 0
    designed = load_schedule(out / "schedule_designed.txt")
    given = load_schedule(MASTER)
    assert designed.idle == given.idle
    units = list(csv.DictReader(open(out / "units.csv")))
    kept = {dict(c.labels)["uid"]: c for c in designed.ces}
    for c, unit in zip(given.ces, units):
        uid = dict(c.labels)["uid"]
        if uid in kept:  # a CES the operations eat whole is left out
            assert kept[uid].boresight_deg == float(unit["angle_deg"])
            assert kept[uid].labels == c.labels and kept[uid].hwp_dir == c.hwp_dir


def test_observed_delta_r_is_the_design_of_the_observed_schedule(tmp_path, schedule):
    """A strategy that loses time (Keck's four decks on 5-minute CESs 5 minutes apart): its
    delta_r with [operations] equals that of its CESs as observed, written as a schedule of
    their own and scored as given without [operations]."""
    import logging

    from boresight._util.provenance import Timer
    from boresight.design.job import design as design_job
    from boresight.design.operations import observed

    timer = Timer(logging.getLogger("test"))
    priced = budget_module.load_budget(budget_file(tmp_path, operations='preset = "so-sat"'))
    tight = tuple(replace(c, start_unix=schedule.ces[0].start_unix + 600.0 * i)
                  for i, c in enumerate(schedule.ces))  # fmt: skip
    schedule = replace(schedule, ces=tight)
    result = design_job(priced, schedule, timer=timer, validate=False, search_angles=False)
    rows = {r["strategy"]: r for r in result.rows}
    angles = result.strategies["keck 4 decks"]
    line = result.time_price.timeline(angles)
    assert line.lost_s.sum() > 0 and rows["keck 4 decks"]["lost_min"] > 0
    moments = result.moments
    per_row = np.empty(len(moments.rows))
    for u, idx in enumerate(moments.units):
        per_row[idx] = angles[u]
    seen = observed(moments.rows, line.lost_s, schedule.sample_rate_hz)
    seen = tuple(replace(c, boresight_deg=float(a)) for c, a in zip(seen, per_row))
    alone = Schedule(seen, schedule.site, schedule.sample_rate_hz)
    free = budget_module.load_budget(budget_file(tmp_path))
    scored = design_job(free, alone, timer=timer, validate=False, search_angles=False)
    given = next(r for r in scored.rows if r["strategy"] == "as given")
    assert rows["keck 4 decks"]["delta_r"] == pytest.approx(given["delta_r"], rel=1e-9)
    assert rows["keck 4 decks"]["delta_r"] != pytest.approx(
        rows["keck 4 decks"]["delta_r_ces_whole"]
    )


def test_as_given_needs_one_angle_per_unit(tmp_path, schedule):
    """One unit per UTC day holds both repeats (0 and 90 deg): the design leaves out the row
    "as given", and scoring the schedule as given is refused with what to do."""
    import csv

    from boresight import cli

    budget = budget_file(tmp_path, design='nside = 32\nsweeps = 2\ngroup = "day"')
    out = run_design(tmp_path, schedule, budget, "--no-validate")
    names = [r["strategy"] for r in csv.DictReader(open(out / "strategies.csv"))]
    assert "as given" not in names and "optimised" in names
    args = ["-q", "design", budget, str(tmp_path / "s.toml"), "--out", str(tmp_path / "x")]
    assert cli.main([*args, "--no-validate", "--no-search"]) == 2
    assert not (tmp_path / "x").exists()
