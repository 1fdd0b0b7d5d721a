"""Property-based fuzzing of every entry point, with Hypothesis.

For any generated input the outcome is one of: success with finite results; a ConfigError (exit 2
with one line naming a key or file); or a ValueError / TypeError from the API. Never another
exception, a crash, NaN output with exit 0, or a write outside --out. Example counts are fixed and
derandomised, and the resolution is Nside <= 16, so the suite costs seconds in CI.
"""

import math
import os
import re

import numpy as np
import pytest
from helpers import FUZZ, mostly
from hypothesis import event, given, settings
from hypothesis import strategies as st

from boresight import engine, moments
from boresight.cli import main
from boresight.instrument.pairs import Instrument, Systematics
from boresight.scan import SyntheticScan

SLOW_FUZZ = settings(FUZZ, max_examples=20)


def _near(lo, hi):
    """Floats in [lo, hi] and the non-finite values that must never pass."""
    return st.one_of(st.floats(lo, hi), st.sampled_from([math.nan, math.inf, -math.inf]))


@st.composite
def small_studies(draw):
    """Runnable studies at Nside <= 16 (lmax above the default lmin of 20), each field now and
    then out of range or non-finite."""
    nside = draw(mostly(st.sampled_from([8, 16]), st.sampled_from([1, 2, 4, 12, 0, True])))
    top = 3 * max(int(nside), 1) - 1
    return {
        "sky": {
            "nside": nside,
            "lmax": draw(mostly(st.integers(21, max(top, 21)), st.integers(-1, 60))),
            "fwhm_arcmin": draw(mostly(st.floats(60, 600), _near(-1, 2e4))),
            "r": draw(mostly(st.floats(0, 1), _near(-1, 1e3))),
            "seed": draw(mostly(st.integers(0, 2**63 - 1), st.integers(-5, 2**65))),
        },
        "scan": {
            "n_phi": draw(mostly(st.integers(1, 5), st.integers(-1, 0))),
            "range_rad": draw(mostly(st.floats(0, 6.28), _near(-1, 7))),
            "rotations_deg": draw(
                mostly(st.lists(st.floats(-400, 400), min_size=1, max_size=3), st.just([]))
            ),
        },
        "systematics": {
            "dg": draw(
                mostly(
                    st.lists(st.floats(-0.5, 0.5), min_size=2, max_size=2),
                    st.lists(_near(-2, 2), min_size=1, max_size=3),
                )
            ),
            "rho_arcmin": draw(mostly(st.floats(0, 30), _near(-1, 800))),
        },
        "mask": {"survey": draw(mostly(st.sampled_from(["deep", "wide", "none"]), st.just("x")))},
        "output": {
            "lmax": draw(mostly(st.integers(21, max(top, 21)), st.integers(0, 60))),
            "n_bands": draw(mostly(st.integers(1, 5), st.integers(-1, 0))),
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
@pytest.mark.slow
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


# The public API ---------------------------------------------------------------------------------


def _names_one_of(err, names):
    """Whether an error's message names one of the arguments (not a bare numpy or numba error)."""
    return any(re.search(rf"\b{name}\b", str(err)) for name in names)


pixel_args = st.one_of(
    st.none(),
    st.lists(st.integers(-5, 4000), max_size=20).map(np.array),
    st.lists(_near(-5, 4000), max_size=20).map(np.array),
    st.lists(st.booleans(), min_size=0, max_size=30).map(np.array),
    st.just(np.ones((2, 3), dtype=np.int64)),
)


@SLOW_FUZZ
@given(
    pixels=mostly(
        st.none() | st.lists(st.integers(0, 3071), max_size=20).map(np.array), pixel_args
    ),
    n_phi=mostly(st.integers(1, 4), st.integers(-1, 0)),
    rho=mostly(st.floats(0, 30), _near(-1, 700)),
    dg=mostly(st.floats(-0.1, 0.1), _near(-2, 2)),
    nside=mostly(st.just(16), st.sampled_from([12, 0, -16])),
)
def test_simulate_and_moments_return_finite_maps_or_raise(pixels, n_phi, rho, dg, nside, tiny_sky):
    """Finite maps, or a ValueError / TypeError that names the argument at fault."""
    try:
        scan = SyntheticScan(n_phi=n_phi, rotations_deg=(0.0, 90.0))
        systematics = Systematics(dg=dg, rho_arcmin=rho)
        maps = engine.simulate(tiny_sky, scan, Instrument(), systematics, pixels=pixels)
        h, hits = engine.scan_moments(scan, nside, pixels=pixels)
    except (ValueError, TypeError) as err:
        assert _names_one_of(err, ["pixels", "n_phi", "rho_arcmin", "dg", "nside"]), err
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
        stats = moments.characterise([(theta, phi, psi)], tiny_sky.nside)
    except (ValueError, TypeError) as err:
        assert _names_one_of(err, ["theta", "phi", "psi", "samples"]), err
        event("refused")
        return
    event("simulated")
    assert np.isfinite(maps.q[maps.valid]).all() and np.isfinite(stats.h).all()


@pytest.fixture(scope="module")
def tiny_sky(theory):
    from boresight import sky

    return sky.make_sky(sky.SkyConfig(nside=16, lmax=47, fwhm_arcmin=240.0, seed=3), theory)
