"""The wheel a user installs, checked by .ci/run in a fresh venv.

``contents WHEEL``: it carries the package data. ``run BORESIGHT EXAMPLES``: from a folder outside
the checkout, a scan-stats run (numba kernels compiled and cached) works for root and for a user
with no writable home, and writes nothing into the installed package. ``uninstalled``: after
``pip uninstall``, no boresight file or folder is left in site-packages.
"""

import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path


def contents(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    need = {"boresight/kernels/gpu.cu", "boresight/data/planck2015_spectra.npz", "boresight/cli.py"}
    assert need <= names, f"the wheel lacks {sorted(need - names)}"
    print(f"wheel: {len(names)} files, package data included")


def _package():
    return Path(sysconfig.get_paths()["purelib"]) / "boresight"


def run(boresight, examples):
    schedule = Path(examples) / "schedule_deep_sat.toml"
    work = Path(tempfile.mkdtemp(prefix="boresight-wheel-"))
    try:
        work.chmod(0o777)
        # two 2-minute CESs of the deep example, readable by every user
        text = schedule.read_text().replace("duration_s = 1500", "duration_s = 120")
        (work / "schedule.toml").write_text(text)
        (work / "schedule.toml").chmod(0o644)
        users = [("root", [])]
        runuser = shutil.which("runuser")
        if os.geteuid() == 0 and runuser:
            env = ["env", "-i", f"PATH={os.environ['PATH']}", "HOME=/nonexistent"]
            users.append(("nobody, no writable home", [runuser, "-u", "nobody", "--", *env]))
        else:
            print("wheel: not root or no runuser; the no-home user is not tried")
        for who, prefix in users:
            out = work / f"out-{len(prefix)}"
            cmd = [*prefix, boresight, "-q", "scan-stats", "schedule.toml", "--nside", "16"]
            proc = subprocess.run(
                [*cmd, "--out", str(out)], cwd=work, capture_output=True, text=True
            )
            assert proc.returncode == 0, f"{who}: exit {proc.returncode}\n{proc.stderr}"
            assert (out / "hn_maps.fits").is_file(), f"{who}: no hn_maps.fits"
            print(f"wheel: scan-stats from {work} as {who}: ok")
        left = sorted(str(p) for p in _package().rglob("*.nb[ic]"))
        assert left == [], f"numba wrote into the installed package: {left[:3]}"
    finally:
        shutil.rmtree(work)


def uninstalled():
    site = Path(sysconfig.get_paths()["purelib"])
    left = sorted(str(p) for p in site.iterdir() if p.name.lower().startswith("boresight"))
    assert left == [], f"pip uninstall left {left}"
    print(f"wheel: uninstalled, nothing of boresight left in {site}")


if __name__ == "__main__":
    {"contents": contents, "run": run, "uninstalled": uninstalled}[sys.argv[1]](*sys.argv[2:])
