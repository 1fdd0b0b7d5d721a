"""Each command's memory estimate against its measured peak, and its time estimate against its
run, across Nside.

Every run is a fresh process that runs the command line, its peak the kernel's high-water mark of
its resident memory (``VmHWM``, read by the process as it ends: a child's ``ru_maxrss`` starts at
its parent's), its estimate the one it wrote into its manifest.json before any work.
``tests/jobs/test_resources.py`` checks a subset of these within a factor of 1.5.

Usage: python bench/bench_memory.py [NSIDE,NSIDE,...] [COMMAND,COMMAND,...]
(default 64,128,256,512 and every command below).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _table import report

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def study_file(directory, nside, systematics="dg = [0.01, -0.01]", fwhm=7.0):
    """The deep gain example at one Nside: lmax 3 Nside - 1, spectra to 2 Nside."""
    text = (EXAMPLES / "gain_deep.toml").read_text()
    text = text.replace("nside = 256", f"nside = {nside}").replace(
        "lmax = 767", f"lmax = {3 * nside - 1}"
    )
    text = text.replace("lmax = 512", f"lmax = {2 * nside}").replace(
        "dg = [0.01, -0.01]", systematics
    )
    text = text.replace("fwhm_arcmin = 7.0", f"fwhm_arcmin = {fwhm}")
    path = Path(directory) / f"study_{nside}_{abs(hash((systematics, fwhm)))}.toml"
    path.write_text(text)
    return str(path)


def budget_file(directory, nside):
    """The deep example's budget at one Nside, its TOD check on one sky per strategy (the skies
    run one after another: the peak is one sky's)."""
    text = (
        (EXAMPLES / "budget_deep_sat.toml").read_text().replace("nside = 128", f"nside = {nside}")
    ) + "validation_skies = 1\n"
    path = Path(directory) / f"budget_{nside}.toml"
    path.write_text(text)
    return str(path)


def season_file(directory):
    """The deep example's CES set at 12 boresight angles: 8.6 million samples, 3 groups of CESs
    (moments.focalplane.time_groups)."""
    text = (EXAMPLES / "schedule_deep_sat.toml").read_text()
    angles = ", ".join(f"{30.0 * k}" for k in range(12))
    text = text.replace("repeat_boresight_deg = [0.0, 90.0]", f"repeat_boresight_deg = [{angles}]")
    path = Path(directory) / "season.toml"
    path.write_text(text)
    return str(path)


def command_args(command, directory, nside):
    """The arguments of each benchmarked command at one Nside."""
    schedule = str(EXAMPLES / "schedule_deep_sat.toml")
    beams = "ellipticity_b = 0.02\ndfwhm_a_arcmin = 0.5"
    return {
        "simulate": ["simulate", study_file(directory, nside)],
        "simulate (beams)": ["simulate", study_file(directory, nside, beams, fwhm=30.0)],
        "predict": ["predict", study_file(directory, nside)],
        "predict (beams)": ["predict", study_file(directory, nside, beams, fwhm=30.0)],
        "scan-stats": ["scan-stats", study_file(directory, nside)],
        "scan-stats (schedule)": ["scan-stats", schedule, "--nside", str(nside)],
        "scan-stats (focal plane)": [
            "scan-stats",
            schedule,
            "--nside",
            str(nside),
            "--focalplane",
            "hexagon:37:35",
        ],
        "scan-stats (per detector)": [
            "scan-stats",
            schedule,
            "--nside",
            str(nside),
            "--focalplane",
            "hexagon:91:35",
            "--per-detector",
            "--format",
            "so",
        ],
        "scan-stats (per detector, a season)": [
            "scan-stats",
            season_file(directory),
            "--nside",
            str(nside),
            "--focalplane",
            "hexagon:91:35",
            "--per-detector",
            "--format",
            "so",
            "--partial",
        ],
        "scan-stats (hwp)": [
            "scan-stats",
            schedule,
            "--nside",
            str(nside),
            "--hwp",
            "continuous",
            "--hwp-frequency",
            "1.3",
        ],
        "compare-scans": ["compare-scans", schedule, "--nside", str(nside)],
        "design": ["design", budget_file(directory, nside), schedule],
        "suppression": ["suppression", "--nside", str(nside)],
        "suppression (filter)": [
            "suppression",
            "--nside",
            str(nside),
            "--filter",
            "p3+ground",
            "--schedule",
            schedule,
        ],
        "suppression (deproject)": [
            "suppression",
            "--nside",
            str(nside),
            "--deproject",
            "bk",
            "--schedule",
            schedule,
        ],
        "reproduce": ["reproduce", "--nside", str(nside), "--lmax", str(3 * nside - 1)],
    }[command]


COMMANDS = (
    "simulate",
    "simulate (beams)",
    "predict",
    "predict (beams)",
    "scan-stats",
    "scan-stats (schedule)",
    "scan-stats (focal plane)",
    "scan-stats (per detector)",
    "scan-stats (hwp)",
    "compare-scans",
    "design",
    "suppression",
    "suppression (filter)",
    "suppression (deproject)",
    "reproduce",
)


#: the command line in a process that prints its own peak resident memory [kB] as it ends
PEAK = """
import sys
from boresight.cli import main
code = main(sys.argv[1:])
with open("/proc/self/status") as f:
    print(next(line.split()[1] for line in f if line.startswith("VmHWM")))
sys.exit(code)
"""


def measure(args, out):
    """(peak resident GiB, wall seconds, the manifest's estimate) of one fresh run."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", PEAK, "-q", *args, "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    seconds = time.perf_counter() - t0
    if proc.returncode not in (0, 1):  # reproduce exits 1 below Nside 256
        raise RuntimeError(f"{args} failed: {proc.stderr}")
    estimate = json.loads((Path(out) / "manifest.json").read_text())["estimate"]
    return int(proc.stdout.split()[-1]) / 2**20, seconds, estimate


def main(nsides, commands):
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        for command in commands:
            for nside in nsides:
                peak, seconds, estimate = measure(
                    command_args(command, directory, nside), Path(directory) / "out"
                )
                rows.append(
                    dict(
                        command=command,
                        nside=nside,
                        peak_gib=round(peak, 3),
                        estimate_gib=estimate["memory_gib"],
                        ratio=round(estimate["memory_gib"] / peak, 3),
                        process_gib=estimate["parts_gib"]["process"],
                        seconds=round(seconds, 1),
                        estimated_s=estimate["seconds"],
                    )
                )
                print(rows[-1], flush=True)
    columns = list(rows[0])
    report(
        "memory",
        "Memory estimate against the measured peak of a fresh process, and time (2-core machine)",
        columns,
        rows,
        "ratio = estimate / peak; process = the resident memory when the job is checked. "
        "seconds include the process's start (imports, loading cached kernels).",
    )


if __name__ == "__main__":
    nsides = [int(n) for n in sys.argv[1].split(",")] if len(sys.argv) > 1 else [64, 128, 256, 512]
    commands = sys.argv[2].split(",") if len(sys.argv) > 2 else list(COMMANDS)
    main(nsides, commands)
