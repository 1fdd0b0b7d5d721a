"""The one table of a pair's leak terms: which coefficient, which spin moment h_n it multiplies,
which sky field it reads and which systematics switch it on.

A pair difference's leak into the map-maker's Y (docs/conventions.md, "Polarisation-angle
errors, gain drift and jitter, focal planes (general pairs)") is

    Y = t2 h_2 T + s2 h_2 S + g1 h_1 G + g3 h_3 G* + p0 P + p4 h_4 P*,

with S the leak's template (T unless given), G the gradient of T and P = Q + i U. Every
consumer (the coefficients, the maps, the spectra, the exact expectation, the focal plane)
iterates :data:`TERMS` in the order it needs (:func:`ordered`), so the table is written once.
"""

from __future__ import annotations

from typing import NamedTuple

from ..instrument.added import REGISTRY


class Term(NamedTuple):
    """One leak term.

    Parameters
    ----------
    name : str
        The coefficient (:func:`boresight.predict.coefficients.pair_terms`).
    n : int
        The spin moment h_n it multiplies (h_0 = 1).
    field : str
        The sky field it reads, as :mod:`boresight.predict.expectation` names it.
    symbol : str
        The field in the docs' notation.
    switches : tuple of str
        The :class:`boresight.instrument.pairs.Systematics` keys that turn it on.
    templates : tuple of str
        The :class:`boresight.mitigation.Deprojection` template sets that fit it exactly when its
        coefficient is constant in a block (a leak of T; none for a leak of P).
    """

    name: str
    n: int
    field: str
    symbol: str
    switches: tuple
    templates: tuple = ()


#: the terms, in the order of Y
TERMS = (
    Term("t2", 2, "temperature", "T", ("dg", "dg_repeat"), ("gain",)),
    Term("s2", 2, "template", "S", ("leak",), ("gain",)),  # where the template is T
    Term("g1", 1, "gradient", "G", ("rho_arcmin",), ("pointing",)),
    Term("g3", 3, "conjugate gradient", "G*", ("rho_arcmin",), ("pointing",)),
    Term("p0", 0, "polarisation", "P", ("dg", "dg_repeat", "pol_angle_deg", "nonortho_deg")),
    Term(
        "p4",
        4,
        "conjugate polarisation",
        "P*",
        ("dg", "dg_repeat", "pol_angle_deg", "nonortho_deg"),
    ),
)
#: each term by its coefficient's name
BY_NAME = {term.name: term for term in TERMS}
#: the order of the coefficients' moments (:func:`boresight.predict.coefficients.coefficient_moments`)
MOMENT_ORDER = ("t2", "s2", "g1", "g3", "p4", "p0")


def ordered(names) -> tuple[Term, ...]:
    """The terms of ``names``, in that order."""
    return tuple(BY_NAME[name] for name in names)


def deprojected_by(templates) -> frozenset:
    """The names of the terms that deprojecting ``templates`` (template set names, e.g.
    ``("gain", "pointing")``) takes out: a leak of T whose coefficient is constant in a block
    goes whatever the h_n (what a template's error leaves is
    :mod:`boresight.predict.template_error`'s)."""
    return frozenset(term.name for term in TERMS if set(term.templates) & set(templates))


def switched_on_by(key: str) -> tuple[Term, ...]:
    """The terms a systematic's key turns on, in the order of Y."""
    return tuple(term for term in TERMS if key in term.switches)


def couples_through(key: str) -> str:
    """The moments and fields a systematic's key leaks through, as the docs write them:
    "h_2 T, h_0 P, h_4 P*" for ``dg``; an added systematic's own term
    (:mod:`boresight.instrument.added`)."""
    if key in REGISTRY:
        return f"h_{REGISTRY[key].n} {REGISTRY[key].symbol}"
    return ", ".join(f"h_{term.n} {term.symbol}" for term in switched_on_by(key))
