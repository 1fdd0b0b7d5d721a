"""Figures: written as PNG and PDF, the residual's sign shown, and a notebook's matplotlib backend
left as it was (the command line alone asks for Agg)."""

import subprocess
import sys

import healpy as hp
import matplotlib.image
import numpy as np
from helpers import ROOT

from boresight.outputs import plots


def test_importing_the_plots_leaves_the_backend_alone():
    code = (
        "import matplotlib; matplotlib.use('svg'); import boresight.outputs.plots; "
        "print(matplotlib.get_backend())"
    )
    env = {"PATH": "", "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.strip() == "svg"


def test_a_spectrum_figure_is_a_png_and_a_pdf(tmp_path):
    bands = [
        dict(ell_lo=lo, ell_hi=lo + 9, residual_bb=(-1) ** i * 10.0**-i, predicted_bb=10.0**-i)
        for i, lo in enumerate(range(20, 120, 10))
    ]
    plots.spectrum_figure(bands, tmp_path / "residual")
    assert (tmp_path / "residual.pdf").read_bytes().startswith(b"%PDF")
    image = matplotlib.image.imread(tmp_path / "residual.png")
    assert image.shape[0] > 100 and image.std() > 0  # something is drawn


def test_a_map_figure_shows_one_panel_per_map(tmp_path):
    m = np.arange(12 * 8**2, dtype=float)
    m[:100] = hp.UNSEEN
    plots.map_figure([m, -m], ["a", "b"], tmp_path / "maps.png")
    one = tmp_path / "one.png"
    plots.map_figure([m], ["a"], one)
    two = matplotlib.image.imread(tmp_path / "maps.png")
    assert two.shape[1] == 2 * matplotlib.image.imread(one).shape[1]


def test_a_pairs_figure_draws_every_moment_against_the_radius(tmp_path):
    rows = [
        dict(
            pair=f"D{i}",
            radius_deg=2.0 * i,
            hits=100,
            **{f"abs_h{n}_sq": 0.1 * n + 0.01 * i for n in range(1, 5)},
        )
        for i in range(7)
    ]
    rows[0]["abs_h2_sq"] = 0.0  # a cancelled moment stays on the log axis
    plots.pairs_figure(rows, tmp_path / "pairs")
    image = matplotlib.image.imread(tmp_path / "pairs.png")
    assert image.shape[0] > 100 and image.std() > 0


def test_a_transfer_figure_draws_f_tt_where_the_matrix_has_the_t_block(tmp_path, monkeypatch):
    """The polarised matrix's four entries, and the 9x9 one's F^TT beside them, in each band."""
    from boresight.jobs.transfer import FIELD_PAIRS, FIELD_PAIRS_TEB, Transfer

    closed = []
    monkeypatch.setattr(plots.plt, "close", closed.append)  # keep each figure to read it
    for fields in (FIELD_PAIRS, FIELD_PAIRS_TEB):
        matrix = np.repeat(np.eye(len(fields))[:, :, None] * 0.5, 3, axis=2)
        transfer = Transfer(np.array([30, 40, 50, 65]), matrix, 0.1 * matrix, 2, fields)
        plots.transfer_figure(transfer, tmp_path / f"transfer{len(fields)}")
        assert (tmp_path / f"transfer{len(fields)}.png").is_file()
    polarised, full = (fig.axes[0].get_legend_handles_labels()[1] for fig in closed)
    assert polarised == ["F^EE", "F^BB", "E to B", "B to E"]
    assert full == ["F^TT", *polarised]
