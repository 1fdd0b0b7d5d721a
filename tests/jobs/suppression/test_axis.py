"""The suppression map end to end: every systematic of the catalogue through the rotation
schedules, simulated against predicted."""

import re

import pytest
from helpers import ROOT

from boresight.jobs.suppression.axis import CATALOGUE
from boresight.predict import coefficients, terms


def test_suppression_map_end_to_end(tmp_path):
    """`boresight suppression` at Nside 64: the table says which terms rotation cures (gain and
    leak at 0/90, drift at 0/180), which it cannot touch (angle errors: exactly 1), and that white
    jitter only halves with twice the samples; the prediction agrees where it applies."""
    import csv

    from boresight import cli

    out = tmp_path / "sup"
    assert cli.main(["-q", "suppression", "--out", str(out), "--nside", "64"]) == 0
    rows = {
        (r["systematic"], r["rotations_deg"]): r
        for r in csv.DictReader(open(out / "suppression.csv"))
    }
    band = "ell_30_99"
    sup = {k: float(r[f"suppression_sim_{band}"]) for k, r in rows.items()}
    pred = {k: float(r[f"suppression_pred_{band}"]) for k, r in rows.items()}
    for sched in ("0/45", "0/90", "0/180"):
        assert sup["angle", sched] == pytest.approx(1.0, rel=1e-9)
        assert pred["angle", sched] == pytest.approx(1.0, rel=1e-9)
        assert sup["gain jitter", sched] == pytest.approx(2.0, rel=0.25)  # 2x samples, scatter
    assert sup["gain", "0/90"] > 1e3 and sup["leak", "0/90"] > 1e10
    assert sup["gain drift", "0/180"] > 1e10 and sup["gain drift", "0/90"] == pytest.approx(
        1, rel=0.05
    )
    assert sup["gain", "0/45"] == pytest.approx(pred["gain", "0/45"], rel=0.1)
    assert (out / "suppression.png").is_file() and "cancels" in (out / "suppression.md").read_text()


@pytest.mark.parametrize("name", ["gain", "pointing", "leak", "angle", "non-orthogonality"])
def test_the_human_tables_name_the_moments_the_one_table_and_the_formula_give(name):
    """The catalogue's "couples through" column and the systematics guide's table name, for each
    systematic of the six leak terms, exactly the moments h_n whose coefficients its own
    systematic makes non-zero on the paper's pairs (predict.terms through pair_terms)."""
    entry = next(e for e in CATALOGUE if e.name == name)
    coefs = coefficients(entry.systematics)
    made = {t.n for t in terms.TERMS if abs(getattr(coefs, t.name)) > 1e-12}
    assert {int(n) for n in re.findall(r"h_(\d)", entry.coupling)} == made
    guide = (ROOT / "docs" / "guide" / "systematics.md").read_text()
    keys = {
        "gain": "`dg`",
        "pointing": "`rho_arcmin`",
        "leak": "`leak`",
        "angle": "`pol_angle_deg`",
        "non-orthogonality": "`nonortho_deg`",
    }
    row = next(line for line in guide.splitlines() if line.startswith("|") and keys[name] in line)
    cell = row.split("|")[3]
    assert {int(n) for n in re.findall(r"h_(\d)", cell)} == made
