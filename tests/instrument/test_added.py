"""A systematic added from one file (boresight.instrument.added): a toy constant offset per pair,
declared in a fixture and registered, and nothing else. Its TOD, its prediction, its table row and
its study key work from that declaration alone; what does not carry it yet refuses it."""

import numpy as np
import pytest
from helpers import CENTRED, rel_max

from boresight import config, engine, predict
from boresight.instrument import added
from boresight.instrument.hwp import check_systematics
from boresight.instrument.pairs import Spread, Systematics
from boresight.jobs.suppression import axis
from boresight.scan import SyntheticScan
from boresight.validation import ConfigError


def _ones(sky):
    return np.ones(12 * sky.nside**2)


@pytest.fixture
def offset():
    """A constant offset c per pair: detector A sees +c/2 and B -c/2 [muK]."""
    one = added.register(
        added.PairSystematic(
            key="offset",
            limits=(-1e3, 1e3),
            field=_ones,
            symbol="1",
            amplitude=10.0,
            words="c = 10 muK",
            help="a constant offset of the pair difference [muK]",
        )
    )
    yield one
    added.unregister("offset")


def test_the_offsets_tod_is_the_built_in_leak_with_a_constant_template(offset, small_sky):
    """An independent route: the compiled kernels' additive leak with a template of ones is the
    same signal (A +l/2, B -l/2), so both runs give the same maps to rounding, per pair."""
    scan = SyntheticScan(**CENTRED, rotations_deg=(0.0, 30.0))
    amplitudes = (7.0, -3.0)
    got = engine.simulate(small_sky, scan, systematics=Systematics(added={"offset": amplitudes}))
    want = engine.simulate(  # the leak's amplitudes are at most 1: a template of 10s
        small_sky,
        scan,
        systematics=Systematics(leak=(0.7, -0.3)),
        leak_template=10.0 * _ones(small_sky),
    )
    assert rel_max(got.q + 1j * got.u, want.q + 1j * want.u) < 1e-12
    assert np.array_equal(got.hits, want.hits)


def test_the_offsets_leak_is_its_term_c_h2_times_one(offset, small_sky):
    """The map-level prediction from the declaration's term equals the TOD's leak to rounding
    (exact for pixel-centre hits), on the sky's own polarisation plus the offset's h_2."""
    scan = SyntheticScan(**CENTRED, rotations_deg=(0.0, 30.0))
    sysm = Systematics(added={"offset": (7.0, -3.0)})
    m = engine.simulate(small_sky, scan, systematics=sysm)
    ideal = engine.simulate(small_sky, scan)
    h, _ = engine.scan_moments(scan.one_repeat(), small_sky.nside)
    pred = predict.delta_p(small_sky, h, sysm, rotations_deg=scan.rotations_deg)
    leak = (m.q - ideal.q) + 1j * (m.u - ideal.u)
    assert np.max(np.abs(leak)) > 1.0  # a leak of muK, not rounding
    assert rel_max(leak, pred) < 1e-10
    c = np.mean(np.array([7.0, -3.0]) * np.exp(2j * np.radians([[0.0, 45.0], [30.0, 75.0]])))
    assert rel_max(pred, c * h[2]) < 1e-12  # the declaration's term, by hand


def test_a_90_degree_rotation_cancels_the_offset_and_a_drawn_one_is_keyed(offset, small_sky):
    """h_2 terms cancel under 0/90 (paper eq. 6), and {mean, rms} draws per pair depend on the
    seed and the key alone, not on what else is registered."""
    scan = SyntheticScan(**CENTRED, rotations_deg=(0.0, 90.0))
    m = engine.simulate(small_sky, scan, systematics=Systematics(added={"offset": 10.0}))
    assert rel_max(m.q + 1j * m.u, small_sky.maps[1] + 1j * small_sky.maps[2]) < 1e-12
    sysm = Systematics(added={"offset": {"mean": 1.0, "rms": 2.0}}, seed=3)
    ((_, first),) = sysm.added_per_pair(4)
    added.register(added.PairSystematic("other", (0.0, 1.0), _ones, "1", 0.1, "x = 0.1"))
    try:
        ((_, again),) = sysm.added_per_pair(4)
    finally:
        added.unregister("other")
    assert np.array_equal(first, again) and np.unique(first).size == 4
    assert isinstance(sysm.added[0][1], Spread)


def test_the_offsets_table_row_comes_from_its_declaration(offset, plain_sky, monkeypatch):
    """Its suppression row (the built-in rows left out): its coupling from the term, its
    amplitude in words, 0/90 cancels, and 0/45 agrees with the map-level prediction."""
    monkeypatch.setattr(axis, "CATALOGUE", ())
    entries = axis.catalogue()
    assert [e.name for e in entries] == ["offset"]
    assert entries[0].coupling == "h_2 1" and entries[0].amplitude == "c = 10 muK"
    result = axis.run(plain_sky)
    rows = {r["rotations_deg"]: r for r in axis.table(result, plain_sky.nside)}
    band = "ell_30_32"
    assert rows["0/90"][f"suppression_sim_{band}"] > axis.CANCELS
    sim, pred = (rows["0/45"][f"suppression_{k}_{band}"] for k in ("sim", "pred"))
    assert sim == pytest.approx(pred, rel=1e-6)  # both exact: one is the other's formula
    assert rows["0"]["delta_r_sim"] == pytest.approx(rows["0"]["delta_r_pred"], rel=1e-6)


def test_a_study_takes_the_key_beside_the_built_in_ones(offset, tmp_path):
    study = tmp_path / "study.toml"
    study.write_text(
        "[sky]\nnside = 16\nlmax = 32\n[systematics]\ndg = 0.01\noffset = [1.0, 2.0]\n"
    )
    got = config.load_study(str(study))
    assert got.systematics.added == (("offset", (1.0, 2.0)),)
    assert config.as_dict(got)["systematics"]["offset"] == (1.0, 2.0)
    study.write_text("[sky]\nnside = 16\nlmax = 32\n[systematics]\noffset = 2e3\n")
    with pytest.raises(ConfigError, match="offset"):
        config.load_study(str(study))


def test_an_unregistered_key_and_what_does_not_carry_it_refuse(offset):
    with pytest.raises(ValueError, match="not registered"):
        Systematics(added={"drift": 1.0})
    sysm = Systematics(added={"offset": 1.0})
    with pytest.raises(ValueError, match="a HWP does not carry it yet"):
        check_systematics(sysm)
    with pytest.raises(ValueError, match="the C_ell level"):
        predict.leak_terms(predict.coefficients(sysm), sysm, np.ones(8), np.ones(8))
    with pytest.raises(ValueError, match="built-in"):
        added.register(added.PairSystematic("dg", (0.0, 1.0), _ones, "1", 0.1, "x"))


def test_the_offset_runs_on_a_focal_planes_sample_streams(offset, small_sky):
    """Each pair of a 7-pixel hexagon off the axis, on its own samples: the offset per pair is
    the kernels' leak with a template of ones there too, and the chunks do not matter."""
    from helpers import toast_schedule

    from boresight.instrument.focalplane import hexagon

    schedule, fp = toast_schedule(), hexagon(7, 10.0)
    amplitudes = tuple(np.linspace(-5.0, 5.0, fp.n_pairs))
    got = engine.simulate_focalplane(
        small_sky, schedule, fp, Systematics(added={"offset": amplitudes})
    )
    again = engine.simulate_focalplane(
        small_sky, schedule, fp, Systematics(added={"offset": amplitudes}), chunk_samples=777
    )
    want = engine.simulate_focalplane(
        small_sky,
        schedule,
        fp,
        Systematics(leak=tuple(a / 10.0 for a in amplitudes)),
        leak_template=10.0 * _ones(small_sky),
    )
    assert np.array_equal(got.pixels, want.pixels)
    assert rel_max(got.q_obs + 1j * got.u_obs, want.q_obs + 1j * want.u_obs) < 1e-12
    assert rel_max(got.q_obs + 1j * got.u_obs, again.q_obs + 1j * again.u_obs) < 1e-12


def test_the_guides_worked_example_is_the_toy():
    """docs/guide/adding_a_systematic.md's code registers the systematic these tests declare."""
    import re

    from helpers import ROOT

    page = (ROOT / "docs" / "guide" / "adding_a_systematic.md").read_text()
    code = re.search(r"```python\n(.*?)```", page, re.S).group(1)
    try:
        exec(code, {})
        one = added.REGISTRY["offset"]
        assert (one.limits, one.symbol, one.amplitude, one.words, one.n) == (
            (-1e3, 1e3),
            "1",
            10.0,
            "c = 10 muK",
            2,
        )
    finally:
        added.unregister("offset")


def test_the_built_in_keys_no_added_one_may_take_are_the_systematics_fields():
    import dataclasses

    fields = {f.name for f in dataclasses.fields(Systematics)}
    assert added.BUILT_IN == fields | {"leak_template"}  # a study's file key beside them
