"""The instrument: its detector pairs and their systematics (:mod:`~boresight.instrument.pairs.pairs`),
where each pair sits on the focal plane (:mod:`~boresight.instrument.pairs.focalplane`), a half-wave
plate in front of them (:mod:`~boresight.instrument.pairs.hwp`) and their beams
(:mod:`~boresight.instrument.pairs.beams`). The pairs' names are re-exported here."""

from .pairs import (
    AMPLITUDES,
    BEAM_KEYS,
    LIMITS,
    MAX_ANGLE_DEG,
    MAX_ELLIPTICITY,
    PAPER_GAIN,
    PAPER_POINTING,
    PRESETS,
    REPEAT_LIMITS,
    RESPONSE_COLUMNS,
    UNITS,
    Instrument,
    PairParameters,
    Spread,
    Systematics,
    is_nonzero,
    response,
)

__all__ = [
    "MAX_ANGLE_DEG",
    "MAX_ELLIPTICITY",
    "LIMITS",
    "UNITS",
    "AMPLITUDES",
    "BEAM_KEYS",
    "REPEAT_LIMITS",
    "PRESETS",
    "Instrument",
    "Spread",
    "PairParameters",
    "is_nonzero",
    "Systematics",
    "RESPONSE_COLUMNS",
    "response",
    "PAPER_GAIN",
    "PAPER_POINTING",
]
