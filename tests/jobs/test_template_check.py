"""The TOD checks of deprojection's predictions (the checks themselves run in the slow tests of
tests/predict/test_template_error.py and tests/predict/test_template_cost.py): what each refuses
before any work."""

import pytest
from helpers import EXAMPLES

from boresight.instrument.pairs import Systematics
from boresight.jobs.template_check import template_cost_check, template_error_check
from boresight.mitigation import Deprojection
from boresight.schedule import load_schedule


def test_the_tod_check_refuses_what_it_cannot_predict_before_any_work():
    schedule = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml")).single()
    gain = Systematics(dg=0.01)
    with pytest.raises(ValueError, match="fits \\('gain',\\) or \\('pointing',\\)"):
        template_error_check(schedule, gain, ("width",), nside=16, noise=0.1, n_skies=4)
    with pytest.raises(ValueError, match="at least 2 skies"):
        template_error_check(schedule, gain, ("gain",), nside=16, noise=0.1, n_skies=1)
    with pytest.raises(ValueError, match="noise above 0"):
        template_error_check(schedule, gain, ("gain",), nside=16, noise=0.0, n_skies=4)
    with pytest.raises(ValueError, match="ell_min 40, above 2 nside"):
        template_error_check(schedule, gain, ("gain",), nside=16, noise=0.1, n_skies=4)


def test_the_cost_check_refuses_what_it_does_not_predict():
    schedule = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml")).single()
    with pytest.raises(ValueError, match="at least 2 skies"):
        template_cost_check(schedule, Deprojection(("ellipticity",)), nside=16, n_skies=1)
    with pytest.raises(ValueError, match="templates of the sky itself"):
        template_cost_check(schedule, Deprojection(), nside=16, n_skies=4)
    with pytest.raises(ValueError, match="the default bands need nside >= 32"):
        template_cost_check(schedule, Deprojection(("ellipticity",)), nside=16, n_skies=4)
    mapped = Deprojection(("ellipticity",), template_map="planck.fits")
    with pytest.raises(ValueError, match="templates of the sky itself"):
        template_cost_check(schedule, mapped, nside=16, n_skies=4)
