"""The focal plane's prediction against its TOD, and what 0/90 buys once pairs sit off the axis.

TOAST's 37-pixel, 35 deg hexagon on the deep example schedule at 2 Hz, Nside 64, a sky of
FWHM 200 arcmin read exactly at every pair's own samples (engine.simulate_focalplane), with
and without the 0/90 repeat:

* per band of 40 <= ell <= 2 Nside, the leaked pseudo-C_BB of one drawn focal plane predicted
  from each pair's own h_n (predict.focalplane.delta_p) over that of the TOD, for a gain
  {mean 0, rms 0.01} and a pointing offset {mean 1, rms 0.5} arcmin;
* the expected leaked power over the draws (predict.focalplane.expected_leak_bb), its coherent
  and scattered parts, summed over those bands, and the same for every pair put on the axis
  (today's model): the suppression 0/90 buys in each.

Usage: python bench/bench_focalplane_prediction.py [NSIDE]
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np
from _table import report

from boresight import engine, harmonics, moments, spectra
from boresight.instrument import focalplane
from boresight.instrument.pairs import Spread, Systematics
from boresight.predict import focalplane as predict_fp
from boresight.schedule import load_schedule
from boresight.sky import SkyConfig, make_sky

SCHEDULE = Path(__file__).resolve().parent.parent / "examples" / "schedule_deep_sat.toml"
CASES = {
    "gain": Systematics(dg=Spread(0.0, 0.01), seed=1),
    "pointing": Systematics(rho_arcmin=Spread(1.0, 0.5), seed=2),
}
REPEATS = {"0": (0.0,), "0/90": (0.0, 90.0)}


def _bb(footprint, dp, lmax, edges):
    d = dp[footprint.pixels]
    b = footprint.alm(np.array([d.real, d.imag]), lmax, 2)[1]
    return spectra.bin_spectrum(harmonics.alm2cl(b), edges)[1]


def main(nside):
    lmax = 2 * nside
    edges = np.append(np.arange(40, lmax - 15, 16), lmax + 1)  # the last band ends at 2 Nside
    base = dataclasses.replace(load_schedule(str(SCHEDULE)), sample_rate_hz=2.0)
    fp = focalplane.hexagon(37, 35.0)
    axis = focalplane.on_axis(fp.pair_angles_deg)
    sky = make_sky(SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=200.0, seed=10))
    rows, expected = [], {}
    for label, repeats in REPEATS.items():
        schedule = dataclasses.replace(base, repeat_boresight_deg=repeats)
        stats = moments.characterise_focalplane(schedule, fp, nside, per_pair=True)
        on_axis = moments.characterise_focalplane(schedule, axis, nside, per_pair=True)
        ref = engine.simulate_focalplane(sky, schedule, fp, Systematics(), evaluation="exact")
        mask = (ref.rcond > 0.05).astype(float)
        footprint = spectra.as_footprint(mask)
        for case, sy in CASES.items():
            tod = engine.simulate_focalplane(sky, schedule, fp, sy, evaluation="exact")
            measured = _bb(footprint, (tod.q - ref.q) + 1j * (tod.u - ref.u), lmax, edges)
            predicted = _bb(footprint, predict_fp.delta_p(sky, stats, sy), lmax, edges)
            row = dict(case=f"{case}, {label}: predicted / TOD")
            for lo, hi, ratio in zip(edges[:-1], edges[1:], predicted / measured):
                row[f"ell {lo}-{hi - 1}"] = f"{ratio:.3f}"
            rows.append(row)
            for model, s in (("focal plane", stats), ("every pair on the axis", on_axis)):
                coherent, scattered = predict_fp.expected_leak_bb(sky, s, sy, mask, lmax)
                expected[(case, label, model)] = (
                    float(np.sum(coherent[40 : lmax + 1])),
                    float(np.sum(scattered[40 : lmax + 1])),
                )
    for case in CASES:
        for model in ("focal plane", "every pair on the axis"):
            (c0, s0), (c1, s1) = (expected[(case, label, model)] for label in REPEATS)
            rows.append(
                dict(
                    case=f"{case}, {model}: expected sum of C_BB [muK^2]",
                    coherent_0=f"{c0:.3g}",
                    scattered_0=f"{s0:.3g}",
                    coherent_0_90=f"{c1:.3g}",
                    scattered_0_90=f"{s1:.3g}",
                    suppression=f"{(c0 + s0) / (c1 + s1):.3g}",
                )
            )
    bands = [f"ell {lo}-{hi - 1}" for lo, hi in zip(edges[:-1], edges[1:])]
    report(
        "focalplane_prediction",
        f"A focal plane's prediction against its TOD, and what 0/90 buys off the axis, Nside {nside}",
        ["case", *bands, "coherent_0", "scattered_0", "coherent_0_90", "scattered_0_90"]
        + ["suppression"],
        rows,
        notes=(
            "37-pixel, 35 deg hexagon on the deep example at 2 Hz; sky FWHM 200 arcmin read exactly "
            "at each pair's samples; pixels with rcond > 0.05. Ratios: one drawn focal plane. "
            "Expected: coherent and scattered parts over the draws, summed over 40 <= ell <= 2 "
            "Nside; suppression = total without rotation / total with 0/90."
        ),
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 64)
