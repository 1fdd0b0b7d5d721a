"""Study files: the examples are valid, and any config parses or names the key at fault in one line."""

import os

import pytest
from helpers import EXAMPLES, FUZZ, scalars, values
from hypothesis import given
from hypothesis import strategies as st

from boresight.config import ConfigError, parse_study, schema


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
