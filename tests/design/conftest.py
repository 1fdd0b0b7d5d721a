"""The design tests' shared schedule and its per-unit moments."""

import pytest
from helpers import EXAMPLES

from boresight import cosmology
from boresight.moments import unit_moments
from boresight.schedule import CES, Schedule, load_schedule

NSIDE = 32


@pytest.fixture(scope="module")
def schedule():
    """Eight 5-minute CESs of the deep example at 2 Hz, observed again at +90 deg."""
    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    ces = tuple(
        CES(**{**c.__dict__, "duration_s": 300.0}) for c in base.ces[::3]
    )  # fmt: skip
    return Schedule(ces, base.site, 2.0, repeat_boresight_deg=(0.0, 90.0))


@pytest.fixture(scope="module")
def moments(schedule):
    return unit_moments(schedule, NSIDE, "ces")


@pytest.fixture(scope="module")
def theory():
    return cosmology.load_spectra()
