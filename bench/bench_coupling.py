"""Coupling-matrix time: boresight (ducc0; spin 2, what predictions use, and with TT as
NaMaster's two workspaces) against NaMaster on the same mask and lmax.

NaMaster runs only where pymaster is importable (it ships no wheels). Usage:
python bench/bench_coupling.py [NSIDE LMAX ...pairs]
"""

import sys
import time

from boresight import coupling, masks


def main(pairs):
    try:
        import pymaster as nmt
    except ImportError:
        nmt = None
    print(f"{'Nside':>6} {'lmax':>5} {'boresight s':>12} {'with TT s':>10} {'NaMaster s':>11}")
    for nside, lmax in pairs:
        mask = masks.survey_mask("wide", nside)
        t_ours = []
        for tt in (False, True):
            t0 = time.perf_counter()
            coupling.coupling_matrices(mask, lmax, tt=tt)
            t_ours.append(time.perf_counter() - t0)
        t_nmt = float("nan")
        if nmt is not None:
            t0 = time.perf_counter()
            b = nmt.NmtBin.from_lmax_linear(lmax, 1)
            f0 = nmt.NmtField(mask, None, spin=0, lmax=lmax)
            f2 = nmt.NmtField(mask, None, spin=2, lmax=lmax)
            nmt.NmtWorkspace.from_fields(f0, f0, b)
            nmt.NmtWorkspace.from_fields(f2, f2, b)
            t_nmt = time.perf_counter() - t0
        row = f"{nside:>6} {lmax:>5} {t_ours[0]:>12.2f} {t_ours[1]:>10.2f} {t_nmt:>11.2f}"
        print(row, flush=True)
    if nmt is None:
        print("(pymaster not installed: NaMaster column is nan)")


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    main(list(zip(args[::2], args[1::2])) or [(256, 767), (512, 1535), (1024, 3071)])
