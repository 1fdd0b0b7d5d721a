"""What boresight rotation buys a pipeline that filters before binning: the table of
``boresight suppression --filter`` (boresight.jobs.suppression.filtered) on the deep example (or
the wide one).

The example's CES set at its own sample rate, the paper's Q and U pairs on the boresight, a sky
of FWHM 60 arcmin: per systematic, pipeline (raw, filtered) and boresight schedule (the CES set
once, and repeated at 45, 90 and 180 deg) the leaked pseudo-C_BB in three bands, over the same
schedule's raw leak and over its own pipeline's unrotated leak; then the verdict the command
prints.

Usage: python bench/bench_filtered_suppression.py [NSIDE] [FILTER] [EXAMPLE]

EXAMPLE is ``deep`` (examples/schedule_deep_sat.toml, the default), ``wide``
(examples/schedule_wide_lat.toml) or ``hexagon``: the deep example's CES set at 4 Hz seen by
every pair of TOAST's 37-pixel 35 deg hexagon, each from its own place, with gains and pointing
offsets drawn per pair (``filtered.SCATTERED``) in place of the paper's. Writes the table to bench/results/filtered_suppression.json,
its figure (boresight.outputs.plots.filtered_suppression_figure) to
docs/figures/filtered_suppression_deep.png and the filter's transfer function
(plots.transfer_figure) to docs/figures/transfer_deep.png. A FILTER that deprojects (e.g.
``"deproject(bk)"``) evaluates the sky exactly and writes
bench/results/deprojected_suppression.json, docs/figures/deprojected_suppression_deep.png and
transfer_deprojected_deep.png, with what it keeps of the sky's own E and B. The wide and hexagon examples'
files end in ``_wide`` and ``_hexagon`` (``filtered_suppression_wide.json``, ``..._suppression_wide.png``,
``transfer_..._wide.png``).
"""

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from _table import report

from boresight.config import RunOptions
from boresight.instrument.focalplane import hexagon
from boresight.jobs.suppression import filtered
from boresight.mitigation import Filtering
from boresight.outputs import plots
from boresight.schedule import load_schedule
from boresight.sky import SkyConfig, make_sky

ROOT = Path(__file__).resolve().parent.parent


EXAMPLES = {
    "deep": "schedule_deep_sat.toml",
    "wide": "schedule_wide_lat.toml",
    "hexagon": "schedule_deep_sat.toml",
}
#: the hexagon's sample rate [Hz]: 37 pairs at the deep example's 20 Hz would take 37 times the
#: axis's time; at 1 deg/s, 4 Hz still steps 0.25 deg, half an Nside-128 pixel
HEXAGON_RATE_HZ = 4.0


def main(nside, text, example="deep"):
    if example not in EXAMPLES:
        raise SystemExit(f"EXAMPLE {example!r}: one of {', '.join(EXAMPLES)}")
    schedule = load_schedule(str(ROOT / "examples" / EXAMPLES[example]))
    focalplane, cases, pairs = None, filtered.CASES, "the paper's Q and U pairs on the boresight"
    if example == "hexagon":
        schedule = dataclasses.replace(schedule, sample_rate_hz=HEXAGON_RATE_HZ)
        focalplane, cases = hexagon(37, 35.0), filtered.SCATTERED
        pairs = "every pair of TOAST's 37-pixel 35 deg hexagon from its own place"
    sky = make_sky(SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=60.0, seed=10))
    filtering = Filtering.parse(text)
    deprojects = bool(filtering.deprojection)
    evaluation = "exact" if deprojects else "interp"
    t0 = time.perf_counter()
    result = filtered.run(
        schedule,
        sky,
        filtering,
        cases=cases,
        focalplane=focalplane,
        run_options=RunOptions(evaluation=evaluation),
        progress=True,
    )
    seconds = time.perf_counter() - t0
    figures = ROOT / "docs" / "figures"
    name = "deprojected" if deprojects else "filtered"
    plots.filtered_suppression_figure(
        result, figures / f"{name}_suppression_{example}", formats=("png",)
    )
    transfer = f"transfer_deprojected_{example}" if deprojects else f"transfer_{example}"
    plots.transfer_figure(result.transfer, figures / transfer, formats=("png",))
    rows = [{k: _cell(v) for k, v in row.items() if k != "amplitude"} for row in result.rows]
    verdict = filtered.verdict(
        result.rows, result.kept, noise=result.noise, transfer=result.transfer
    )
    unrotated = next(k for k in result.kept if k["pipeline"] != filtered.RAW)
    kept = "; ".join(
        f"{field} " + "/".join(f"{v:.3f}" for k, v in unrotated.items() if k.startswith(field))
        for field in ("EE kept", "BB kept")
    )
    tf = result.transfer
    mixing = ", ".join(
        f"{name} {'/'.join(f'{x:.3f}' for x in tf.entry(into, source))}"
        for name, into, source in (
            ("F^EE", "EE", "EE"),
            ("F^BB", "BB", "BB"),
            ("E to B", "BB", "EE"),
            ("B to E", "EE", "BB"),
        )
    )
    print(verdict)
    report(
        f"{name}_suppression" + ("" if example == "deep" else f"_{example}"),
        f"What boresight rotation buys a pipeline that filters ({filtering}), the {example} "
        f"example, Nside {nside}",
        list(rows[0]),
        rows,
        notes=(
            f"examples/{EXAMPLES[example]}'s CES set at {schedule.sample_rate_hz:g} Hz, "
            f"{pairs}, a sky of FWHM 60 arcmin read by "
            f"{'exact evaluation' if deprojects else 'interpolation'}, the spectra on the raw unrotated maps' pixels with rcond > 0.05; "
            + "; ".join(f"{case.name} {case.amplitude}" for case in cases)
            + ". leak: "
            "the leaked pseudo-C_BB <dB, dB> [muK^2] per band; over raw: over the same boresight "
            "schedule's raw leak; F_BB: the filter's transfer function of B on the CES set once "
            "(SOOPERCOOL's estimator, 4 pairs of pure skies); corrected over raw: over raw "
            "divided by F_BB, the leak's bias on r filtered over raw; over unrotated: over its "
            "own pipeline's leak without rotation; delta_r: the r the leak fakes (corrected by "
            "F_BB where filtered) over 30 <= ell <= 2 Nside, against its pipeline's sigma(r) "
            f"over the bands ({result.noise.summary()}; filtered: N_ell / F_BB, its E purified; "
            "'sigma_r unpurified' adds the E the filter moves into B; where it filters without "
            "templates, F_TT: the T block, each detector's TOD filtered; N_BB kept: what the filter keeps of a white noise's BB, 4 "
            "paired realisations; 'sigma_r its noise filtered': N_ell N_BB kept / F_BB). "
            f"A leak of ~1e-36 is rounding. {seconds:.0f} s in all. The transfer per band: "
            f"{mixing}; the spread of F^BB {'/'.join(f'{x:.3f}' for x in tf.error[3, 3])}. "
            f"The sky's own (CAMB) E and B kept without rotation, over raw: {kept}. "
            f"The verdict: {verdict}"
        ),
    )


def _cell(value):
    if not isinstance(value, float):
        return value
    return "-" if np.isnan(value) else f"{value:.3g}"


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 128,
        sys.argv[2] if len(sys.argv) > 2 else "p3+ground",
        sys.argv[3] if len(sys.argv) > 3 else "deep",
    )
