"""What a 0/90 boresight rotation cancels off the axis: hit-weighted <|h_2|^2> of each pair of
TOAST's 37-pixel, 35 deg hexagon on the deep example schedule (examples/schedule_deep_sat.toml),
every CES at 0 deg against the same CESs at 0 and 90 deg, and the focal plane's combination, on the
axis pair's pixels and over the whole footprint; with the scattered weight
sum_i N_i^2 |h_2,i|^2 / N^2 that a systematic drawn per pair couples through, against the
on-axis model's |h_2|^2 / n_pairs.

Usage: python bench/bench_focalplane_hn.py [NSIDE]
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np
from _table import report

from boresight import moments
from boresight.instrument import focalplane
from boresight.schedule import load_schedule

SCHEDULE = Path(__file__).resolve().parent.parent / "examples" / "schedule_deep_sat.toml"
RINGS = ((0.0, 0.1, "on the axis"), (5, 6, "5.8 deg off"), (10, 12, "10.1-11.7 deg off"))
RINGS += ((15, 18, "15.2-17.5 deg off"),)


def _weighted(values, weights):
    return float(np.sum(weights * values) / np.sum(weights))


def main(nside):
    base = load_schedule(str(SCHEDULE))
    fp = focalplane.hexagon(37, 35.0)
    on_axis = focalplane.on_axis(fp.pair_angles_deg)
    runs = {}
    for label, repeats in (("0", (0.0,)), ("0/90", (0.0, 90.0))):
        schedule = dataclasses.replace(base, repeat_boresight_deg=repeats)
        runs[label] = (
            moments.characterise_focalplane(schedule, fp, nside, progress=True),
            moments.characterise_focalplane(schedule, on_axis, nside),
        )
    rows = []
    for lo, hi, what in RINGS:
        sel = (fp.radius_deg >= lo) & (fp.radius_deg < hi)
        values = {}
        for label, (planes, _) in runs.items():
            h2 = [m["abs_h2_sq"] for m, s in zip(planes.pair_means(), sel) if s]
            values[label] = f"{min(h2):.3g}" if len(h2) == 1 else f"{min(h2):.3g}-{max(h2):.3g}"
        rows.append(dict(detector=what, pairs=int(sel.sum()), **values))
    first = dataclasses.replace(base, repeat_boresight_deg=(0.0,))
    centre = moments.characterise_focalplane(first, fp.subset([0]), nside).combined.hits > 0
    for where in ("on the axis pair's pixels", "whole footprint"):
        values = {}
        for label, (planes, _) in runs.items():
            hits = planes.combined.hits.astype(float)
            pixels = centre if where.startswith("on") else hits > 0
            h2 = np.abs(planes.combined.h[2][pixels]) ** 2
            values[label] = f"{_weighted(h2, hits[pixels]):.3g}"
        rows.append(dict(detector=f"all 37 pairs binned together, {where}", pairs=37, **values))
    for model in ("focal plane", "every pair on the axis"):
        values = {}
        for label, (planes, axis) in runs.items():
            stats = planes if model == "focal plane" else axis
            hits = stats.combined.hits.astype(float)
            seen = hits > 0
            values[label] = f"{_weighted(stats.scattered()[2][seen], hits[seen]):.3g}"
        rows.append(dict(detector=f"scattered weight, {model}", pairs=37, **values))
    report(
        "focalplane_hn",
        f"Hit-weighted <|h_2|^2> of a 37-pixel, 35 deg hexagon on the deep example, Nside {nside}",
        ["detector", "pairs", "0", "0/90"],
        rows,
        notes=(
            "Columns: every CES at boresight angle 0 deg, and the same CESs again at 90 deg. A "
            "range is the smallest to largest pair of a ring. The scattered weight is the hit-"
            "weighted sum_i N_i^2 |h_2,i|^2 / N^2 (the focal plane) or |h_2|^2 / 37 (every pair "
            "on the axis, today's model): what a gain drawn per pair couples through."
        ),
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 64)
