"""The one table of leak terms against the formula that makes them: each systematic's key turns
on exactly the terms the table says (a pair's shares, :func:`pair_terms`), and every consumer's
table is the one table in its own order."""

import numpy as np
import pytest

from boresight.instrument.pairs import PairParameters
from boresight.predict import expectation, terms
from boresight.predict.coefficients import MOMENT_NAMES, pair_terms

KEYS = {  # a Systematics key -> the PairParameters field it sets, and the repeats' gain
    "dg": ("dg", 0.0),
    "dg_repeat": (None, 0.01),
    "leak": ("leak", 0.0),
    "rho_arcmin": ("rho", 0.0),
    "pol_angle_deg": ("pol_angle", 0.0),
    "nonortho_deg": ("nonortho", 0.0),
}


@pytest.mark.parametrize("key", sorted(KEYS))
def test_a_key_turns_on_the_terms_the_table_names(key):
    field, repeat = KEYS[key]
    zeros = {name: np.zeros(2) for name in PairParameters._fields}
    if field is not None:
        zeros[field] = np.array([0.01, -0.02])
    shares = pair_terms(
        PairParameters(**zeros), np.radians([0.0, 45.0]), np.zeros(1), np.full(1, repeat)
    )
    on = {name for name, share in shares.items() if name != "m4" and np.any(np.abs(share) > 0)}
    assert on == {term.name for term in terms.switched_on_by(key)}


def test_every_term_is_a_coefficient_and_every_consumer_reads_the_table():
    shares = pair_terms(
        PairParameters(**{n: np.zeros(1) for n in PairParameters._fields}),
        np.zeros(1), np.zeros(1), np.zeros(1),
    )  # fmt: skip
    assert {t.name for t in terms.TERMS} == set(shares) - {"m4"} == set(MOMENT_NAMES)
    assert expectation.TERM_FIELDS == {t.name: (t.n, t.field) for t in terms.ordered(MOMENT_NAMES)}
    assert [t.name for t in terms.ordered(("p4", "t2"))] == ["p4", "t2"]
    assert terms.couples_through("rho_arcmin") == "h_1 G, h_3 G*"
    assert terms.couples_through("dg") == "h_2 T, h_0 P, h_4 P*"
