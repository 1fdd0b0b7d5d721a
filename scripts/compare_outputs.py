"""Run the commands whose outputs a refactor must keep, and compare two such runs cell by cell.

    python scripts/compare_outputs.py run OUT [--checkout DIR] [--only NAME ...]
    python scripts/compare_outputs.py compare BEFORE AFTER

``run`` writes each command's output to OUT/<name>, importing boresight from --checkout (a
worktree of the commit before the change, say) instead of the installed copy. ``compare`` walks
both trees and compares every CSV cell, every FITS/HDF5/NPZ array and every JSON value, apart
from when, where and with what it ran (the keys and columns in IGNORED); it prints one verdict
line per file and exits 1 when any differs.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

DEEP = "examples/schedule_deep_sat.toml"
HWP_SKY = ["--nside", "32", "--fwhm-arcmin", "480"]  # a beam of 4 pixels at Nside 32

#: name -> arguments of ``boresight``, each run into OUT/<name> (issue 51's list)
COMMANDS = {
    "reproduce_quick": ["reproduce", "--quick"],
    "suppression": ["suppression", "--nside", "32"],
    "suppression_hwp_continuous": [
        "suppression",
        "--hwp",
        "continuous",
        "--schedule",
        DEEP,
        *HWP_SKY,
    ],
    "suppression_hwp_stepped": ["suppression", "--hwp", "stepped", "--schedule", DEEP, *HWP_SKY],
    "suppression_hwp_continuous_hexagon": [
        "suppression",
        "--hwp",
        "continuous",
        "--schedule",
        DEEP,
        *HWP_SKY,
        "--focalplane",
        "hexagon:7:20",
    ],
    "suppression_hwp_stepped_hexagon": [
        "suppression",
        "--hwp",
        "stepped",
        "--schedule",
        DEEP,
        *HWP_SKY,
        "--focalplane",
        "hexagon:7:20",
    ],
    "scan_stats": ["scan-stats", DEEP, "--nside", "32"],
    "scan_stats_so_hexagon": [
        "scan-stats",
        DEEP,
        "--nside",
        "32",
        "--format",
        "so",
        "--focalplane",
        "hexagon:7:20",
    ],
    "scan_stats_so_per_detector": [
        "scan-stats",
        DEEP,
        "--nside",
        "32",
        "--format",
        "so",
        "--focalplane",
        "hexagon:7:20",
        "--per-detector",
    ],
    "scan_stats_litebird": [
        "scan-stats",
        DEEP,
        "--nside",
        "32",
        "--format",
        "litebird",
        "--frame",
        "galactic",
    ],
    "scan_stats_hwp": ["scan-stats", DEEP, "--nside", "32", "--hwp", "continuous"],
    "design": ["design", "examples/budget_deep_sat.toml", DEEP],
    "suppression_filtered": [
        "suppression",
        "--filter",
        "p1+ground",
        "--deproject",
        "gain",
        "--schedule",
        DEEP,
        *HWP_SKY,
    ],
    "suppression_filter_only": ["suppression", "--filter", "p1", "--schedule", DEEP, *HWP_SKY],
    "suppression_deprojected": [
        "suppression",
        "--deproject",
        "gain,ellipticity",
        "--schedule",
        DEEP,
        *HWP_SKY,
    ],
}

#: keys and columns that may differ between two runs of the same numbers
#: keys and columns that differ between two runs of the same numbers: when and where it ran,
#: with what, and this process's memory at the start (so the estimate's total too)
IGNORED = {"created", "versions", "git_revision", "machine", "wall_time_s", "process", "memory_gib"}
#: text lines that name the same
IGNORED_LINE = re.compile(r"(version|created|revision|wall time|machine)", re.I)


def run(out: Path, checkout: Path | None, only: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    prefix = "import sys; " + (f"sys.path.insert(0, {str(checkout)!r}); " if checkout else "")
    code = prefix + "from boresight.cli import main; sys.exit(main())"
    for name, args in COMMANDS.items():
        if only and name not in only:
            continue
        start = time.time()
        proc = subprocess.run(
            [sys.executable, "-c", code, "-q", *args, "--out", str(out / name), "--force"],
            cwd=checkout or Path.cwd(),
            capture_output=True,
            text=True,
        )
        (out / f"{name}.log").write_text(proc.stdout + proc.stderr)
        print(f"{name:40s} rc={proc.returncode} {time.time() - start:7.1f} s", flush=True)


def _numbers(value):
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _csv(a: Path, b: Path) -> list[str]:
    ra = list(csv.reader(a.open()))
    rb = list(csv.reader(b.open()))
    if len(ra) != len(rb):
        return [f"{len(ra)} rows against {len(rb)}"]
    header = ra[0] if ra else []
    problems = []
    for i, (x, y) in enumerate(zip(ra, rb)):
        if len(x) != len(y):
            problems.append(f"row {i}: {len(x)} cells against {len(y)}")
            continue
        for j, (u, v) in enumerate(zip(x, y)):
            column = header[j] if j < len(header) else str(j)
            if u == v or column in IGNORED:
                continue
            nu, nv = _numbers(u), _numbers(v)
            if nu is not None and nv is not None and (nu == nv or (np.isnan(nu) and np.isnan(nv))):
                continue
            problems.append(f"row {i} {column}: {u!r} against {v!r}")
    return problems


def _arrays(a: np.ndarray, b: np.ndarray, where: str) -> list[str]:
    if a.shape != b.shape or a.dtype != b.dtype:
        return [f"{where}: {a.shape} {a.dtype} against {b.shape} {b.dtype}"]
    if a.dtype.kind in "fc":
        same = np.array_equal(a, b, equal_nan=True)
    else:
        same = np.array_equal(a, b)
    if same:
        return []
    if a.dtype.kind in "fc":
        diff = np.nanmax(np.abs(a - b)) / max(np.nanmax(np.abs(a)), 1e-300)
        return [f"{where}: differs, max |a-b|/max|a| = {diff:.2e}"]
    return [f"{where}: differs"]


def _fits(a: Path, b: Path) -> list[str]:
    from astropy.io import fits

    problems = []
    with fits.open(a) as ha, fits.open(b) as hb:
        if len(ha) != len(hb):
            return [f"{len(ha)} HDUs against {len(hb)}"]
        for k, (x, y) in enumerate(zip(ha, hb)):
            if x.data is None and y.data is None:
                continue
            if hasattr(x.data, "names") and x.data.names:
                for name in x.data.names:
                    problems += _arrays(
                        np.asarray(x.data[name]), np.asarray(y.data[name]), f"HDU {k} {name}"
                    )
            else:
                problems += _arrays(np.asarray(x.data), np.asarray(y.data), f"HDU {k}")
    return problems


def _hdf5(a: Path, b: Path) -> list[str]:
    import h5py

    problems = []
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        names_a, names_b = [], []
        fa.visit(names_a.append)
        fb.visit(names_b.append)
        if sorted(names_a) != sorted(names_b):
            return ["different datasets"]
        for name in names_a:
            if isinstance(fa[name], h5py.Dataset):
                problems += _arrays(np.asarray(fa[name][()]), np.asarray(fb[name][()]), name)
    return problems


def _npz(a: Path, b: Path) -> list[str]:
    with np.load(a, allow_pickle=False) as za, np.load(b, allow_pickle=False) as zb:
        if sorted(za.files) != sorted(zb.files):
            return ["different arrays"]
        return [p for name in za.files for p in _arrays(za[name], zb[name], name)]


def _json_values(x, y, where: str) -> list[str]:
    if isinstance(x, dict) and isinstance(y, dict):
        problems = []
        for key in sorted(set(x) | set(y)):
            if key in IGNORED:
                continue
            if key not in x or key not in y:
                problems.append(f"{where}/{key}: in one only")
            else:
                problems += _json_values(x[key], y[key], f"{where}/{key}")
        return problems
    if isinstance(x, list) and isinstance(y, list):
        if len(x) != len(y):
            return [f"{where}: {len(x)} items against {len(y)}"]
        return [
            p for i, (u, v) in enumerate(zip(x, y)) for p in _json_values(u, v, f"{where}[{i}]")
        ]
    if x == y or (isinstance(x, float) and isinstance(y, float) and np.isnan(x) and np.isnan(y)):
        return []
    return [f"{where}: {x!r} against {y!r}"]


def _json(a: Path, b: Path) -> list[str]:
    return _json_values(json.loads(a.read_text()), json.loads(b.read_text()), "")


def _text(a: Path, b: Path) -> list[str]:
    """Line by line, but lines that name a time, a version, a date or a path."""
    la, lb = a.read_text().splitlines(), b.read_text().splitlines()
    if len(la) != len(lb):
        return [f"{len(la)} lines against {len(lb)}"]
    return [
        f"line {i + 1}: {x!r} against {y!r}"
        for i, (x, y) in enumerate(zip(la, lb))
        if x != y and not IGNORED_LINE.search(x)
    ]


COMPARERS = {
    ".csv": _csv,
    ".fits": _fits,
    ".h5": _hdf5,
    ".hdf5": _hdf5,
    ".npz": _npz,
    ".json": _json,
    ".md": _text,
    ".toml": _text,
    ".txt": _text,
    ".ecsv": _text,
}


def compare(before: Path, after: Path) -> int:
    files_a = {p.relative_to(before) for p in before.rglob("*") if p.is_file()}
    files_b = {p.relative_to(after) for p in after.rglob("*") if p.is_file()}
    failures = 0
    counted = 0
    for rel in sorted(files_a | files_b):
        if rel.suffix not in COMPARERS:
            continue
        if rel not in files_a or rel not in files_b:
            print(f"DIFFERS  {rel}: in {'before' if rel in files_a else 'after'} only")
            failures += 1
            continue
        problems = COMPARERS[rel.suffix](before / rel, after / rel)
        counted += 1
        if problems:
            failures += 1
            print(
                f"DIFFERS  {rel}: "
                + "; ".join(problems[:5])
                + (f" (+{len(problems) - 5} more)" if len(problems) > 5 else "")
            )
    print(f"{counted} files compared, {failures} differ")
    return 1 if failures else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p_run = sub.add_parser("run")
    p_run.add_argument("out", type=Path)
    p_run.add_argument("--checkout", type=Path)
    p_run.add_argument("--only", nargs="*", default=[])
    p_cmp = sub.add_parser("compare")
    p_cmp.add_argument("before", type=Path)
    p_cmp.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.what == "run":
        run(args.out, args.checkout.resolve() if args.checkout else None, args.only)
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
