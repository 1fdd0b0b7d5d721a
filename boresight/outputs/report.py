"""The paper's claims (SPEC section 3) checked against a study's numbers, and report.md.

Each claim is a band statistic of the measured spectra compared with what the paper states. The
paper reads its numbers off log plots spanning eight decades, so "about" means within the factor
stated next to each claim. Every verdict is computed here, none is written by hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..jobs.paper import band_table

if TYPE_CHECKING:
    from ..config import Study
    from ..jobs.paper import BandTable, ExperimentResult


@dataclass(frozen=True)
class Claim:
    """One claim of the paper and its computed verdict.

    Parameters
    ----------
    experiment : str
    statement : str
        What the paper says.
    test : str
        The statistic and the range it must fall in.
    measured : str
        The statistic measured here.
    reproduced : bool
    """

    experiment: str
    statement: str  #: what the paper says
    test: str  #: the statistic and the range it must fall in
    measured: str
    reproduced: bool


def _median(values):
    """The median of a band statistic, NaN (a claim not reproduced) where a resolution too low
    for the claim leaves its multipole range empty."""
    values = np.asarray(values)
    return float(np.median(values)) if values.size else float("nan")


def _column(part):
    return {"total": "residual_bb", "auto": "residual_auto_bb"}[part]


def _reduction(table, angle, lo=0, hi=np.inf, part="total"):
    base = table.values(None, _column(part), lo, hi)
    return np.abs(base / table.values(angle, _column(part), lo, hi))


def _ratio_to_reference(table, angle, value, lo=0, hi=np.inf):
    return table.values(angle, "residual_bb", lo, hi) / table.reference(value, lo, hi)


def _claim(res, statement, test, value, ok, fmt="{:.3g}"):
    return Claim(res.experiment.name, statement, test, fmt.format(value), bool(ok))


def pointing_claims(res: ExperimentResult, table: BandTable) -> list[Claim]:
    """The wide survey's pointing claims.

    Parameters
    ----------
    res : boresight.jobs.paper.ExperimentResult
    table : boresight.jobs.paper.BandTable

    Returns
    -------
    list of Claim
    """
    med = _median
    out = []
    a1 = med(_ratio_to_reference(table, None, 1.0, lo=40))
    out.append(
        _claim(
            res,
            "Without rotation the residual is of the order of the lensing B-mode (A_lens = 1).",
            "median over bands (ell >= 40) of residual / C_BB(A_lens=1) in [1/3, 3]",
            a1,
            1 / 3 <= a1 <= 3,
        )
    )
    r180 = med(_reduction(table, 180.0))
    out.append(
        _claim(
            res,
            "180 deg rotation reduces it by about three orders of magnitude.",
            "log10 of the median |reduction| over bands in [2, 4]",
            np.log10(r180),
            2 <= np.log10(r180) <= 4,
        )
    )
    lvl = med(np.abs(_ratio_to_reference(table, 180.0, 1.0)))
    out.append(
        _claim(
            res,
            "...to about the level of A_lens = 0.001.",
            "median |residual_180| / C_BB(A_lens=1) in [1e-4, 1e-2]",
            lvl,
            1e-4 <= lvl <= 1e-2,
        )
    )
    before = table.values(None, "residual_auto_bb")
    leaking = before >= 1e-2 * before.max()  # bands with a leak to speak of, not beyond the beam
    leak = np.max(table.values(180.0, "residual_auto_bb")[leaking] / before[leaking])
    neg = np.mean(table.values(180.0, "residual_bb") < 0)
    out.append(
        _claim(
            res,
            "The 180 deg residual is scattered about zero (no leakage survives).",
            "leaked power <dB,dB> after 180 deg / before, worst band where the unrotated "
            "leak is >= 1 % of its peak, < 1e-2 (the rest is the zero-mean cross term; "
            f"{neg:.0%} of bands negative)",
            leak,
            leak < 1e-2,
        )
    )
    r179 = med(_reduction(table, 179.0))
    out.append(
        _claim(
            res,
            "179 deg still gives a large reduction.",
            "median |reduction| over bands >= 30",
            r179,
            r179 >= 30,
        )
    )
    r160 = med(_reduction(table, 160.0))
    out.append(
        _claim(
            res,
            "160 deg gives about one order of magnitude.",
            "median |reduction| over bands in [3, 30]",
            r160,
            3 <= r160 <= 30,
        )
    )
    return out


def gain_claims(res: ExperimentResult, table: BandTable) -> list[Claim]:
    """The deep survey's gain claims; parameters and return value as :func:`pointing_claims`."""
    med = _median
    out = []
    r_eq = med(_ratio_to_reference(table, None, 0.1, lo=30, hi=150)) * 0.1
    out.append(
        _claim(
            res,
            "Without rotation the residual lies between r = 0.1 and r = 1.",
            "median over 30 <= ell <= 150 of the equivalent r (residual / C_BB(r=1)) in "
            "[0.1/3, 1*3]",
            r_eq,
            0.1 / 3 <= r_eq <= 3,
        )
    )
    large = med(_reduction(table, 90.0, hi=60))
    small = med(_reduction(table, 90.0, lo=100))
    out.append(
        _claim(
            res,
            "90 deg rotation reduces it by more than two orders on the largest scales...",
            "median |reduction| over ell <= 60 >= 100",
            large,
            large >= 100,
        )
    )
    out.append(
        _claim(
            res,
            "...and by one to two orders or more on smaller scales.",
            "median |reduction| over ell >= 100 >= 10",
            small,
            small >= 10,
        )
    )
    auto = table.values(90.0, "residual_auto_bb")
    pred = table.values(90.0, "predicted_bb")
    floor = med(auto / pred)
    out.append(
        _claim(
            res,
            "The 90 deg residual is not centred on zero: E-to-B leakage from the "
            "gain error itself remains.",
            "leaked power <dB,dB> after 90 deg is > 0 in "
            "every band and its median ratio to the predicted h_4 E-to-B term is in "
            "[0.5, 2]",
            floor,
            np.all(auto > 0) and 0.5 <= floor <= 2,
        )
    )
    r89, r90 = med(_reduction(table, 89.0)), med(_reduction(table, 90.0))
    out.append(
        _claim(
            res,
            "89 deg is about as good as 90 deg (saturated).",
            "median |reduction| at 89 deg >= 100 and >= 1/10 of that at 90 deg",
            r89 / r90,
            r89 >= 100 and r89 >= 0.1 * r90,
        )
    )
    r70 = med(_reduction(table, 70.0))
    out.append(
        _claim(
            res,
            "70 deg gives about one order of magnitude.",
            "median |reduction| over bands in [3, 30]",
            r70,
            3 <= r70 <= 30,
        )
    )
    return out


def common_claims(res: ExperimentResult, table: BandTable, study: Study) -> list[Claim]:
    """The claims both experiments make: Q = U = 0, the prediction, the continuum in angle.

    Parameters
    ----------
    res : boresight.jobs.paper.ExperimentResult
    table : boresight.jobs.paper.BandTable
    study : boresight.config.Study

    Returns
    -------
    list of Claim
    """
    exp = res.experiment
    med = _median
    out = []
    floor = 1e-20 if exp.name == "gain_deep" else 1e-2
    z = np.max(np.abs(res.zero_qu[exp.ideal_deg][2:])) / np.max(np.abs(res.zero_qu[None][2:]))
    out.append(
        _claim(
            res,
            f"With Q = U = 0 the {exp.ideal_deg:g} deg residual is negligible.",
            f"max |residual| with rotation / without < {floor:g} (gain cancels exactly; "
            "pointing leaves a second-order term)",
            z,
            z < floor,
        )
    )
    lo, hi = 40, study.sky.nside / 2
    total, auto = (table.values(None, c, lo, hi) for c in ("residual_bb", "residual_auto_bb"))
    pmap, pcl = (table.values(None, c, lo, hi) for c in ("predicted_map_bb", "predicted_bb"))
    dev_map = med(np.abs(pmap / total - 1))
    dev_cl = med(np.abs(pcl / auto - 1))
    out.append(
        _claim(
            res,
            "The analytic prediction matches the simulation without rotation in "
            "shape and amplitude.",
            f"median |prediction / simulation - 1| over {lo} <= "
            f"ell <= {hi:g}: map level < 0.1, C_ell level (vs leaked power) < 0.15",
            max(dev_map, dev_cl),
            dev_map < 0.1 and dev_cl < 0.15,
        )
    )
    angles = sorted(exp.angles_deg, key=lambda a: abs(a - exp.ideal_deg), reverse=True)
    reds = [med(_reduction(table, a, part="auto")) for a in angles]
    out.append(
        _claim(
            res,
            "The reduction is a continuum in the rotation angle.",
            "median leaked-power reduction grows as the angle approaches "
            f"{exp.ideal_deg:g} deg ({', '.join(f'{a:g}' for a in angles)})",
            reds[-1] / reds[0],
            all(b > a for a, b in zip(reds, reds[1:])),
        )
    )
    return out


def evaluate_claims(results: dict, rows: list[dict], study: Study) -> list[Claim]:
    """All claims of the experiments present, read from their results.csv rows (binned once).

    Parameters
    ----------
    results : dict
    rows : list of dict
    study : boresight.config.Study

    Returns
    -------
    list of Claim
    """

    claims = []
    for name, res in results.items():
        table = band_table(res, rows, study)
        claims += (
            pointing_claims(res, table) if name == "pointing_wide" else gain_claims(res, table)
        )
        claims += common_claims(res, table, study)
    return claims


def report_markdown(claims: list[Claim], study: Study, stages: dict) -> str:
    """report.md: each claim, the number measured here and the computed verdict.

    Parameters
    ----------
    claims : list of Claim
    study : boresight.config.Study
    stages : dict

    Returns
    -------
    str
    """
    lines = [
        "# boresight: reproduction of [Thomas, McCallum & Brown (2020)](https://arxiv.org/abs/1905.12647)",
        "",
        f"Nside {study.sky.nside}, lmax {study.sky.lmax}, beam {study.sky.fwhm_arcmin:g} arcmin, "
        f"seed {study.sky.seed}, evaluation `{study.run.evaluation}`, band edges "
        f"{[int(e) for e in study.output.edges()]}.",
        "",
        f"**{sum(c.reproduced for c in claims)} of {len(claims)} claims reproduced.**",
        "",
        "| experiment | the paper says | test | measured | verdict |",
        "|---|---|---|---|---|",
    ]
    for c in claims:
        verdict = "reproduced" if c.reproduced else "not reproduced"
        lines.append(f"| {c.experiment} | {c.statement} | {c.test} | {c.measured} | {verdict} |")
    lines += [
        "",
        "Residuals are C_BB(with systematic) - C_BB(same sky, same scan, no systematic) of "
        "the masked maps; 'reduction' is the unrotated residual divided by the rotated one "
        "in the same band; 'leaked power' is <dB, dB>, the part of the residual that leakage "
        "adds on average (the cross term 2 Re<B, dB> has zero mean).",
        "",
        f"Total wall time {sum(stages.values()):.1f} s; stages in manifest.json.",
    ]
    return "\n".join(lines) + "\n"
