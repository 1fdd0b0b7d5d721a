"""Designing the boresight-rotation schedule: the budget file (:mod:`~boresight.design.budget`),
the white-h_n objective (:mod:`~boresight.design.white`), the exact objective and its
search (:mod:`~boresight.design.exact`) and the same on a real focal plane
(:mod:`~boresight.design.focalplane`). The budget's and the white objective's names are
re-exported here."""

from .budget import (
    BUDGET_HWP_KEYS,
    BUDGET_SECTIONS,
    Budget,
    load_budget,
    search_instrument,
)
from .white import (
    KECK_DECKS,
    MAX_ANGLES,
    Design,
    DesignOptions,
    Objective,
    baselines,
    drawn,
    objective,
)

__all__ = [
    "KECK_DECKS",
    "DesignOptions",
    "MAX_ANGLES",
    "Objective",
    "objective",
    "drawn",
    "Design",
    "baselines",
    "Budget",
    "search_instrument",
    "BUDGET_SECTIONS",
    "BUDGET_HWP_KEYS",
    "load_budget",
]
