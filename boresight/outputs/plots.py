"""Figures in the style of the paper: ``|residual|`` with the sign marked, analytic curve, reference
curves, log axes; and survey footprints over a Galactic-emission proxy."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import healpy as hp
import matplotlib.pyplot as plt
import matplotlib.ticker
import numpy as np

from .. import predict
from .._util import interrupts
from ..constants import ARCMIN
from ..jobs.suppression.axis import ANGLES, catalogue
from ..jobs.suppression.filtered import RAW as FILTER_RAW
from ..jobs.suppression.hwp import CASES as HWP_CASES
from ..spectra import bin_spectrum

if TYPE_CHECKING:
    import os

    from ..config import Study
    from ..cosmology import Spectra
    from ..design.white import Objective
    from ..jobs.paper import BandTable, ExperimentResult
    from ..noise import SurveyNoise


#: axis labels in Unicode, not mathtext (its parser costs a tenth of a figure's drawing time):
#: ``|Delta C~^BB(ell)|`` and ``[muK^2]``
RESIDUAL = "|\u0394C\u0303\u1d2e\u1d2e(\u2113)|"
MUK2 = "[\u03bcK\u00b2]"
ANGLE_COLOURS = {None: "tab:orange", 0: "tab:blue", 1: "tab:green", 2: "tab:red"}
REF_COLOURS = ("tab:purple", "tab:red", "tab:green")


def _signed_points(ax, ell, values, colour, label):
    """``|values|`` on log axes: filled markers for positive, open for negative."""
    pos = values > 0
    ax.plot(ell[pos], values[pos], "o", color=colour, label=label, ms=5)
    ax.plot(ell[~pos], -values[~pos], "o", mfc="none", color=colour, ms=5)


_SUPERSCRIPT = str.maketrans(
    "-0123456789", "\u207b\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079"
)


def _power_of_ten(value, _position=None):
    """Label of a log axis' decade tick as 10 with a Unicode superscript: matplotlib's default
    typesets each label with mathtext, about a third of a figure's drawing time."""
    exponent = int(np.round(np.log10(value)))
    return "10" + str(exponent).translate(_SUPERSCRIPT)


def _log_y(ax):
    """A log y axis labelled at its decades by :func:`_power_of_ten`."""
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(_power_of_ten))


def _residual_axes(ax):
    """Log axes labelled for ``|residual C_BB|`` against ell (linear in y, with a note, when the
    residual is zero everywhere: a study without a systematic)."""
    ax.set_xscale("log")
    if any((np.asarray(line.get_ydata()) > 0).any() for line in ax.get_lines()):
        _log_y(ax)
    else:
        ax.text(0.5, 0.5, "no residual (zero everywhere)", transform=ax.transAxes, ha="center")
    ax.set_xlabel("multipole \u2113")
    ax.set_ylabel(f"{RESIDUAL} {MUK2} (open: negative)")


def _save(fig, path_stem, formats=("png", "pdf"), dpi=120, tight=True):
    """Write a figure in each format and close it; Ctrl-C is acted on between the files."""
    try:
        if tight:
            fig.tight_layout()
        for ext in formats:
            interrupts.check()
            fig.savefig(f"{path_stem}.{ext}", dpi=dpi)
    finally:
        plt.close(fig)


def residual_figure(
    res: ExperimentResult,
    table: BandTable,
    study: Study,
    path_stem: str | os.PathLike,
    *,
    angles: list,
) -> None:
    """Residual pseudo-C_BB against ell at some rotation angles, as in the paper's figures.

    Parameters
    ----------
    res : boresight.jobs.paper.ExperimentResult
        Its unbinned prediction and reference curves.
    table : boresight.jobs.paper.BandTable
        Its bands.
    study : boresight.config.Study
    angles : list of float or None
    path_stem : pathlib.Path
        Writes .png and .pdf.
    """
    exp = res.experiment
    edges = study.output.edges()
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for value, colour in zip(exp.reference_values, REF_COLOURS):
        ell = np.arange(res.references[value].size)
        name = "r" if exp.reference == "r" else "A\u2097\u2091\u2099\u209b"  # A_lens
        ax.plot(ell[2:], res.references[value][2:], color=colour, lw=1, label=f"{name} = {value:g}")
    ell_pred = np.arange(res.predicted_cl[None].size)
    ax.plot(
        ell_pred[2:],
        np.abs(res.predicted_cl[None][2:]),
        "k--",
        lw=1.2,
        label="analytic (no rotation)",
    )
    for i, angle in enumerate(angles):
        centres, values = table.centres, table.values(angle, "residual_bb")
        label = "no rotation" if angle is None else f"rotation {angle:g}\u00b0"
        colour = ANGLE_COLOURS[None] if angle is None else ANGLE_COLOURS.get(i - 1, "tab:gray")
        _signed_points(ax, centres, values, colour, label)
    _residual_axes(ax)
    ax.set_xlim(edges[0], edges[-1])
    ticks = [t for t in (20, 50, 100, 200, 500, 1000, 2000, 4000) if edges[0] <= t <= edges[-1]]
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_title(f"{exp.name.replace('_', ', ')}: Nside {study.sky.nside}")
    ax.legend(fontsize=8, loc="lower left")
    _save(fig, path_stem)


def galactic_proxy(nside: int) -> np.ndarray:
    """A smooth Galactic-emission proxy: exp(-``|b|`` / 10 deg) + 0.01.

    Parameters
    ----------
    nside : int

    Returns
    -------
    numpy.ndarray, shape (npix,)
        Arbitrary units, equatorial RING.
    """
    theta, phi = hp.pix2ang(nside, np.arange(12 * nside**2))
    theta_g, _ = hp.Rotator(coord=["C", "G"])(theta, phi)
    return np.exp(-np.abs(90.0 - np.degrees(theta_g)) / 10.0) + 0.01


def footprint_figure(mask: np.ndarray, title: str, path_stem: str | os.PathLike) -> None:
    """Mollweide view (equatorial) of the Galactic proxy with a mask's footprint shaded.

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,)
    title : str
    path_stem : pathlib.Path
    """
    nside = hp.npix2nside(mask.size)
    proxy = np.log10(galactic_proxy(nside))
    shown = np.where(mask > 0, proxy.max() + 0.3, proxy)
    hp.mollview(
        shown,
        title=title,
        cmap="magma",
        cbar=True,
        min=proxy.min(),
        unit="log10 Galactic proxy (footprint in white)",
        max=proxy.max() + 0.3,
    )
    fig = plt.gcf()
    hp.graticule(dpar=30, dmer=60, alpha=0.4)  # logs its spacing at INFO to "healpy"
    _save(fig, path_stem, dpi=110, tight=False)


def map_figure(
    maps: list[np.ndarray], names: list[str], path: str | os.PathLike, unit: str = "\u03bcK"
) -> None:
    """Quick-look Mollweide panels of maps (UNSEEN shown grey).

    Parameters
    ----------
    maps : list of numpy.ndarray, shape (npix,)
    names : list of str
    path : pathlib.Path
    unit : str
        Colour-bar label.
    """
    width, dpi = 5, 100  # inches per panel, and the PNG's dots per inch
    fig = plt.figure(figsize=(width * len(maps), 3.2))
    with warnings.catch_warnings():  # healpy warns when it draws panels into an existing figure
        warnings.simplefilter("ignore", UserWarning)
        for i, (m, name) in enumerate(zip(maps, names)):
            hp.mollview(
                m,
                fig=fig.number,
                sub=(1, len(maps), i + 1),
                title=name,
                unit=unit,
                xsize=width * dpi,  # a panel's width in the PNG: a finer projection would not show
            )
    _save(fig, str(path).removesuffix(".png"), ("png",), dpi, tight=False)


def spectrum_figure(bands: list[dict], path_stem: str | os.PathLike) -> None:
    """``|residual C_BB|`` per band of a simulate run, sign marked, with the h_n prediction.

    Parameters
    ----------
    bands : list of dict
        bands.csv rows.
    path_stem : pathlib.Path
    """
    centres = _band_centres(bands)
    values = np.array([r["residual_bb"] for r in bands])
    predicted = np.array([r["predicted_bb"] for r in bands])
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    _signed_points(ax, centres, values, "tab:orange", "residual (band mean)")
    if np.isfinite(predicted).all():
        ax.plot(centres, np.abs(predicted), "k--", lw=1.2, label="h_n prediction")
    _residual_axes(ax)
    ax.legend(fontsize=8)
    _save(fig, path_stem)


#: the lowest <|h_n|^2> the pairs' figure draws: below it a moment has cancelled to rounding
PAIRS_FLOOR = 1e-6


def pairs_figure(rows: list[dict], path_stem: str | os.PathLike) -> None:
    """Each pair's hit-weighted ``<|h_n|^2>`` (n = 1..4) against its distance from the boresight:
    what a rotation leaves off the axis.

    Parameters
    ----------
    rows : list of dict
        pairs.csv rows (:meth:`boresight.moments.FocalPlaneStats.pair_means`).
    path_stem : pathlib.Path
    """
    radius = np.array([r["radius_deg"] for r in rows])
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for n, colour in zip(range(1, 5), ("tab:blue", "tab:orange", "tab:green", "tab:red")):
        values = np.array([r[f"abs_h{n}_sq"] for r in rows])
        low = values < PAIRS_FLOOR  # cancelled to rounding: drawn open, on the floor
        ax.plot(radius[~low], values[~low], "o", color=colour, ms=4, label=f"n = {n}")
        ax.plot(radius[low], np.full(low.sum(), PAIRS_FLOOR), "o", mfc="none", color=colour, ms=5)
    ax.set_yscale("log")
    ax.set_ylim(bottom=0.5 * PAIRS_FLOOR)
    ax.set_title(f"open: below {PAIRS_FLOOR:g} (cancelled)", fontsize=8)
    ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(_power_of_ten))
    ax.set_xlabel("distance from the boresight [deg]")
    ax.set_ylabel("hit-weighted <|h_n|\u00b2> of the pair")
    ax.legend(fontsize=8)
    _save(fig, path_stem, ("png",))


def _band_centres(rows):
    return np.array([0.5 * (r["ell_lo"] + r["ell_hi"]) for r in rows])


def compare_figure(rows: list[dict], systematic: str, path_stem: str | os.PathLike) -> None:
    """``|residual C_BB|`` of a real scan and its synthetic twin per band, sign marked.

    Parameters
    ----------
    rows : list of dict
        compare.csv rows.
    systematic : str
    path_stem : pathlib.Path
    """
    centres = _band_centres(rows)
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    colours = ("tab:orange", "tab:blue", "tab:red", "tab:green")
    names = [k for k in rows[0] if k.startswith("residual_")]
    for name, colour in zip(names, colours):
        values = np.array([r[name] for r in rows])
        _signed_points(ax, centres, values, colour, name[9:-3].replace("_", " "))
    _residual_axes(ax)
    ax.set_title(f"{systematic}: real schedule and its synthetic twin")
    ax.legend(fontsize=8)
    _save(fig, path_stem)


def continuum_figure(rows: list[dict], path_stem: str | os.PathLike) -> None:
    """Suppression and ``|delta r|`` against the rotation angle, with the h_n prediction.

    Skipped unless the sweep varies pbr_angle_deg with 0 among its values and the base has a
    systematic; seeds are pooled.

    Parameters
    ----------
    rows : list of dict
        The sweep's table.
    path_stem : str
    """
    if not rows or "pbr_angle_deg" not in rows[0]:
        return

    def band_sum(angle, col):
        return sum(r[col] for r in rows if r["pbr_angle_deg"] == angle)

    angles = sorted({r["pbr_angle_deg"] for r in rows})
    if 0 not in angles or band_sum(0, "residual_auto_bb") == 0 or band_sum(0, "predicted_bb") == 0:
        return  # nothing to normalise by: the base study has no systematic
    measured = [band_sum(a, "residual_auto_bb") / band_sum(0, "residual_auto_bb") for a in angles]
    closed = [band_sum(a, "predicted_bb") / band_sum(0, "predicted_bb") for a in angles]

    def first(angle, col):
        return next(r[col] for r in rows if r["pbr_angle_deg"] == angle)

    fig, (ax, ax_r) = plt.subplots(1, 2, figsize=(10, 4))
    ax.semilogy(angles, measured, "o", label="simulation (leaked power)")
    ax.semilogy(angles, closed, "k--", label="h_n prediction")
    ax.set_xlabel("boresight rotation angle [deg]")
    ax.set_ylabel("residual power / no rotation")
    ax.legend()
    ax_r.semilogy(angles, [abs(first(a, "delta_r")) for a in angles], "o", label="simulation")
    ax_r.semilogy(
        angles, [abs(first(a, "predicted_delta_r")) for a in angles], "k--", label="h_n prediction"
    )
    ax_r.set_xlabel("boresight rotation angle [deg]")
    ax_r.set_ylabel(f"|\u0394r| ({predict.R_RANGE[0]} \u2264 \u2113 \u2264 {predict.R_RANGE[1]})")
    ax_r.legend()
    _save(fig, path_stem, ("png",), dpi=110)


def design_figure(
    curves: dict,
    objective: Objective,
    noise: SurveyNoise,
    sigma_r: float,
    *,
    theory: Spectra,
    path_stem: str | os.PathLike,
    kept_bb: np.ndarray | None = None,
) -> None:
    """Predicted residual pseudo-C_BB of each rotation strategy beside the noise and r.

    Parameters
    ----------
    curves : dict of str -> numpy.ndarray
        Strategy name -> predicted residual pseudo-C_BB (lmax + 1,) [muK^2].
    objective : boresight.design.Objective
        Its coupling and the mask's Nside.
    noise : boresight.noise.SurveyNoise
    sigma_r : float
        The survey's sigma(r): its tensor spectrum is drawn.
    theory : boresight.cosmology.Spectra
    path_stem : pathlib.Path
    kept_bb : numpy.ndarray, shape (lmax + 1,), optional
        A filtering pipeline's F_ell^BB, by which its curves are corrected: the noise is drawn as
        N_ell / F_ell^BB.
    """

    coupling = objective.coupling
    nside = objective.moments.nside
    ell = np.arange(coupling.lmax + 1)
    keep = ell >= 10
    fsky = objective.moments.pixels.size / (12 * nside**2)
    fig, ax = plt.subplots(figsize=(7.0, 4.8))
    for i, (name, cl) in enumerate(curves.items()):
        style = dict(lw=2.5, color="black") if name == "optimised" else dict(lw=1, color=f"C{i}")
        ax.plot(ell[keep], np.abs(cl[keep]), label=name, **style)
    nl, label = None, None
    if noise.nl_bb_file is not None:  # the table's N_ell through the beam and the sky fraction
        beam = hp.gauss_beam(noise.fwhm_arcmin * ARCMIN, lmax=coupling.lmax)
        nl, label = fsky * noise.n_ell(coupling.lmax) * beam**2, "noise (nl_bb_file)"
    elif noise.has_spectrum:
        nl = np.full(ell.size, fsky * (noise.depth * ARCMIN) ** 2)
        label = f"noise ({noise.depth:.3g} \u03bcK\u2032)"
    if nl is not None:
        if kept_bb is not None:  # the filtered pipeline's yardstick
            nl, label = nl / kept_bb[: nl.size], label + " / F_BB"
        ax.plot(ell[keep], nl[keep], color="grey", ls=":", label=label)
    for r, ls in ((sigma_r, "--"), (10 * sigma_r, "-.")):
        ref = predict.reference_bb(coupling, theory, noise.fwhm_arcmin, nside, r=r)
        ax.plot(ell[keep], ref[keep], "k", ls=ls, lw=1, label=f"r = {r:.2g}")
    _residual_axes(ax)
    ax.set_ylabel(f"{RESIDUAL} predicted {MUK2}")
    ax.set_title("predicted residual B-modes of each rotation strategy")
    ax.legend(fontsize=7, ncol=2)
    _save(fig, path_stem)


def suppression_figure(result, nside: int, path_stem: str | os.PathLike) -> None:
    """The suppression map: one panel per systematic, the residual pseudo-C_BB of each rotation
    schedule simulated (solid) and predicted (dashed), against lensing and r = 0.01.

    Parameters
    ----------
    result : boresight.jobs.suppression.axis.Result
    nside : int
    path_stem : pathlib.Path
        Writes .png and .pdf.
    """

    ncol = 4
    entries = catalogue()
    nrow = -(-len(entries) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.8 * nrow), sharex=True, sharey=True)
    ell = np.arange(result.template.size)
    keep = ell >= 20
    for ax, entry in zip(axes.flat, entries):
        ax.plot(
            ell[keep],
            result.lensing[keep],
            color="0.6",
            lw=1,
            label="lensing A\u2097\u2091\u2099\u209b = 1",
        )
        ax.plot(ell[keep], 0.01 * result.template[keep], "k:", lw=1, label="r = 0.01")
        for i, angle in enumerate(ANGLES):
            colour = f"C{i}"
            label = "no rotation" if angle is None else f"0/{angle:g}\u00b0"
            sim = np.abs(result.simulated[entry.name, i])
            ax.plot(ell[keep], sim[keep], color=colour, lw=1, label=label)
            pred = result.predicted[entry.name, i]
            if pred is not None:
                ax.plot(ell[keep], np.abs(pred[keep]), "--", color=colour, lw=1)
        ax.set_title(f"{entry.name}: {entry.amplitude}", fontsize=9)
        if max(np.max(np.abs(result.simulated[entry.name, i])) for i in range(len(ANGLES))) < 1e-12:
            ax.text(0.5, 0.5, "below the axis at every ell", transform=ax.transAxes, ha="center")
        ax.set_xscale("log")
        _log_y(ax)
    for ax in axes.flat[len(entries) :]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    axes.flat[-1].legend(
        handles, labels + [], loc="center", fontsize=9, title="solid: simulated\ndashed: predicted"
    )
    for ax in axes[-1]:
        ax.set_xlabel("multipole \u2113")
    for ax in axes[:, 0]:
        ax.set_ylabel(f"{RESIDUAL} {MUK2}")
    ax0 = axes.flat[0]
    ax0.set_ylim(1e-12, None)
    fig.suptitle(f"Residual B-mode of each systematic under boresight rotation (Nside {nside})")
    _save(fig, path_stem)


def hwp_suppression_figure(
    result, path_stem: str | os.PathLike, *, formats: tuple = ("png", "pdf")
) -> None:
    """What boresight rotation still buys behind a HWP: one panel per systematic, its leaked
    pseudo-C_BB per boresight schedule behind the plate (solid) and without it (dashed), each
    smoothed over bins of 4 in ell; leaks cancelled to rounding stay below the axis.

    Parameters
    ----------
    result : boresight.jobs.suppression.hwp.Result
    path_stem : pathlib.Path
    formats : tuple of str
        The files written, by extension.
    """
    spectra = {key: cl for key, (cl, _) in result.spectra.items()}
    _leak_panels(
        spectra,
        result.edges,
        [case.name for case in HWP_CASES],
        (("plate", "-"), ("none", "--")),
        legend="boresight; dashed: no HWP",
        title="What boresight rotation still buys behind a half-wave plate",
        path_stem=path_stem,
        formats=formats,
    )


def filtered_suppression_figure(
    result, path_stem: str | os.PathLike, *, formats: tuple = ("png", "pdf")
) -> None:
    """What boresight rotation buys a filtering pipeline: one panel per systematic, its leaked
    pseudo-C_BB per boresight schedule from the filtered pair differences (solid) and from the
    raw ones (dashed), smoothed over bins of 4 in ell; leaks cancelled to rounding stay below the
    axis.

    Parameters
    ----------
    result : boresight.jobs.suppression.filtered.Result
    path_stem : pathlib.Path
    formats : tuple of str
        The files written, by extension.
    """
    pipelines = list(dict.fromkeys(key[1] for key in result.spectra))
    filtered = next(p for p in pipelines if p != FILTER_RAW)
    _leak_panels(
        result.spectra,
        result.edges,
        list(dict.fromkeys(key[0] for key in result.spectra)),
        ((filtered, "-"), (FILTER_RAW, "--")),
        legend=f"boresight; solid: {filtered}, dashed: raw",
        title=f"What boresight rotation buys a pipeline that cleans its TOD ({filtered})",
        path_stem=path_stem,
        formats=formats,
    )


def transfer_figure(transfer, path_stem: str | os.PathLike, *, formats: tuple = ("png", "pdf")):
    """A filter's transfer function per band: F^EE and F^BB (and F^TT where the matrix has the T
    block), and the filter's E-to-B and B-to-E shares, each with its realisations' spread.

    Parameters
    ----------
    transfer : boresight.jobs.transfer.Transfer
    path_stem : pathlib.Path
    formats : tuple of str
    """
    lo, hi = transfer.edges[:-1], transfer.edges[1:] - 1
    centres = 0.5 * (lo + hi)
    fig, ax = plt.subplots(figsize=(5.4, 3.6))
    entries = (("TT", "TT", "F^TT"),) if "TT" in transfer.fields else ()
    entries += (
        ("EE", "EE", "F^EE"),
        ("BB", "BB", "F^BB"),
        ("BB", "EE", "E to B"),
        ("EE", "BB", "B to E"),
    )
    middle = 0.5 * (len(entries) - 1)
    for k, (into, source, label) in enumerate(entries):
        shift = (k - middle) * 0.06 * (hi - lo)  # the entries side by side in each band
        ax.errorbar(
            centres + shift,
            transfer.entry(into, source),
            yerr=transfer.entry_error(into, source),
            xerr=None,
            fmt="o-" if into == source else "s--",
            color=f"C{k}",
            label=label,
            capsize=2,
        )
    ax.axhline(1.0, color="0.6", lw=0.8)
    ax.axhline(0.0, color="0.6", lw=0.8)
    ax.set_xlabel("multipole \u2113 (band centre)")
    ax.set_ylabel("transfer")
    ax.legend(
        fontsize=8, title=f"{transfer.n_sims} realisations; bars: their spread", title_fontsize=8
    )
    ax.set_title("The filter's polarised transfer function (SOOPERCOOL's estimator)", fontsize=9)
    _save(fig, path_stem, formats)


def _leak_panels(spectra, edges, names, styles, *, legend, title, path_stem, formats):
    """One panel per systematic: its leaked pseudo-C_BB per boresight schedule (a colour each) in
    each of two variants (a line style each), ``spectra`` keyed (name, variant, boresight label)."""
    labels = list(dict.fromkeys(key[2] for key in spectra))
    columns = 3 if len(names) > 4 else min(2, len(names))
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(
        rows, columns, figsize=(3.6 * columns + 2.4, 3.0 * rows), sharey=True, squeeze=False
    )  # 2.4 in beside the panels for the legend
    floor = 1e-16
    for ax in axes.flat[len(names) :]:
        ax.set_visible(False)
    for ax, name in zip(axes.flat, names):
        for i, label in enumerate(labels):
            for which, style in styles:
                key = (name, which, label)
                if key not in spectra:
                    continue
                cl = spectra[key]
                centres, binned = bin_spectrum(cl, np.arange(edges[0], cl.size + 1, 4))
                shown = ("0 (once)" if label == "0" else f"{label}\u00b0") if style == "-" else None
                width = 2.8 - 0.6 * i  # schedules that leak alike (0 and 0/180) stay visible
                ax.plot(
                    centres,
                    np.maximum(binned, floor / 10),
                    style,
                    color=f"C{i}",
                    lw=width,
                    label=shown,
                )
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("multipole \u2113")
        _log_y(ax)
        ax.set_ylim(floor, None)
    for ax in axes[:, 0]:
        ax.set_ylabel(f"leaked pseudo-C_BB {MUK2}")
    axes.flat[len(names) - 1].legend(  # beside the panels, where it covers no leak
        fontsize=8, title=legend, title_fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0)
    )
    fig.suptitle(f"{title}\n(a leak cancelled to rounding stays below the axis)", fontsize=10)
    _save(fig, path_stem, formats)
