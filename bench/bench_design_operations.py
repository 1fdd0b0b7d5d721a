"""Rotations priced in observing time: which strategy wins on the deep example once each change of
boresight angle costs SO's SAT operations (HWP spin-down 15 min, rotation 1, detector setup 20,
HWP spin-up 7), and by how much.

For the deep example's budget (gain, pointing and ellipticity) and for the same systematics at a
tenth of their amplitude, on examples/schedule_deep_sat.toml (its 24 CESs of 25 minutes, 5
minutes apart, then again at +90 deg on another day) at NSIDE: every strategy's systematic
delta_r, the minutes its changes lose, sigma(r) with them and the total, with and without
``[operations] preset = "so-sat"``; and each designed schedule as the telescope would run it
(``design --no-search`` of the written schedule with SO's operations): the free-rotation
optimum's delta_r on the CESs the operations leave it.

Usage: python bench/bench_design_operations.py [NSIDE]

Writes bench/results/design_operations.json.
"""

import csv
import sys
import tempfile
import time
from pathlib import Path

from _table import report

from boresight.commands import design as design_command

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
SCALES = {"deep example": 1.0, "a tenth of it": 0.1}


def budget_text(nside, scale, operations):
    text = (
        (EXAMPLES / "budget_deep_sat.toml").read_text().replace("nside = 128", f"nside = {nside}")
    )
    if scale != 1.0:
        text = text.replace("dg = [0.01, -0.01]", f"dg = [{0.01 * scale}, {-0.01 * scale}]")
        text = text.replace("rho_arcmin = 0.5", f"rho_arcmin = {0.5 * scale}")
        text = text.replace("ellipticity_b = 0.01", f"ellipticity_b = {0.01 * scale}")
    return text + ('\n[operations]\npreset = "so-sat"\n' if operations else "")


def main(nside):
    rows, t0 = [], time.perf_counter()
    schedule = str(EXAMPLES / "schedule_deep_sat.toml")
    with tempfile.TemporaryDirectory() as tmp:
        for label, scale in SCALES.items():
            for operations in (False, True):
                path = Path(tmp) / "budget.toml"
                path.write_text(budget_text(nside, scale, operations))
                out = Path(tmp) / "out"
                result = design_command.run(str(path), schedule, str(out), force=True,
                                            validate=False)  # fmt: skip
                # the designed schedule as SO's SAT would run it, scored without a search
                priced = Path(tmp) / "priced.toml"
                priced.write_text(budget_text(nside, scale, True))
                scored = design_command.run(
                    str(priced), str(out / "schedule_designed.toml"), str(Path(tmp) / "again"),
                    force=True, validate=False, search=False,
                )  # fmt: skip
                run = next(r for r in scored["strategies"] if r["strategy"] == "as given")
                for r in result["strategies"]:
                    row = {
                        "budget": label,
                        "priced": "so-sat" if operations else "free",
                        "strategy": r["strategy"],
                        "delta_r": f"{r['delta_r']:.4g}",
                        "lost min": f"{r.get('lost_min', 0.0):.0f}",
                        "lost %": f"{100 * r.get('lost_fraction', 0.0):.1f}",
                        "sigma(r)": f"{r.get('sigma_r_with_lost_time', result['sigma_r']):.4g}",
                        "total": f"{r.get('delta_r_total', r['delta_r']):.4g}",
                    }
                    if r["strategy"] == "optimised":
                        with open(Path(tmp) / "again" / "operations.csv") as f:
                            ops = list(csv.DictReader(f))
                        row["rotations"] = sum("rotation" in o["operations"] for o in ops)
                        row["as run: delta_r"] = f"{run['delta_r']:.4g}"
                        row["as run: lost %"] = f"{100 * run['lost_fraction']:.1f}"
                        row["as run: total"] = f"{run['delta_r_total']:.4g}"
                    rows.append(row)
    seconds = time.perf_counter() - t0
    columns = ["budget", "priced", "strategy", "delta_r", "lost min", "lost %", "sigma(r)",
               "total", "rotations", "as run: delta_r", "as run: lost %", "as run: total"]  # fmt: skip
    report(
        "design_operations",
        f"Rotations priced in observing time, the deep example, Nside {nside}",
        columns,
        [{c: row.get(c, "") for c in columns} for row in rows],
        notes=(
            "examples/budget_deep_sat.toml (and its systematics at a tenth of their amplitude) on "
            "examples/schedule_deep_sat.toml, its five allowed angles, one per CES; 'so-sat': "
            "[operations] preset = 'so-sat' (15 + 1 + 20 + 7 minutes per rotation, 22 per change "
            "of the HWP's direction, 20 per new elevation), the lost time raising sigma(r) through "
            "N_ell / (1 - f); total = delta_r + sigma(r, f) - sigma(r, 0). The repeat at +90 deg is "
            "a session of its own (another day): its rotation costs no observing time. With "
            "[operations] delta_r is each strategy's on its CESs as observed (the operations cut "
            "from their starts). 'as run': the designed schedule scored with SO's operations "
            "(design --no-search): its delta_r on the CESs it observes, its lost time and "
            f"total; 'rotations': the boresight rotations it makes. {seconds:.0f} s."
        ),
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 128)
