"""What boresight rotation still buys behind a half-wave plate: the table of
``boresight suppression --hwp`` (boresight.jobs.suppression.hwp) on an example schedule.

The example at its own sample rate, the paper's Q and U pairs on the axis, a sky of FWHM 60
arcmin read exactly at every sample, a plate spinning at 2 Hz (SO's small-aperture telescopes)
with an instrumental polarisation of 1e-3 (and the table's default angle offset, angle jitter and
synchronous signal): per systematic, plate and boresight schedule (the CES
set once, and repeated at 45, 90 and 180 deg) the leaked pseudo-C_BB of the TOD in three bands,
its prediction over it, and the leak over its systematic's first row.

Usage: python bench/bench_hwp_suppression.py [NSIDE] [deep|wide] [RATE_HZ]

Writes the table to bench/results/hwp_suppression[_wide].json and its figure
(boresight.outputs.plots.hwp_suppression_figure) to docs/figures/hwp_suppression_{deep,wide}.png.

RATE_HZ resamples the schedule (default its own): the wide example at 5 Hz keeps a 2 Hz plate's
4 chi turning 0.6 of a turn per sample, at a quarter of the samples.
"""

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from _table import report

from boresight.instrument.hwp import HWP
from boresight.jobs.suppression import hwp as hwp_suppression
from boresight.outputs import plots
from boresight.schedule import load_schedule
from boresight.sky import SkyConfig, make_sky

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
SCHEDULES = {"deep": "schedule_deep_sat.toml", "wide": "schedule_wide_lat.toml"}
PLATE = HWP("continuous", frequency_hz=2.0, ip=1e-3)


def main(nside, survey, rate_hz=None):
    schedule = load_schedule(str(EXAMPLES / SCHEDULES[survey]))
    if rate_hz is not None:
        schedule = dataclasses.replace(schedule, sample_rate_hz=rate_hz)
    sky = make_sky(SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=60.0, seed=10))
    t0 = time.perf_counter()
    result = hwp_suppression.run(schedule, sky, PLATE, progress=True)
    seconds = time.perf_counter() - t0
    figure = ROOT / "docs" / "figures" / f"hwp_suppression_{survey}"
    plots.hwp_suppression_figure(result, figure, formats=("png",))
    rows = [{k: _cell(v) for k, v in row.items() if k != "amplitude"} for row in result.rows]
    suffix = "" if survey == "deep" else f"_{survey}"
    report(
        f"hwp_suppression{suffix}",
        f"What boresight rotation still buys behind a 2 Hz HWP, the {survey} example, Nside {nside}",
        list(rows[0]),
        rows,
        notes=(
            f"examples/{SCHEDULES[survey]} at {schedule.sample_rate_hz:g} Hz, the paper's Q and U "
            "pairs on the axis, a sky of FWHM 60 arcmin read exactly at every sample, pixels with "
            "rcond > 0.05; gain dg = +-0.01, leak 0.01 T, a pointing offset of 1 arcmin, a "
            "polarisation-angle error of 0.5 deg, an ellipticity of 0.02 on every detector A "
            "and a 1 arcmin wider beam on every B, the plate's IP epsilon = 1e-3, its angle "
            "offset 0.1 deg, its angle jitter 0.5 deg rms per sample and its synchronous signal "
            "A_2 = A_4 = 1 muK. through: the moment the leak reaches the map through. leak: the "
            "TOD's leaked pseudo-C_BB [muK^2] per band of ell; predicted/TOD: "
            "predict.focalplane.delta_p (the pairs' reflected-angle moments; bare, with the "
            "samples' offsets from their pixel centres; a pointing offset to second order in "
            "rho, bare and behind the plate; a pointing offset and beams behind the plate "
            "through scanstats.pointing_behind and beams_behind), "
            "ip_delta_p (h_{2,0}, "
            "h_{2,8}, h_{4,8}), angle_jitter_leak (its mean's (mu - 1) P and its white part) or "
            "synchronous_delta_p (h_{2,2}, h_{2,6}, h_{4,8}) over it; over "
            "first: the leak over its systematic's first row (no plate, no rotation; the IP: "
            f"behind the plate, no rotation). A leak of ~1e-36 is rounding. {seconds:.0f} s in all."
        ),
    )


def _cell(value):
    if not isinstance(value, float):
        return value
    return "-" if np.isnan(value) else f"{value:.3g}"


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 64,
        sys.argv[2] if len(sys.argv) > 2 else "deep",
        float(sys.argv[3]) if len(sys.argv) > 3 else None,
    )
