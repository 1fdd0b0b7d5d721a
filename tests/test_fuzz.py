"""Property-based fuzzing of every entry point (issue 17), with Hypothesis.

For any generated input the outcome is one of: success with finite results; a ConfigError (exit 2
with one line naming a key or file); or a ValueError / TypeError from the API. Never another
exception, a crash, NaN output with exit 0, or a write outside --out. Example counts are fixed and
derandomised, and the resolution is Nside <= 16, so the suite costs seconds in CI.
"""

import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from boresight import engine, scanstats, sweep
from boresight.cli import main
from boresight.config import ConfigError, parse_study, schema
from boresight.instrument import Instrument, Systematics
from boresight.scan import SyntheticScan
from boresight.schedule import CES_LIMITS, CES_REQUIRED, load_schedule
from boresight.schedule.files import SCHEDULE_KEYS

FUZZ = settings(
    max_examples=150,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
SLOW_FUZZ = settings(FUZZ, max_examples=20)


def _near(lo, hi):
    """Floats in [lo, hi] and the non-finite values that must never pass."""
    return st.one_of(st.floats(lo, hi), st.sampled_from([math.nan, math.inf, -math.inf]))


numbers = st.one_of(
    st.integers(-(2**65), 2**65),
    st.sampled_from([0, 1, 2, 3, 4, 8, 16, -1, 2**31]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 0.5, 1e-300, 1e300, -0.0]),
)
scalars = st.one_of(numbers, st.booleans(), st.text(max_size=8), st.just("junk.fits"))
values = st.one_of(
    scalars,
    st.lists(scalars, max_size=4),
    st.dictionaries(st.text(max_size=3), scalars, max_size=2),
)


@st.composite
def raw_configs(draw):
    """Dicts shaped like a study TOML: mostly known sections and keys, sometimes not."""
    raw = {}
    sections = draw(st.lists(st.sampled_from([*schema(), "telescope"]), max_size=6, unique=True))
    for section in sections:
        keys = [*schema().get(section, {}), "colour"]
        body = draw(st.dictionaries(st.sampled_from(keys), values, max_size=4))
        raw[section] = body if draw(st.integers(0, 9)) else draw(scalars)
    return raw


@FUZZ
@given(raw=raw_configs())
def test_any_config_parses_or_names_its_error(raw, tmp_path_factory):
    base = tmp_path_factory.mktemp("cfg")
    (base / "junk.fits").write_text("not a FITS file")
    try:
        parse_study(raw, str(base))
    except ConfigError as err:
        assert str(err) and "\n" not in str(err)


def _mostly(valid, invalid):
    """Nine draws in ten from ``valid``: a study with several fields then still runs often."""
    return st.integers(0, 9).flatmap(lambda k: invalid if k == 9 else valid)


@st.composite
def small_studies(draw):
    """Runnable studies at Nside <= 16 (lmax above the default lmin of 20), each field now and
    then out of range or non-finite."""
    nside = draw(_mostly(st.sampled_from([8, 16]), st.sampled_from([1, 2, 4, 12, 0, True])))
    top = 3 * max(int(nside), 1) - 1
    return {
        "sky": {
            "nside": nside,
            "lmax": draw(_mostly(st.integers(21, max(top, 21)), st.integers(-1, 60))),
            "fwhm_arcmin": draw(_mostly(st.floats(60, 600), _near(-1, 2e4))),
            "r": draw(_mostly(st.floats(0, 1), _near(-1, 1e3))),
            "seed": draw(_mostly(st.integers(0, 2**63 - 1), st.integers(-5, 2**65))),
        },
        "scan": {
            "n_phi": draw(_mostly(st.integers(1, 5), st.integers(-1, 0))),
            "range_rad": draw(_mostly(st.floats(0, 6.28), _near(-1, 7))),
            "rotations_deg": draw(
                _mostly(st.lists(st.floats(-400, 400), min_size=1, max_size=3), st.just([]))
            ),
        },
        "systematics": {
            "dg": draw(
                _mostly(
                    st.lists(st.floats(-0.5, 0.5), min_size=2, max_size=2),
                    st.lists(_near(-2, 2), min_size=1, max_size=3),
                )
            ),
            "rho_arcmin": draw(_mostly(st.floats(0, 30), _near(-1, 800))),
        },
        "mask": {"survey": draw(_mostly(st.sampled_from(["deep", "wide", "none"]), st.just("x")))},
        "output": {
            "lmax": draw(_mostly(st.integers(21, max(top, 21)), st.integers(0, 60))),
            "n_bands": draw(_mostly(st.integers(1, 5), st.integers(-1, 0))),
        },
    }


def _toml(raw):
    def value(v):
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    return "".join(
        f"[{s}]\n" + "".join(f"{k} = {value(v)}\n" for k, v in body.items())
        for s, body in raw.items()
    )


def _finite_csv(path):
    rows = path.read_text().splitlines()[1:]
    return all(math.isfinite(float(x)) for row in rows for x in row.split(",")[1:] if x)


@SLOW_FUZZ
@given(raw=small_studies(), command=st.sampled_from(["simulate", "predict", "scan-stats"]))
def test_cli_runs_or_exits_2_and_never_writes_nan(raw, command, tmp_path_factory, capsys):
    work = tmp_path_factory.mktemp("cli")
    config = work / "study.toml"
    config.write_text(_toml(raw))
    out = work / "out"
    rc = main(["-q", command, str(config), "--out", str(out)])
    err = capsys.readouterr().err
    event(f"{command} exit {rc}")
    assert rc in (0, 2), err
    assert sorted(os.listdir(work)) == (["out", "study.toml"] if rc == 0 else ["study.toml"])
    if rc == 2:
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        return
    csv = {"simulate": "spectra.csv", "predict": "prediction.csv", "scan-stats": "hn_summary.csv"}
    assert _finite_csv(out / csv[command])


# Schedules ---------------------------------------------------------------------------------------

cells = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10, 2 * 10**9).map(str),
    st.sampled_from(["", "2026-01-01", "x", "1e400", "50", "60", "1790028800"]),
)


VALID_CES = {
    "start_unix": st.floats(1.7e9, 1.8e9),
    "duration_s": st.floats(1, 60),
    "elevation_deg": st.floats(30, 70),
    "az_centre_deg": st.floats(-360, 360),
    "az_throw_deg": st.floats(0, 360),
    "speed_deg_s": st.floats(0.1, 3),
    "boresight_deg": st.floats(-180, 180),
    "turnaround_s": st.floats(0, 10),
}


@st.composite
def csv_schedules(draw):
    """CSV schedules: mostly well-formed rows, sometimes a junk cell, column or row length."""
    header = list(CES_REQUIRED) + draw(
        st.lists(st.sampled_from([*VALID_CES, "colour"]), max_size=3, unique=True)
    )
    header = list(dict.fromkeys(header))
    if draw(st.integers(0, 9)) == 0:
        header = header[1:]
    rows = []
    for _ in range(draw(st.integers(1, 3))):
        row = [
            (
                repr(draw(_mostly(VALID_CES.get(col, st.floats(0, 1)), st.nothing() | cells)))
                if draw(st.integers(0, 19))
                else draw(cells)
            )
            for col in header
        ]
        if draw(st.integers(0, 19)) == 0:
            row = row[:-1]
        rows.append(row)
    return ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows)


def _check_schedule(path):
    try:
        schedule = load_schedule(path)
    except ConfigError as err:
        assert "\n" not in str(err)
        event("schedule refused")
        return
    event("schedule loaded")
    if schedule.n_samples <= 20_000:  # characterise what is cheap: finite statistics
        stats = scanstats.characterise_schedule(schedule, 8)
        assert np.isfinite(stats.h).all() and stats.hits.sum() == schedule.n_samples


@FUZZ
@given(text=csv_schedules())
def test_any_csv_schedule_loads_or_names_its_error(text, tmp_path_factory):
    path = tmp_path_factory.mktemp("s") / "s.csv"
    path.write_text(text)
    _check_schedule(path)


ces_values = st.one_of(numbers, st.just("2026-01-01"), st.sampled_from([1, 50.0, 10.0, 1790028800]))


@FUZZ
@given(
    ces=st.lists(
        st.dictionaries(st.sampled_from([*CES_LIMITS, "colour"]), ces_values, max_size=9),
        max_size=2,
    ),
    top=st.dictionaries(st.sampled_from([*SCHEDULE_KEYS[2:], "repeat"]), numbers, max_size=2),
)
def test_any_toml_schedule_loads_or_names_its_error(ces, top, tmp_path_factory):
    def value(v):
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(v) if not isinstance(v, str) else f'"{v}"'

    text = "".join(f"{k} = {value(v)}\n" for k, v in top.items())
    for c in ces:
        c = {**dict.fromkeys(CES_REQUIRED, 10), **c}
        text += "[[ces]]\n" + "".join(f"{k} = {value(v)}\n" for k, v in c.items())
    path = tmp_path_factory.mktemp("s") / "s.toml"
    path.write_text(text)
    _check_schedule(path)


# Sweep files ------------------------------------------------------------------------------------

STUDY = '[sky]\nnside = 16\nlmax = 47\n[mask]\nsurvey = "wide"\n[output]\nlmax = 40\nn_bands = 3\n'


@FUZZ
@given(
    spec=st.dictionaries(
        st.sampled_from(["base", "mode", "parameters", "colour"]),
        st.one_of(
            values,
            st.just("study.toml"),
            st.sampled_from(["grid", "list"]),
            st.dictionaries(
                st.sampled_from(["pbr_angle_deg", "sky.seed", "scan.n_phi", "x", "a.b.c"]),
                st.one_of(st.lists(scalars, max_size=3), scalars),
                max_size=3,
            ),
        ),
        max_size=4,
    )
)
def test_any_sweep_file_loads_or_names_its_error(spec, tmp_path_factory):
    base = tmp_path_factory.mktemp("sw")
    (base / "study.toml").write_text(STUDY)
    path = base / "sweep.toml"
    path.write_text(
        "".join(
            f"{k} = {v!r}\n".replace("True", "true").replace("False", "false")
            for k, v in spec.items()
            if not isinstance(v, dict)
        )
        + "".join(
            f"[{k}]\n" + "".join(f'"{a}" = {b!r}\n' for a, b in v.items())
            for k, v in spec.items()
            if isinstance(v, dict)
        )
    )
    try:
        sweep.load_sweep(str(path))
    except ConfigError as err:
        assert "\n" not in str(err)


# The public API ---------------------------------------------------------------------------------

pixel_args = st.one_of(
    st.none(),
    st.lists(st.integers(-5, 4000), max_size=20).map(np.array),
    st.lists(_near(-5, 4000), max_size=20).map(np.array),
    st.lists(st.booleans(), min_size=0, max_size=30).map(np.array),
    st.just(np.ones((2, 3), dtype=np.int64)),
)


@SLOW_FUZZ
@given(
    pixels=_mostly(
        st.none() | st.lists(st.integers(0, 3071), max_size=20).map(np.array), pixel_args
    ),
    n_phi=_mostly(st.integers(1, 4), st.integers(-1, 0)),
    rho=_mostly(st.floats(0, 30), _near(-1, 700)),
    dg=_mostly(st.floats(-0.1, 0.1), _near(-2, 2)),
    nside=_mostly(st.just(16), st.sampled_from([12, 0, -16])),
)
def test_simulate_and_moments_return_finite_maps_or_raise(pixels, n_phi, rho, dg, nside, tiny_sky):
    try:
        scan = SyntheticScan(n_phi=n_phi, rotations_deg=(0.0, 90.0))
        systematics = Systematics(dg=dg, rho_arcmin=rho)
        maps = engine.simulate(tiny_sky, scan, Instrument(), systematics, pixels=pixels)
        h, hits = engine.scan_moments(scan, nside, pixels=pixels)
    except (ValueError, TypeError):
        event("refused")
        return
    event("simulated")
    valid = maps.valid
    assert np.isfinite(maps.q[valid]).all() and np.isfinite(maps.u[valid]).all()
    assert np.isfinite(h).all() and (hits >= 0).all()


@SLOW_FUZZ
@given(
    samples=st.lists(st.tuples(*[_near(-1, 7)] * 3), max_size=12),
    drop=st.booleans(),
)
def test_sample_streams_return_finite_maps_or_raise(samples, drop, tiny_sky):
    arr = np.array(samples, dtype=np.float64).reshape(-1, 3).T
    theta, phi, psi = arr
    if drop and theta.size:
        psi = psi[:-1]
    try:
        maps = engine.simulate_samples(tiny_sky, [(theta, phi, psi)])
        stats = scanstats.characterise([(theta, phi, psi)], tiny_sky.nside)
    except (ValueError, TypeError):
        event("refused")
        return
    event("simulated")
    assert np.isfinite(maps.q[maps.valid]).all() and np.isfinite(stats.h).all()


@pytest.fixture(scope="module")
def tiny_sky(theory):
    from boresight import sky

    return sky.make_sky(sky.SkyConfig(nside=16, lmax=47, fwhm_arcmin=240.0, seed=3), theory)
