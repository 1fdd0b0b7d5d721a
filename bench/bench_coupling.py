"""Coupling time: what a prediction pays (the mask's spectrum to 2 lmax, then one pseudo-C_BB in
real space), the spin-2 matrices and TT (ducc0, as NaMaster's two workspaces), and NaMaster on the
same mask and lmax.

NaMaster runs only where pymaster is importable (it ships no wheels). Usage:
python bench/bench_coupling.py [NSIDE LMAX ...pairs]
"""

import sys
import time

import numpy as np
from _table import report

from boresight import coupling, masks


def main(pairs):
    try:
        import pymaster as nmt
    except ImportError:
        nmt = None
    rows = []
    for nside, lmax in pairs:
        mask = masks.survey_mask("wide", nside)
        t_ours = [time.perf_counter()]
        mixing = coupling.mask_coupling(mask, lmax)
        t_ours.append(time.perf_counter())
        mixing.pseudo_bb(np.ones(lmax + 1), np.ones(lmax + 1))
        t_ours.append(time.perf_counter())
        mixing.even  # noqa: B018 (a lazy property: its first read builds it)
        t_ours.append(time.perf_counter())
        mixing.tt  # noqa: B018
        t_ours.append(time.perf_counter())
        t_ours = np.diff(t_ours)
        t_nmt = float("nan")
        if nmt is not None:
            t0 = time.perf_counter()
            b = nmt.NmtBin.from_lmax_linear(lmax, 1)
            f0 = nmt.NmtField(mask, None, spin=0, lmax=lmax)
            f2 = nmt.NmtField(mask, None, spin=2, lmax=lmax)
            nmt.NmtWorkspace.from_fields(f0, f0, b)
            nmt.NmtWorkspace.from_fields(f2, f2, b)
            t_nmt = time.perf_counter() - t0
        rows.append(
            dict(
                nside=nside,
                lmax=lmax,
                mask_spectrum_s=t_ours[0],
                pseudo_bb_s=t_ours[1],
                spin2_matrices_s=t_ours[2],
                tt_matrix_s=t_ours[3],
                namaster_s=None if nmt is None else t_nmt,
            )
        )
    report(
        "coupling",
        "Mask coupling on the wide mask: boresight's (ducc0) stages against NaMaster's workspaces",
        list(rows[0]),
        rows,
        "" if nmt is not None else "pymaster not installed: no NaMaster column",
    )


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    main(list(zip(args[::2], args[1::2])) or [(256, 767), (512, 1535), (1024, 3071)])
