"""h_n, the paper's central object, and its relatives, from any scan's samples: hits, h_n and
crossing angles of the boresight (:mod:`~boresight.moments.axis`), moments weighted by the
samples' offsets from their pixel's centre (:mod:`~boresight.moments.offsets`), every pair of a
focal plane (:mod:`~boresight.moments.focalplane`), each unit of a design's schedule
(:mod:`~boresight.moments.units`) and h_{n,m} behind a half-wave plate
(:mod:`~boresight.moments.hwp`). Every public name is re-exported here."""

from ..constants import N_MAX
from .axis import (
    Moments,
    ScanStats,
    ces_hits,
    ces_hits_pairs,
    characterise,
    characterise_schedule,
    compute_moments,
)
from .focalplane import (
    PAIR_BLOCK_BYTES,
    FocalPlaneStats,
    characterise_focalplane,
    observed_pixels,
    pair_blocks,
)
from .hwp import (
    BEAM_BEHIND_TERMS,
    BEAM_N_MAX,
    HWP_TERMS,
    IP_BEHIND_TERMS,
    IP_TERMS,
    JITTER_TERMS,
    OFFSET_WEIGHTS,
    OFFSETS,
    PLATE_TERMS,
    POINTING_BEHIND_TERMS,
    SYNCHRONOUS_TERMS,
    T_BEHIND_TERMS,
    PlateMoments,
    beams_behind,
    hwp_moments,
    plate_moments,
    pointing_behind,
    synchronous_weights,
)
from .offsets import (
    centroid_moments,
    sample_offsets,
)
from .units import (
    GROUPS,
    UnitMoments,
    UnitSums,
    allowed_index,
    unit_moments,
    unit_sums,
    units_of,
)

__all__ = [
    "N_MAX",
    "ces_hits",
    "ces_hits_pairs",
    "ScanStats",
    "characterise",
    "characterise_schedule",
    "Moments",
    "compute_moments",
    "sample_offsets",
    "centroid_moments",
    "HWP_TERMS",
    "hwp_moments",
    "OFFSETS",
    "T_BEHIND_TERMS",
    "IP_BEHIND_TERMS",
    "POINTING_BEHIND_TERMS",
    "pointing_behind",
    "OFFSET_WEIGHTS",
    "BEAM_N_MAX",
    "BEAM_BEHIND_TERMS",
    "beams_behind",
    "IP_TERMS",
    "SYNCHRONOUS_TERMS",
    "JITTER_TERMS",
    "PLATE_TERMS",
    "synchronous_weights",
    "PlateMoments",
    "plate_moments",
    "FocalPlaneStats",
    "PAIR_BLOCK_BYTES",
    "pair_blocks",
    "observed_pixels",
    "characterise_focalplane",
    "GROUPS",
    "units_of",
    "UnitMoments",
    "unit_moments",
    "UnitSums",
    "unit_sums",
    "allowed_index",
]
