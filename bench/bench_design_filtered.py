"""Rotation for a pipeline that filters before binning: `boresight design` of the deep example
for raw pair differences and for a pipeline that subtracts a third-order polynomial per throw and
a ground template per CES (p3+ground).

The deep example's budget without its ellipticity (as bench_design_deprojection.py), at NSIDE
(delta_r over 30 <= ell <= 2 NSIDE), the sky read by EVALUATION, SKIES TOD skies checking every
strategy; the same budget with ``[filter] poly_order = 3, ground_order = 5``, whose objective is
the filtered leak of each unit simulated on OBJECTIVE_SKIES skies (boresight.design.filtered),
its delta_r against N_ell / F_ell^BB. Per strategy its predicted delta_r and its TOD check, raw
and filtered; then the verdict: which rotation each pipeline chooses and how far every check sits
from its prediction (in the two estimates' standard errors, added in quadrature).

PIPELINES ``deproject`` runs instead the pipeline that filters and then regresses the gain's
template of T per CES (BICEP/Keck's order), alone.

Usage: python bench/bench_design_filtered.py [NSIDE] [SKIES] [EVALUATION] [OBJECTIVE_SKIES]
[PIPELINES]

Writes bench/results/design_filtered.json (design_filtered_interp.json for interp;
design_filtered_deprojected.json for ``deproject``).
"""

import sys

from _table import print_verdict, report
from bench_design_deprojection import COLUMNS, NOTES, arguments, compare

#: the pipelines of each run of the bench, by its PIPELINES argument
RUNS = {
    "filter": ("design_filtered", ("raw pairs", "p3+ground")),
    "deproject": ("design_filtered_deprojected", ("p3+ground+deproject(gain)",)),
}


def main(nside, skies, evaluation, objective_skies, pipelines="filter"):
    filtered = f"[filter]\npoly_order = 3\nground_order = 5\nskies = {objective_skies}\n"
    tables = {
        "raw pairs": "",
        "p3+ground": filtered,
        "p3+ground+deproject(gain)": filtered + '[deprojection]\ntemplates = ["gain"]\n',
    }
    name, names = RUNS[pipelines]
    rows, verdicts = compare({k: tables[k] for k in names}, nside, skies, evaluation)
    report(
        name + ("" if evaluation == "exact" else "_interp"),
        f"design on the deep example at Nside {nside} (delta_r over 30 <= ell <= {2 * nside}), "
        f"{' against '.join(names)}, {skies} TOD skies per check, the filtered objective on "
        f"{objective_skies} skies of its own, the sky read by {evaluation} evaluation",
        COLUMNS,
        rows,
        notes=NOTES
        + "delta_r: the design's objective (filtered: the mean over its own skies of each "
        "strategy's filtered (deprojected) leak and its cross term with the sky's B through h_0, "
        "corrected by "
        "F_BB per band); tod_check: the mean +- standard error of the TOD skies' delta_r, the "
        "pipeline run as the row names it (the filtered TOD's spectra corrected alike); within: "
        "their distance in the two standard errors added in quadrature; cpu_s: the design's CPU "
        "seconds.",
    )
    print_verdict("verdict:", verdicts)


if __name__ == "__main__":
    main(*arguments(sys.argv[1:], (64, 8, "exact", 8, "filter")))
