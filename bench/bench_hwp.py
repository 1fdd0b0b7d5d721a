"""What a half-wave plate does to the leak of a gain and an additive leak, simulated and predicted.

The deep example at its 20 Hz, the paper's Q and U pairs, Nside NSIDE, a sky of FWHM 60 arcmin
read exactly at every sample (engine.simulate_focalplane with hwp=): per plate and systematic, the
leaked pseudo-C_BB of the TOD in three bands of 30 <= ell <= 2 Nside, the prediction from the
pairs' reflected-angle moments (predict.focalplane.delta_p) over it, and the leak over the one
without a plate.

Usage: python bench/bench_hwp.py [NSIDE]
"""

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from _table import report

from boresight import engine, harmonics, spectra
from boresight import moments as scanstats
from boresight.instrument import focalplane
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Systematics
from boresight.predict import focalplane as predict_fp
from boresight.schedule import load_schedule
from boresight.sky import SkyConfig, make_sky

SCHEDULE = Path(__file__).resolve().parent.parent / "examples" / "schedule_deep_sat.toml"
PLATES = {
    "none": None,
    "continuous 2 Hz": HWP("continuous", frequency_hz=2.0),
    "continuous 0.37 Hz": HWP("continuous", frequency_hz=0.37),
    "stepped per CES, 4 x 22.5 deg": HWP("stepped", step="ces"),
    "stepped per day, 4 x 22.5 deg": HWP("stepped", step="day"),
}
CASES = {"gain (0.01, -0.01)": Systematics(dg=(0.01, -0.01)), "leak 0.01": Systematics(leak=0.01)}


def main(nside):
    lmax = 2 * nside
    edges = np.array([30, nside, 3 * nside // 2, lmax + 1])
    bands = [f"{lo}-{hi - 1}" for lo, hi in zip(edges[:-1], edges[1:])]
    pairs = focalplane.on_axis((0.0, 45.0))
    sky = make_sky(SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=60.0, seed=10))
    rows = []
    for repeats in ((0.0,), (0.0, 90.0)):
        schedule = dataclasses.replace(load_schedule(str(SCHEDULE)), repeat_boresight_deg=repeats)
        rows += _rows(schedule, pairs, sky, edges, bands)
    columns = ["boresight", "plate", "systematic"]
    for kind in ("leak", "predicted/TOD", "over no plate"):
        columns += [f"{kind} {band}" for band in bands]
    report(
        "hwp_leak",
        f"A half-wave plate's effect on a gain and a leak, simulated and predicted, Nside {nside}",
        [*columns, "seconds"],
        rows,
        notes=(
            "The deep example at 20 Hz, once (boresight 0) and with its 0/90 repeats, the paper's "
            "Q and U pairs on the axis, a sky of FWHM 60 arcmin read exactly at every sample; "
            "pixels with rcond > 0.05. leak: the TOD's leaked pseudo-C_BB [muK^2] per band of "
            "ell; predicted: from the pairs' reflected-angle moments (predict.focalplane."
            "delta_p); over no plate: the leak over the same schedule's without a HWP (a leak "
            "the 0/90 repeats cancel to rounding has no meaningful ratio). seconds: the plate's "
            "TOD and moments."
        ),
    )


def _rows(schedule, pairs, sky, edges, bands):
    nside, lmax = sky.nside, 2 * sky.nside
    boresight = "/".join(f"{r:g}" for r in schedule.repeat_boresight_deg)
    rows, bare = [], {}
    for label, plate in PLATES.items():
        t0 = time.perf_counter()
        run = dict(evaluation="exact", hwp=plate)
        ref = engine.simulate_focalplane(sky, schedule, pairs, Systematics(), **run)
        footprint = spectra.as_footprint((ref.rcond > 0.05).astype(float))
        stats = scanstats.characterise_focalplane(schedule, pairs, nside, per_pair=True, hwp=plate)

        def bb(dp, footprint=footprint):
            d = dp[footprint.pixels]
            b = footprint.alm(np.array([d.real, d.imag]), lmax, 2)[1]
            return spectra.bin_spectrum(harmonics.alm2cl(b), edges)[1]

        for case, sy in CASES.items():
            tod = engine.simulate_focalplane(sky, schedule, pairs, sy, **run)
            measured = bb((tod.q - ref.q) + 1j * (tod.u - ref.u))
            predicted = bb(predict_fp.delta_p(sky, stats, sy))
            bare.setdefault(case, measured)
            row = dict(boresight=boresight, plate=label, systematic=case)
            for band, m, p, b in zip(bands, measured, predicted, bare[case]):
                row[f"leak {band}"] = f"{m:.3g}"
                row[f"predicted/TOD {band}"] = f"{p / m:.3f}"
                row[f"over no plate {band}"] = f"{m / b:.3g}"
            row["seconds"] = f"{time.perf_counter() - t0:.0f}"
            rows.append(row)
    return rows


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 64)
