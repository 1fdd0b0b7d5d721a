"""The worked design example on a real focal plane: `boresight design` on the deep example with
TOAST's 37-pixel, 35 deg hexagon, against the same pairs on the axis.

The deep example schedule at 2 Hz (48 units: each CES, once per repeat), or a short one (8 of
its CESs, 16 units), allowed angles 0, 45, 90 deg, a gain {mean 0, rms 0.01} drawn per pair and
a pointing offset {mean 1, rms 0.5} arcmin (or, on the hexagon, the gain alone, the pointing
alone, or both and an ellipticity of 0.02 on every detector A).
Each strategy's delta_r with the same pairs on the axis (the on-axis objective) is a column.
For each focal plane the command designs on it (boresight.design.focalplane) and reports every
strategy's exact expected delta_r on it, coherent and scattered, and the mean of SKIES TOD skies
of it (every pair on its own samples, a new draw of the pairs per sky) with its standard error.
It also times the design's stages.

The sky is read as the design's ``evaluation`` says: "interp" (bilinear interpolation of the
maps) or "exact" (the band-limited sky at every sample, the prediction carrying each pair's
samples' offsets from their pixel centres).

Usage: python bench/bench_focalplane_design.py [NSIDE] [SKIES] [CASE: "gain + pointing" (both
focal planes), "gain + pointing + ellipticity", "gain" or "pointing" (the hexagon)]
[EVALUATION: interp or exact] [SCHEDULE: deep or short]
"""

import dataclasses
import resource
import sys
import tempfile
import time
from pathlib import Path

from _table import report

from boresight.commands import design as design_command
from boresight.instrument import focalplane
from boresight.schedule import load_schedule, write_schedule

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SYSTEMATICS = {
    "gain + pointing": "dg = {mean = 0.0, rms = 0.01}\nrho_arcmin = {mean = 1.0, rms = 0.5}",
    "gain": "dg = {mean = 0.0, rms = 0.01}",
    "pointing": "rho_arcmin = {mean = 1.0, rms = 0.5}",
    "gain + pointing + ellipticity": (
        "dg = {mean = 0.0, rms = 0.01}\nrho_arcmin = {mean = 1.0, rms = 0.5}\n"
        "ellipticity_a = 0.02\nellipticity_angle_a_deg = 0.0"
    ),
}
UNITS = {"deep": "48 units", "short": "8 of the deep example's CESs, 16 units"}
NOISE = "[noise]\ndepth_uk_arcmin = 3.0\nfsky = 0.1\nfwhm_arcmin = 30.0\n"


def main(nside, skies, case="gain + pointing", evaluation="interp", which="deep"):
    hexagon = focalplane.hexagon(37, 35.0)
    planes = {"37-pixel hexagon": hexagon}
    if case == "gain + pointing":
        planes["the same pairs on the axis"] = focalplane.on_axis(hexagon.pair_angles_deg)
    rows, costs = [], []
    with tempfile.TemporaryDirectory() as tmp:
        base = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml"))
        if which == "short":
            base = dataclasses.replace(base, ces=base.ces[::3])
        schedule = f"{tmp}/{which}_2hz.toml"
        write_schedule(dataclasses.replace(base, sample_rate_hz=2.0), schedule, "toml")
        budget = Path(tmp) / "budget.toml"
        budget.write_text(
            f"[systematics]\n{SYSTEMATICS[case]}\nseed = 1\n{NOISE}"
            f"[design]\nnside = {nside}\nangles_deg = [0.0, 45.0, 90.0]\n"
            f'validation_skies = {skies}\nevaluation = "{evaluation}"\n'
        )
        for label, plane in planes.items():
            t0 = time.perf_counter()
            result = design_command.run(
                str(budget), schedule, f"{tmp}/out", force=True, focalplane=plane
            )
            costs.append(
                dict(
                    focal_plane=label,
                    pairs=plane.n_pairs,
                    nside=nside,
                    skies=skies,
                    wall_s=f"{time.perf_counter() - t0:.0f}",
                    peak_rss_gib=f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.1f}",
                )
            )
            checked = {v["strategy"]: v for v in result["validation"]}
            for r in result["strategies"]:
                v = checked[r["strategy"]]
                sim, se, pred = (
                    v["simulated_delta_r"],
                    v["simulated_delta_r_se"],
                    v["predicted_delta_r"],
                )
                rows.append(
                    dict(
                        focal_plane=label,
                        strategy=r["strategy"],
                        delta_r=f"{r['delta_r']:.4g}",
                        on_axis=f"{r['delta_r_on_axis']:.4g}",
                        coherent=f"{r['fp_delta_r_coherent']:.3g}",
                        scattered=f"{r['fp_delta_r_scattered']:.3g}",
                        simulated=f"{sim:.4g} +- {se:.2g}",
                        ratio=f"{sim / pred:.3f}",
                        within=f"{abs(sim - pred) / max(se, 1e-300):.1f} se",
                    )
                )
    suffix = "" if case == "gain + pointing" else "_" + case.replace(" + ", "_")
    suffix += "" if which == "deep" else "_" + which
    suffix += "" if evaluation == "interp" else "_" + evaluation
    report(
        "focalplane_design" + suffix,
        f"design on the {which} schedule for {case}, a 37-pixel 35 deg hexagon"
        + (" against its pairs on the axis" if len(planes) > 1 else "")
        + f", Nside {nside}"
        + (", the sky read exactly at every sample" if evaluation == "exact" else ""),
        list(rows[0]),
        rows,
        notes=(
            f"The {which} schedule at 2 Hz ({UNITS[which]}), allowed angles 0/45/90; "
            f"{SYSTEMATICS[case].replace(chr(10), ', ')}, drawn per pair where given as mean and "
            "rms. delta_r: the exact "
            "expectation over skies and draws on that focal plane, with its coherent and "
            "scattered parts; on_axis: the same strategy with every pair on the axis (the "
            f"on-axis objective); simulated: the mean +- standard error over {skies} TOD skies; "
            "within: |simulated - predicted| in standard errors."
        ),
    )
    report(
        "focalplane_design_costs" + suffix,
        f"design on a focal plane for {case}: wall time",
        list(costs[0]),
        costs,
    )


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 32,
        int(sys.argv[2]) if len(sys.argv) > 2 else 16,
        sys.argv[3] if len(sys.argv) > 3 else "gain + pointing",
        sys.argv[4] if len(sys.argv) > 4 else "interp",
        sys.argv[5] if len(sys.argv) > 5 else "deep",
    )
