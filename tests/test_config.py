"""Study files: the examples are valid, and any config parses or names the key at fault in one line."""

import os

import healpy as hp
import numpy as np
import pytest
from helpers import EXAMPLES, FUZZ, scalars, values
from hypothesis import given
from hypothesis import strategies as st

from boresight import engine, masks
from boresight.config import ConfigError, RunOptions, parse_study, schema
from boresight.instrument.pairs import Instrument
from boresight.scan import SyntheticScan


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


@pytest.mark.parametrize("name", ["gain_deep.toml", "pointing_wide.toml"])
def test_examples_are_valid(name):
    from boresight.config import load_study

    study = load_study(os.path.join(EXAMPLES, name))
    assert study.scan.rotations_deg[0] == 0.0


def test_the_run_tables_rcond_cut_reaches_the_engine(small_sky):
    """[run] rcond_min is the engine's cut: a scan of two angles about 20 deg apart (rcond
    (1 - cos 40 deg) / (1 + cos 40 deg) = 0.13 in most pixels) keeps the pixels above the
    default 1e-6 and loses those below 0.2, exactly where each pixel's rcond says; out of
    [0, 1) it is refused."""
    scan = SyntheticScan(n_phi=2, range_rad=0.349, in_pixel="centre")
    pixels = masks.survey_mask("deep", small_sky.nside) > 0
    kept, cut = (
        engine.simulate(small_sky, scan, Instrument(pair_angles_deg=(0.0,)), pixels=pixels,
                        **RunOptions(rcond_min=r).engine_kwargs())
        for r in (RunOptions().rcond_min, 0.2)
    )  # fmt: skip
    np.testing.assert_array_equal(kept.rcond_obs, cut.rcond_obs)
    rcond = kept.rcond_obs
    assert np.mean(rcond < 0.2) > 0.5 and np.mean(rcond >= 1e-6) > 0.9
    np.testing.assert_array_equal(kept.q_obs != hp.UNSEEN, rcond >= RunOptions().rcond_min)
    np.testing.assert_array_equal(cut.q_obs != hp.UNSEEN, rcond >= 0.2)
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="rcond_min"):
            RunOptions(rcond_min=bad)


def test_a_sections_errors_name_its_key_whoever_builds_it():
    """section_errors (the design's budget builds its own options inside it): an unknown key is
    refused before the block runs, a field's ValueError becomes section.key, any other becomes
    [section], and a clean block passes its value through."""
    from boresight.config import section_errors

    built = []
    with pytest.raises(ConfigError, match=r"^unknown key run\.colour; allowed: \[") as err:
        with section_errors("run", RunOptions, {"colour": 1}):
            built.append(1)
    assert not built and "\n" not in str(err.value)
    with pytest.raises(ConfigError, match=r"^run\.rcond_min must"):
        with section_errors("run", RunOptions, {"rcond_min": 2.0}):
            RunOptions(rcond_min=2.0)
    with pytest.raises(ConfigError, match=r"^\[run\] bad"):
        with section_errors("run", RunOptions, {}):
            raise TypeError("bad thing")
    with section_errors("run", RunOptions, {"rcond_min": 0.1}):
        options = RunOptions(rcond_min=0.1)
    assert options.rcond_min == 0.1


@pytest.mark.parametrize("section, flag", [("filter", "--filter"), ("deprojection", "--deproject")])
def test_a_study_refuses_a_pipeline_s_table_and_says_where_it_goes(section, flag):
    """A study's scan is synthetic, with no throws or CESs to filter or deproject: its [filter] or
    [deprojection] is one error naming the command and the budget table that take them."""
    raw = {"sky": {"nside": 16}, section: {"poly_order": 3}}
    with pytest.raises(ConfigError, match=rf"^\[{section}\]: a study's scan is synthetic") as err:
        parse_study(raw)
    assert f"boresight suppression {flag}" in str(err.value)
    assert f"a design budget's [{section}]" in str(err.value)
