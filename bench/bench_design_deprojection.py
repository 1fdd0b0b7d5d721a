"""Rotation against deprojection on the deep example: `boresight design` for raw pair
differences and for a pipeline that deprojects the gain's template of T per CES.

The deep example's budget (examples/budget_deep_sat.toml) without its ellipticity, at NSIDE
(delta_r over 30 <= ell <= 2 NSIDE), the sky read by EVALUATION (``exact`` at every sample, the
default, or ``interp``: an interpolated TOD smooths the pointing's gradient, which the
prediction does not), with SKIES TOD skies checking every strategy; the same
budget with ``[deprojection] templates = ["gain"]``. Per strategy (none, the paper's 0/90 and
0/180, the schedule as given, the optimised one) its predicted delta_r and its TOD check, raw and
deprojected; then the verdict: which rotation each pipeline chooses and how far every check sits
from its prediction.

Usage: python bench/bench_design_deprojection.py [NSIDE] [SKIES] [EVALUATION]

Writes bench/results/design_deprojection.json (design_deprojection_interp.json for interp).
"""

import math
import re
import sys
import tempfile
import time
from pathlib import Path

from _table import print_verdict, report

from boresight.commands import design as design_command

ROOT = Path(__file__).resolve().parent.parent
PIPELINES = {"raw pairs": "", "the gain deprojected": '[deprojection]\ntemplates = ["gain"]\n'}
#: the budget, as the notes of every table of this bench and bench_design_filtered.py say it
NOTES = (
    "examples/budget_deep_sat.toml without ellipticity_b: dg = [0.01, -0.01], rho_arcmin = 0.5, "
    "chi_deg = 30, a 30 arcmin sky, 3 muK-arcmin over fsky 0.1; "
)


def budget_text(nside, skies, evaluation, extra):
    """The deep budget, its ellipticity left out, at ``nside`` with ``skies`` TOD skies, the
    sky read by ``evaluation``."""
    text = (ROOT / "examples" / "budget_deep_sat.toml").read_text()
    text = re.sub(r"(?m)^ellipticity_b.*\n", "", text)
    design = f'nside = {nside}\nvalidation_skies = {skies}\nevaluation = "{evaluation}"'
    text = re.sub(r"(?m)^nside = \d+", design, text)
    return text + extra


#: the columns of every table of this bench and bench_design_filtered.py
COLUMNS = ["pipeline", "strategy", "delta_r", "over_sigma_r", "tod_check", "within", "cpu_s"]


def compare(pipelines, nside, skies, evaluation):
    """`boresight design` of the budget once per pipeline (its extra tables): each strategy's
    delta_r beside its TOD check (rows), and a verdict per pipeline."""
    if evaluation not in ("exact", "interp"):
        raise SystemExit(f"EVALUATION {evaluation!r}: exact or interp")
    schedule = str(ROOT / "examples" / "schedule_deep_sat.toml")
    rows, verdicts = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for pipeline, extra in pipelines.items():
            path = Path(tmp) / "budget.toml"
            path.write_text(budget_text(nside, skies, evaluation, extra))
            t0 = time.process_time()
            result = design_command.run(
                str(path), schedule, f"{tmp}/out", force=True, progress=True
            )
            seconds = time.process_time() - t0
            checked = {v["strategy"]: v for v in result["validation"]}
            worst = 0.0
            for row in result["strategies"]:
                v = checked[row["strategy"]]
                sim, se = v["simulated_delta_r"], v["simulated_delta_r_se"]
                se = math.hypot(se, v.get("predicted_delta_r_se", 0.0))  # the objective's own
                off = abs(sim - v["predicted_delta_r"]) / max(se, 1e-300)
                worst = max(worst, off)
                rows.append(
                    {
                        "pipeline": pipeline,
                        "strategy": row["strategy"],
                        "delta_r": f"{row['delta_r']:.3g}",
                        "over_sigma_r": f"{row['delta_r_over_sigma_r']:.3g}",
                        "tod_check": f"{sim:.3g} +- {v['simulated_delta_r_se']:.2g}",
                        "within": f"{off:.1f} se",
                        "cpu_s": round(seconds, 1),
                    }
                )
            best = min(result["strategies"], key=lambda r: r["delta_r"])
            verdicts.append(
                f"{pipeline}: least delta_r {best['delta_r']:.3g} "
                f"({best['delta_r_over_sigma_r']:.3g} sigma(r)) by '{best['strategy']}'; every "
                f"TOD check within {worst:.1f} standard errors of its prediction"
            )
    return rows, verdicts


def main(nside, skies, evaluation):
    rows, verdicts = compare(PIPELINES, nside, skies, evaluation)
    report(
        "design_deprojection" + ("" if evaluation == "exact" else "_interp"),
        f"design on the deep example at Nside {nside} (delta_r over 30 <= ell <= "
        f"{2 * nside}), raw pairs against the gain's template deprojected per CES, {skies} TOD "
        f"skies per check, the sky read by {evaluation} evaluation",
        COLUMNS,
        rows,
        notes=NOTES
        + "delta_r: the design's objective (the deprojected pipeline's leaves the gain's leaks "
        "of T out); tod_check: the mean +- standard error of the TOD skies' delta_r, the "
        "pipeline run as the row names it; within: their distance in standard errors; cpu_s: "
        "the design's CPU seconds.",
    )
    print_verdict("verdict:", verdicts)


def arguments(argv, defaults):
    """The command line's arguments, each of its default's type, the defaults after them."""
    return [type(d)(a) for a, d in zip(argv, defaults)] + list(defaults[len(argv) :])


if __name__ == "__main__":
    main(*arguments(sys.argv[1:], (64, 8, "exact")))
