"""What every benchmark shares: print its table and write it, with the machine, the date and the
versions, as ``bench/results/<name>.json``, which the docs' performance page is built from."""

from __future__ import annotations

import datetime
import json
import os
import platform
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """The machine a benchmark ran on: CPU model, cores this process may use, memory."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**30
    return {"cpu": cpu, "cores": cores, "memory_gib": round(memory, 1), "os": platform.platform()}


def versions() -> dict:
    import ducc0
    import healpy
    import numba
    import numpy

    import boresight

    return {
        "boresight": boresight.__version__,
        "numpy": numpy.__version__,
        "numba": numba.__version__,
        "healpy": healpy.__version__,
        "ducc0": ducc0.__version__,
        "python": platform.python_version(),
    }


def report(name: str, title: str, columns: list[str], rows: list[dict], notes: str = "") -> Path:
    """Print a table and write it as ``bench/results/{name}.json``.

    Parameters
    ----------
    name : str
        The file's stem, usually the script's (``memory`` for bench_memory.py).
    title : str
        One line saying what was measured.
    columns : list of str
        The rows' keys, in order.
    rows : list of dict
    notes : str
        What a reader should know to read the numbers.

    Returns
    -------
    pathlib.Path
        The JSON written.
    """
    widths = [max(len(c), *(len(_cell(r.get(c))) for r in rows)) for c in columns]
    print(title)
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths)))
    for r in rows:
        print("  ".join(_cell(r.get(c)).ljust(w) for c, w in zip(columns, widths)))
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.json"
    data = {
        "title": title,
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "versions": versions(),
        "columns": columns,
        "rows": rows,
        "notes": notes,
    }
    path.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {path}")
    return path


def _cell(value):
    if isinstance(value, float):
        return f"{value:.3g}"
    return "" if value is None else str(value)


def print_verdict(heading: str, lines: list[str]) -> None:
    """Print a bench's verdict: a heading and one indented line per case."""
    print(heading)
    for line in lines:
        print("  " + line)
