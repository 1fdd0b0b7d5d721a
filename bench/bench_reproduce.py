"""Wall time of the paper reproduction, stage by stage, and its peak RSS.

Usage: python bench/bench_reproduce.py [NSIDE [LMAX]] [--backend gpu]
(default Nside 512 / lmax 1535, the --quick run; 2048 4000 is the paper's resolution).
"""

import json
import resource
import sys
import tempfile
import time

from _table import report

from boresight.commands import reproduce
from boresight.config import RunOptions
from boresight.jobs import paper


def main(nside, lmax, backend):
    study = paper.preset(nside=nside, lmax=lmax, run=RunOptions(backend=backend))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        claims = reproduce.run(f"{tmp}/out", study)
        total = time.perf_counter() - t0
        with open(f"{tmp}/out/manifest.json") as f:
            stages = json.load(f)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    rows = [dict(stage=name, seconds=s) for name, s in stages["wall_time_s"].items()]
    rows.append(dict(stage="total", seconds=total))
    report(
        f"reproduce_{nside}_{backend}",
        f"The paper's reproduction at Nside {nside}, lmax {lmax}, backend {backend}, by stage",
        ["stage", "seconds"],
        rows,
        f"peak RSS {rss:.2f} GiB; {sum(c.reproduced for c in claims)} of {len(claims)} "
        "claims reproduced",
    )


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--backend" and a != "gpu"]
    backend = "gpu" if "gpu" in sys.argv[1:] else "cpu"
    nside = int(args[0]) if args else 512
    lmax = int(args[1]) if len(args) > 1 else 3 * nside - 1
    main(nside, lmax, backend)
