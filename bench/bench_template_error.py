"""What a template map's error leaves after TOD deprojection, predicted against TOD skies.

The deep example's CES set evaluated exactly at NSIDE, T-only skies of FWHM 60 arcmin, a gain
(dg = 0.01) or a pointing offset (1 arcmin at 30 deg) deprojected per CES with its own templates
read from a template map: the sky plus white noise of 5 % and 50 % of its rms, and the sky at a
75 arcmin beam plus 5 % noise (boresight.jobs.template_check). Per case and band (20 wide from 40
to 2 NSIDE) the closed form (boresight.predict.template_error) over the mean of SKIES skies'
leak, with that mean's relative error; then the verdict against the issue's 10 %.

Usage: python bench/bench_template_error.py [NSIDE] [SKIES]

Writes bench/results/template_error.json.
"""

import sys
import time
from pathlib import Path

import numpy as np
from _table import print_verdict, report

from boresight.instrument.pairs import Systematics
from boresight.jobs.template_check import template_error_check
from boresight.schedule import load_schedule

ROOT = Path(__file__).resolve().parent.parent
SYSTEMATICS = {
    "gain": (Systematics(dg=0.01), ("gain",)),
    "pointing": (Systematics(rho_arcmin=1.0, chi_deg=30.0), ("pointing",)),
}
#: (systematic, noise over the sky's rms, the template map's beam [arcmin] or the sky's)
CASES = (
    ("gain", 0.05, None),
    ("gain", 0.5, None),
    ("gain", 0.05, 75.0),
    ("pointing", 0.05, None),
    ("pointing", 0.5, None),
    ("pointing", 0.05, 75.0),
)


def main(nside, n_skies):
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml")).single()
    rows, verdicts = [], []
    for name, noise, beam in CASES:
        systematic, templates = SYSTEMATICS[name]
        t0 = time.process_time()
        check = template_error_check(
            schedule,
            systematic,
            templates,
            nside=nside,
            noise=noise,
            n_skies=n_skies,
            template_fwhm_arcmin=beam,
            progress=True,
        )
        seconds = time.process_time() - t0
        within = bool(np.all(np.abs(check.ratio - 1) <= 0.1))
        verdicts.append(
            f"{name}, {noise:.0%} noise, {beam or 60:g}': {'within' if within else 'NOT within'} 10 %"
        )
        for lo, hi, ratio, mean, error in zip(
            check.edges[:-1], check.edges[1:], check.ratio, check.mean, check.error
        ):
            rows.append(
                {
                    "systematic": name,
                    "noise": noise,
                    "template_fwhm_arcmin": beam or 60.0,
                    "kappa": round(check.kappa, 4),
                    "band": f"{lo}-{hi - 1}",
                    "predicted_over_tod": round(float(ratio), 3),
                    "tod_error": round(float(error / mean), 3),
                    "cpu_s": round(seconds, 1),
                }
            )
    report(
        "template_error",
        f"What a template map's error leaves after deprojection per CES: prediction over the "
        f"mean of {n_skies} TOD skies, the deep example at Nside {nside} (exact evaluation)",
        [
            "systematic",
            "noise",
            "template_fwhm_arcmin",
            "kappa",
            "band",
            "predicted_over_tod",
            "tod_error",
            "cpu_s",
        ],
        rows,
        notes="predicted_over_tod: boresight.predict.template_error's closed form through "
        "expected_residual(offsets=) over the skies' mean leak pseudo-C_BB; tod_error: that "
        "mean's standard error over itself; cpu_s: the case's CPU seconds.",
    )
    print_verdict("verdict (within 10 % in every band):", verdicts)


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 64,
        int(sys.argv[2]) if len(sys.argv) > 2 else 16,
    )
