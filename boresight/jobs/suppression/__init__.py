"""What boresight rotation buys: the table of each systematic's leak against the rotation angles on
the paper's pairs on the axis (:mod:`~boresight.jobs.suppression.axis`, re-exported here), and
what rotation still buys behind a half-wave plate, on a real schedule and focal plane
(:mod:`~boresight.jobs.suppression.hwp`)."""

from .axis import (
    ANGLES,
    CANCELS,
    CATALOGUE,
    MIN_NSIDE,
    Entry,
    Result,
    bands,
    catalogue,
    estimate,
    log,
    markdown,
    run,
    table,
)

__all__ = [
    "log",
    "Entry",
    "CATALOGUE",
    "catalogue",
    "ANGLES",
    "MIN_NSIDE",
    "bands",
    "Result",
    "estimate",
    "run",
    "table",
    "markdown",
    "CANCELS",
]
