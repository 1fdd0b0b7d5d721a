"""The report's verdicts are computed from the results table: the paper's 18 claims at a low
resolution, and a claim that fails when its numbers are made to fail."""

import pytest

from boresight.jobs import paper
from boresight.outputs import report

STUDY = paper.preset(nside=64, lmax=191, seed=3)


@pytest.fixture(scope="module")
def reproduction():
    results, stages = paper.run_study(STUDY)
    return results, paper.tidy_rows(results, STUDY), stages


def test_every_claim_has_a_test_a_measurement_and_the_report_counts_them(reproduction):
    results, rows, stages = reproduction
    claims = report.evaluate_claims(results, rows, STUDY)
    assert len(claims) == 18 and all(c.test and c.measured for c in claims)
    text = report.report_markdown(claims, STUDY, stages)
    done = sum(c.reproduced for c in claims)
    assert f"**{done} of 18 claims reproduced.**" in text
    assert text.count("| not reproduced |") == 18 - done


def test_a_claim_fails_when_its_numbers_do(reproduction):
    """70 deg is said to give about one order: with the 70 deg residual replaced by the
    unrotated one (a reduction of 1) that claim, and no other of the gain case's, fails."""
    results, rows, _ = reproduction
    unrotated = {
        (r["ell_lo"]): r["residual_bb"]
        for r in rows
        if r["experiment"] == "gain_deep" and r["pbr_angle_deg"] == ""  # no rotation
    }
    spoiled = [
        {**r, "residual_bb": unrotated[r["ell_lo"]]}
        if r["experiment"] == "gain_deep" and r["pbr_angle_deg"] == 70.0
        else r
        for r in rows
    ]
    before = {c.statement: c.reproduced for c in report.evaluate_claims(results, rows, STUDY)}
    after = {c.statement: c.reproduced for c in report.evaluate_claims(results, spoiled, STUDY)}
    changed = [s for s in before if before[s] != after[s]]
    assert changed == ["70 deg gives about one order of magnitude."]
