"""What TOD template deprojection takes of the sky, predicted against TOD skies.

The deep example's CES set evaluated exactly at NSIDE, SKIES CAMB skies (T, E and B correlated,
FWHM 60 arcmin), the paper's Q and U pairs, no systematic; the maps binned from the raw pair
differences and from the deprojected ones, the templates read from each sky itself
(boresight.jobs.template_check.template_cost_check). Per deprojection (the spin-2 ellipticity
templates, BK's six, the spin-0 gain template; per CES and per 10 hours of CESs) and band: the
skies' mean pseudo-C_EE and pseudo-C_BB deprojected over raw, with their errors, against the
definite share the spin rule predicts (boresight.predict.template_cost: only a spin-2 template
takes a definite share of E; spins 0 and 1 only a chance projection, which the prediction leaves
out), the E taken (1 - kept) predicted over measured, and the r the change of an unpurified
pseudo-C_BB fakes; then the verdict against 10 %.

Usage: python bench/bench_template_cost.py [NSIDE] [SKIES]

Writes bench/results/template_cost.json.
"""

import sys
import time
from pathlib import Path

import numpy as np
from _table import print_verdict, report

from boresight.jobs.template_check import template_cost_check
from boresight.mitigation import Deprojection
from boresight.schedule import load_schedule

ROOT = Path(__file__).resolve().parent.parent
CASES = ("ellipticity/10h", "ellipticity", "bk/10h", "bk", "gain")


def main(nside, n_skies):
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml")).single()
    rows, verdicts = [], []
    for text in CASES:
        t0 = time.process_time()
        check = template_cost_check(
            schedule, Deprojection.parse(text), nside=nside, n_skies=n_skies, progress=True
        )
        seconds = time.process_time() - t0
        taken, predicted = 1.0 - check.ee_kept, 1.0 - check.ee_predicted
        ratio = np.divide(predicted, taken, out=np.full_like(taken, np.nan), where=taken != 0)
        within = bool(np.all(np.abs(predicted - taken) <= 0.1 * np.abs(taken)))
        verdicts.append(
            f"{text}: E taken {_slash(taken)}, predicted {_slash(predicted)} - "
            + ("within" if within else "NOT within")
            + " 10 %"
        )
        for i, (lo, hi) in enumerate(zip(check.edges[:-1], check.edges[1:])):
            rows.append(
                {
                    "deprojection": text,
                    "band": f"{lo}-{hi - 1}",
                    "EE kept": f"{check.ee_kept[i]:.3f} +- {check.ee_error[i]:.3f}",
                    "EE predicted": f"{check.ee_predicted[i]:.3f}",
                    "E taken, predicted over measured": f"{ratio[i]:.2f}",
                    "BB kept": f"{check.bb_kept[i]:.3f} +- {check.bb_error[i]:.3f}",
                    "BB predicted": f"{check.bb_predicted[i]:.3f}",
                    "delta_r faked (unpurified)": f"{check.delta_r:.2g} +- {check.delta_r_error:.1g}",
                    "predicted": f"{check.delta_r_predicted:.2g}",
                    "correlation": round(check.correlation, 3),
                    "cpu_s": round(seconds, 1),
                }
            )
    report(
        "template_cost",
        f"What deprojection takes of the sky: the mean of {n_skies} CAMB skies against the spin "
        f"rule's prediction, the deep example at Nside {nside} (exact evaluation)",
        list(rows[0]),
        rows,
        notes="EE (BB) kept: the skies' mean pseudo-C_EE (C_BB) deprojected over raw on the raw "
        "maps' footprint, +- the spread of each sky's ratio over sqrt(skies); predicted: "
        "boresight.predict.template_cost's definite share of E (a spin-2 template's, through "
        "C^TE) read through the footprint's mask, whose E leaks into the pseudo-C_BB; the "
        "blocks' chance projection is not in it; correlation: the spin-2 template's zero-lag "
        "correlation with P at lmax = 2 Nside; delta_r faked: the r the deprojected maps' "
        "pseudo-C_BB fakes over the raw maps' (no purification: the E the mask leaks into B), the "
        "skies' mean +- its error, and the same from the definite share of E taken; cpu_s: the "
        "case's CPU seconds.",
    )
    print_verdict("verdict (E taken within 10 % in every band):", verdicts)


def _slash(values):
    return " / ".join(f"{v:.3f}" for v in values)


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 64,
        int(sys.argv[2]) if len(sys.argv) > 2 else 16,
    )
