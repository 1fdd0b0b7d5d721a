"""The design's TOD check: its report's verdicts on rows made to need them, and the paired
difference from the optimised strategy measured sky by sky."""

from boresight.design.tod_check import validation_report


def test_the_report_warns_of_what_is_off_and_of_what_is_not_resolved():
    """A simulation 3 standard errors from its prediction is a warning that says its 4 skies'
    error is itself uncertain (Student's t at 95 %: 3.2), and the unresolved difference from the
    optimised strategy is named."""
    row = dict(skies=4, predicted_delta_r=1.0, simulated_delta_r=1.3, simulated_delta_r_se=0.1)
    made = [
        {**row, "strategy": "none", "difference_resolved": False},
        {**row, "strategy": "optimised", "simulated_delta_r": 1.05, "difference_resolved": False},
    ]
    lines, warnings = validation_report(made)
    assert len(lines) == 4 and "3.0s" in lines[2] and "not resolved" in lines[2]
    assert "none's simulated delta_r 1.3 +- 0.1 is 3.0 standard errors" in warnings[0]
    assert "from 4 skies the error is itself uncertain: 95 % of draws lie within 3.2" in warnings[0]
    assert "do not resolve the optimised strategy's difference from none" in warnings[1]
    assert len(warnings) == 2


def test_a_check_within_its_errors_and_resolved_says_nothing():
    row = dict(skies=16, predicted_delta_r=1.0, simulated_delta_r=1.1, simulated_delta_r_se=0.1)
    made = [
        {**row, "strategy": "none", "difference_resolved": True},
        {**row, "strategy": "optimised", "simulated_delta_r": 0.95, "difference_resolved": False},
    ]
    lines, warnings = validation_report(made)
    assert warnings == [] and "resolved" in lines[2] and "not resolved" not in lines[2]
    assert "1.0s" in lines[2] and "-0.5s" in lines[3]
