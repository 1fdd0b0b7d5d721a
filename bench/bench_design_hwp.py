"""`boresight design` behind a HWP: what the search chooses, and its prediction against the TOD.

On the deep example (48 units: its 24 CESs at its two boresight repeats, Nside NSIDE), a budget
of the plate's IP (epsilon = 1e-3 at a 30 deg phase) and the pairs' gain mismatch (dg = +-0.005)
behind a stepped plate (its four steps of 22.5 deg, chosen per unit with the boresight angle)
and behind a plate spinning at 2 Hz. For every strategy (the baselines keep the stepped plate's
steps in turn): the objective's delta_r, and the mean total residual's delta_r over SKIES TOD
skies with its standard error.

Usage: python bench/bench_design_hwp.py [SKIES] [NSIDE]
"""

import sys
import tempfile
import time
from pathlib import Path

from _table import report

from boresight.commands import design as design_command

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
NOISE = "depth_uk_arcmin = 3.0\nfsky = 0.1\nfwhm_arcmin = 30.0"
PLATES = {
    "stepped (4 x 22.5 deg)": 'mode = "stepped"',
    "continuous 2 Hz": 'mode = "continuous"\nfrequency_hz = 2.0',
}


def _ratio(simulated, predicted):
    """simulated / predicted, or "-" where the prediction is far below the TOD's noise."""
    return "-" if abs(predicted) < 1e-12 else f"{simulated / predicted:.3f}"


def main(skies, nside):
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for plate_name, plate in PLATES.items():
            path = Path(tmp) / "budget.toml"
            path.write_text(
                f"[systematics]\ndg = [0.005, -0.005]\n[noise]\n{NOISE}\n"
                f"[design]\nangles_deg = [-90.0, -45.0, 0.0, 45.0, 90.0]\nnside = {nside}\n"
                f"validation_skies = {skies}\n[hwp]\n{plate}\nip = 1e-3\nip_phase_deg = 30.0\n"
            )
            t0 = time.perf_counter()
            result = design_command.run(
                str(path), str(EXAMPLES / "schedule_deep_sat.toml"), f"{tmp}/out", force=True
            )
            seconds = time.perf_counter() - t0
            searched = {r["strategy"]: r for r in result["strategies"]}
            for v in result["validation"]:
                sim, se = v["simulated_delta_r"], v["simulated_delta_r_se"]
                pred = v["predicted_delta_r"]
                rows.append(
                    dict(
                        plate=plate_name,
                        strategy=v["strategy"],
                        objective=f"{searched[v['strategy']]['delta_r']:.4g}",
                        simulated=f"{sim:.4g} +- {se:.2g}",
                        ratio=_ratio(sim, pred),
                        within=f"{abs(sim - pred) / max(se, 1e-300):.1f} se",
                        leaked_ratio=_ratio(
                            v["simulated_leaked_delta_r"], v["predicted_leaked_delta_r"]
                        ),
                        command_s=f"{seconds:.0f}",
                    )
                )
    report(
        "design_hwp",
        f"design behind a HWP (IP 1e-3 and dg +-0.005), deep example at Nside {nside}: the "
        f"objective against the mean of {skies} TOD skies",
        list(rows[0]),
        rows,
        "objective: the search's exact delta_r of the strategy; simulated: mean +- standard error "
        "of the total residual's delta_r over the skies; within: |simulated - predicted| in "
        "standard errors; leaked_ratio: the leaked power's; command_s: the whole command, "
        "search and validation",
    )


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 8,
        int(sys.argv[2]) if len(sys.argv) > 2 else 128,
    )
