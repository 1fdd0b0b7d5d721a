"""Regenerate boresight/data/planck2015_spectra.npz with CAMB (needs `pip install camb`)."""

import sys
from pathlib import Path

from boresight.cosmology import CACHE_FILE, compute_spectra, save_spectra

lmax = int(sys.argv[1]) if len(sys.argv) > 1 else 8000
out = Path(__file__).resolve().parents[1] / "boresight" / "data" / CACHE_FILE
save_spectra(compute_spectra(lmax=lmax), out)
print(f"wrote {out} (lmax={lmax})")
