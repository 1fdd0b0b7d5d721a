"""A design's budget file: its ``[systematics]``, ``[noise]``, ``[design]``, ``[instrument]``,
``[hwp]``, ``[operations]``, ``[constraints]``, ``[deprojection]`` and ``[filter]`` tables, read
and checked.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from .. import predict
from ..config import ConfigError, check_systematics, read_toml, section_errors
from ..instrument.added import NOT_CARRIED, split_table
from ..instrument.focalplane import FocalPlane, focalplane_of_table
from ..instrument.hwp import HWP, pairs_behind
from ..instrument.pairs import AMPLITUDES, Instrument, Systematics, is_nonzero
from ..mitigation import Deprojection, Filtering
from ..noise import SurveyNoise
from ..validation import integer
from .constraints import AngleRule, Constraints
from .operations import OPERATIONS_KEYS, Operations
from .white import DesignOptions

if TYPE_CHECKING:
    from ..instrument.pairs import Systematics
    from ..noise import SurveyNoise


#: the sky realisations a filtering pipeline's objective averages by default
FILTER_SKIES = 4


@dataclass(frozen=True)
class Budget:
    """A design's inputs: the ``[systematics]``, ``[noise]`` and ``[design]`` tables.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
        The systematics over the focal plane: numbers, or {mean, rms} per parameter.
    noise : boresight.noise.SurveyNoise
    design : DesignOptions
    instrument : boresight.instrument.pairs.Instrument
        The pairs (the optional ``[instrument]`` table; default: the paper's Q/U pairs); with a
        focal plane, the on-axis pairs the search takes (:func:`search_instrument`).
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        ``[instrument] focalplane``: a file (beside the budget) or a preset name
        (:func:`boresight.instrument.focalplane.load_focalplane`).
    hwp : boresight.instrument.hwp.HWP, optional
        The ``[hwp]`` table (:class:`boresight.instrument.hwp.HWP`'s fields, ``mode`` "continuous" or
        "stepped"): a HWP in front of the pairs, its IP in the budget. A stepped plate's
        ``angles_deg`` are the steps the design may give each unit.
    operations : boresight.design.operations.Operations, optional
        The ``[operations]`` table: the observing time a change of angle or of the plate's
        direction costs, priced in the objective as the sigma(r) it loses.
    constraints : boresight.design.constraints.Constraints, optional
        The ``[constraints]`` table: ``[[constraints.angles]]`` rules (``elevation_deg = [lo,
        hi]``, ``angles_deg``, optional ``patch``) and ``max_changes_per_day``.
    deprojection : boresight.mitigation.Deprojection, optional
        The ``[deprojection]`` table (``templates``, a list of :data:`DESIGN_TEMPLATES`;
        ``block_hours``): the pipeline regresses those templates of T from each pair difference
        per block, so the objective leaves out the leaks of T they fit and the TOD check
        deprojects.
    filtering : boresight.mitigation.Filtering, optional
        The ``[filter]`` table (:data:`FILTER_KEYS`, as :class:`boresight.mitigation.Filtering`'s
        fields): the pipeline filters each pair difference before binning, so the objective is
        its filtered leak's (:mod:`boresight.design.filtered`) and the TOD check filters.
    filter_skies : int
        ``[filter] skies``: the sky realisations that objective averages.
    """

    systematics: Systematics
    noise: SurveyNoise
    design: DesignOptions
    instrument: Instrument = Instrument()
    focalplane: FocalPlane | None = None
    hwp: HWP | None = None
    operations: Operations | None = None
    constraints: Constraints | None = None
    deprojection: Deprojection | None = None
    filtering: Filtering | None = None
    filter_skies: int = FILTER_SKIES

    @property
    def deprojected(self) -> tuple:
        """The template sets the pipeline deprojects (none without ``[deprojection]``)."""
        return () if self.deprojection is None else self.deprojection.templates

    @property
    def pipeline(self) -> Filtering:
        """What the pipeline does to the pair differences before binning: the ``[filter]``'s
        filters, then the ``[deprojection]``'s templates (none: raw)."""
        filtering = Filtering() if self.filtering is None else self.filtering
        if self.deprojection is None:
            return filtering
        return replace(filtering, deprojection=self.deprojection)


def search_instrument(focal: FocalPlane) -> Instrument:
    """The pairs on the axis that the search's objective takes for a focal plane: the focal
    plane's pairs' angles where their 4 x angles cancel, else as many pairs at uniform angles
    (the exact expectation on the axis needs m_4 = 0); each strategy is then evaluated on the
    focal plane itself (:func:`boresight.predict.focalplane.expected_residual`)."""
    own = Instrument(pair_angles_deg=focal.pair_angles_deg)
    if predict.supports(own):
        return own
    return Instrument(pair_angles_deg="uniform", n_pairs=max(focal.n_pairs, 2))


BUDGET_SECTIONS = ("systematics", "noise", "design", "instrument")
#: the template sets a design's objective can leave out: the beams' leaks of T (width,
#: ellipticity) ride their filters beside their leaks of P, which it does not split yet
DESIGN_TEMPLATES = ("gain", "pointing")
#: the [filter] table's keys (:class:`boresight.mitigation.Filtering`'s filters)
FILTER_KEYS = ("poly_order", "ground_order", "ground_bin_deg", "ground_split", "skies")

#: the [hwp] table's keys (:class:`boresight.instrument.hwp.HWP`; its jitter and synchronous signal are not
#: in the design's objective)
BUDGET_HWP_KEYS = (
    "mode", "frequency_hz", "phase_deg", "angles_deg", "ip", "ip_phase_deg", "angle_offset_deg"
)  # fmt: skip


def load_budget(path: str) -> Budget:
    """Read a budget file; every problem is one :class:`boresight.config.ConfigError`.

    Parameters
    ----------
    path : str

    Returns
    -------
    Budget
    """

    raw = read_toml(path, "budget")
    extra = ("hwp", "operations", "constraints", "deprojection", "filter")
    unknown = sorted(set(raw) - set(BUDGET_SECTIONS) - set(extra))
    if unknown:
        raise ConfigError(
            f"budget {path}: unknown tables {unknown}; allowed: {BUDGET_SECTIONS + extra}"
        )
    plate = _budget_hwp(path, raw.get("hwp"))
    operations = _budget_operations(path, raw.get("operations"))
    constraints = _budget_constraints(path, raw.get("constraints"))
    deprojection = _budget_deprojection(path, raw.get("deprojection"))
    filtering, filter_skies = _budget_filter(path, raw.get("filter"))
    if "noise" not in raw:
        raise ConfigError(f"budget {path}: a [noise] table is required")
    tables, focal = {}, None
    classes = (Systematics, SurveyNoise, DesignOptions, Instrument)
    for name, cls in zip(BUDGET_SECTIONS, classes):
        table = raw.get(name, {})
        if not isinstance(table, dict):
            raise ConfigError(f"budget {path}: [{name}] must be a table")
        if name == "noise" and isinstance(table.get("nl_bb_file"), str):  # beside the budget
            table = {**table, "nl_bb_file": str(Path(path).parent / table["nl_bb_file"])}
        if name == "instrument" and isinstance(table.get("pair_angles_deg"), list):
            table = {**table, "pair_angles_deg": tuple(table["pair_angles_deg"])}
        if name == "systematics":
            added = split_table(table)[1]
            if added:
                raise ConfigError(
                    f"budget {path}: "
                    + NOT_CARRIED.format(keys=", ".join(added), where="the design")
                )
        if name == "instrument" and "focalplane" in table:
            try:
                focal = focalplane_of_table(table, Path(path).parent)
            except ConfigError as err:
                raise ConfigError(f"budget {path}: {err}") from None
            table = {}
        try:
            with section_errors(name, cls, table):  # built here: the design's own options too
                tables[name] = cls(**table)
        except ConfigError as err:
            raise ConfigError(f"budget {path}: {err}") from None
    if focal is not None:
        tables["instrument"] = search_instrument(focal)
    sysm, instrument = tables["systematics"], tables["instrument"]
    if plate is not None and (focal is not None or tables["design"].evaluation != "interp"):
        raise ConfigError(
            f"budget {path}: [hwp] designs pairs on the axis with the sky read by interpolation: "
            "not with [instrument] focalplane or design.evaluation = 'exact' yet"
        )
    if not (sysm.has_amplitude or (plate is not None and plate.ip)):
        raise ConfigError(
            f"budget {path}: [systematics] has no non-zero amplitude (chi_deg and the "
            "ellipticity angles only orient a pointing offset or a beam); give one of "
            f"{', '.join(AMPLITUDES)}"
        )
    if is_nonzero(sysm.dg_repeat):
        raise ConfigError(
            f"budget {path}: [systematics] dg_repeat is a gain drift between the rotation "
            "repeats of a synthetic scan; a schedule's repeats are CESs of their own, each with "
            "the angle the design gives it: remove dg_repeat"
        )
    try:
        check_systematics(sysm, instrument, (0.0,), tables["noise"].fwhm_arcmin)
        if not predict.supports(instrument):
            raise ValueError("its pairs' 4 x angles must cancel (m_4 = 0), e.g. 'uniform'")
        if plate is not None:
            pairs_behind(plate, sysm, instrument)
    except ValueError as err:
        raise ConfigError(f"budget {path}: [systematics] / [instrument]: {err}") from None
    if operations is not None and (focal is not None or plate is not None):
        raise ConfigError(
            f"budget {path}: [operations] prices the observing time of a design of pairs on the "
            "axis without a plate, not with [instrument] focalplane or [hwp] yet; leave out one "
            "of them"
        )
    if constraints is not None and focal is not None:
        raise ConfigError(
            f"budget {path}: [constraints] bind a design of pairs on the axis, not of a focal "
            "plane yet; leave out one of them"
        )
    if deprojection is not None:
        _check_deprojection(path, deprojection, tables["design"], focal, plate)
    if filtering is not None:
        _check_filter(path, deprojection, focal, plate, operations)
    return Budget(
        **tables,
        focalplane=focal,
        hwp=plate,
        operations=operations,
        constraints=constraints,
        deprojection=deprojection,
        filtering=filtering,
        filter_skies=filter_skies,
    )


def _budget_filter(path, table):
    """The budget's [filter] table as (a Filtering or None, its skies)."""
    if table is None:
        return None, FILTER_SKIES
    if not isinstance(table, dict):
        raise ConfigError(f"budget {path}: [filter] must be a table")
    unknown = sorted(set(table) - set(FILTER_KEYS))
    if unknown:
        raise ConfigError(f"budget {path}: unknown key filter.{unknown[0]}; allowed: {FILTER_KEYS}")
    table = dict(table)
    skies = table.pop("skies", FILTER_SKIES)
    try:
        integer("filter.skies", skies, 2, 1000)
        with section_errors("filter", Filtering, table):
            filtering = Filtering(**table)
    except (ConfigError, ValueError) as err:
        raise ConfigError(f"budget {path}: {err}") from None
    if not filtering.filters:
        raise ConfigError(
            f"budget {path}: [filter] filters nothing; give poly_order, ground_order or "
            "ground_bin_deg, or leave the table out"
        )
    return filtering, int(skies)


def _check_filter(path, deprojection, focal, plate, operations):
    """What a design of a filtering pipeline cannot take yet: its units are simulated apart, so a
    deprojection fits per CES."""
    if deprojection is not None and deprojection.block_hours is not None:
        raise ConfigError(
            f"budget {path}: [filter] with [deprojection] fits the templates per CES (the "
            "objective simulates each unit apart, and a block of hours spans units): leave out "
            "deprojection.block_hours"
        )
    other = [
        name
        for name, given in (
            ("[instrument] focalplane", focal),
            ("[hwp]", plate),
            ("[operations]", operations),
        )
        if given is not None
    ]
    if other:
        raise ConfigError(
            f"budget {path}: [filter] designs pairs on the axis without a plate, not with "
            f"{', '.join(other)} yet; leave out one of them"
        )


def _budget_deprojection(path, table):
    """The budget's [deprojection] table as a Deprojection, or None."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ConfigError(f"budget {path}: [deprojection] must be a table")
    allowed = ("templates", "block_hours")
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise ConfigError(
            f"budget {path}: unknown key deprojection.{unknown[0]}; allowed: {allowed}"
            + (" (a template map's error is not in the design's objective yet)"
               if "template_map" in unknown else "")
        )  # fmt: skip
    templates = table.get("templates")
    if not isinstance(templates, list) or not templates:
        raise ConfigError(
            f"budget {path}: deprojection.templates must be a list of template sets, e.g. "
            f"{list(DESIGN_TEMPLATES)}"
        )
    other = [t for t in templates if t not in DESIGN_TEMPLATES]
    if other:
        raise ConfigError(
            f"budget {path}: deprojection.templates {other}: the design leaves out the leaks of "
            f"{', '.join(DESIGN_TEMPLATES)}; the beams' templates (width, ellipticity) are not in "
            "its objective yet"
        )
    try:
        with section_errors("deprojection", Deprojection, table):
            return Deprojection(tuple(templates), block_hours=table.get("block_hours"))
    except ConfigError as err:
        raise ConfigError(f"budget {path}: {err}") from None


def _check_deprojection(path, deprojection, design, focal, plate):
    """What a design that deprojects cannot take yet, and what the TOD check needs."""
    if focal is not None or plate is not None:
        raise ConfigError(
            f"budget {path}: [deprojection] designs pairs on the axis without a plate, not with "
            "[instrument] focalplane or [hwp] yet; leave out one of them"
        )
    if deprojection.derivatives and design.evaluation != "exact":
        raise ConfigError(
            f"budget {path}: [deprojection] of {', '.join(deprojection.templates)} fits "
            "derivatives of T, which the TOD check follows only with design.evaluation = "
            "'exact'"
        )


def _budget_constraints(path, table):
    """The budget's [constraints] table as Constraints, or None."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ConfigError(f"budget {path}: [constraints] must be a table")
    unknown = sorted(set(table) - {"angles", "max_changes_per_day"})
    if unknown:
        raise ConfigError(
            f"budget {path}: unknown key constraints.{unknown[0]}; allowed: angles "
            "([[constraints.angles]] tables), max_changes_per_day"
        )
    rules = table.get("angles", [])
    if not isinstance(rules, list) or not all(isinstance(r, dict) for r in rules):
        raise ConfigError(
            f"budget {path}: constraints.angles must be [[constraints.angles]] tables"
        )
    out = []
    for i, rule in enumerate(rules, start=1):
        where = f"budget {path}: [[constraints.angles]] number {i}"
        bad = sorted(set(rule) - {"elevation_deg", "angles_deg", "patch"})
        missing = [k for k in ("elevation_deg", "angles_deg") if k not in rule]
        if bad or missing:
            raise ConfigError(f"{where}: unknown keys {bad}, missing keys {missing}")
        try:
            out.append(
                AngleRule(**{k: tuple(v) if isinstance(v, list) else v for k, v in rule.items()})
            )
        except (ValueError, TypeError) as err:
            raise ConfigError(f"{where}: {err}") from None
    try:
        return Constraints(tuple(out), table.get("max_changes_per_day"))
    except (ValueError, TypeError) as err:
        raise ConfigError(f"budget {path}: [constraints] {err}") from None


def _budget_operations(path, table):
    """The budget's [operations] table as Operations, or None."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ConfigError(f"budget {path}: [operations] must be a table")
    unknown = sorted(set(table) - set(OPERATIONS_KEYS))
    if unknown:
        raise ConfigError(
            f"budget {path}: unknown key operations.{unknown[0]}; allowed: {OPERATIONS_KEYS}"
        )
    try:
        return Operations(**table)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"budget {path}: [operations] {err}") from None


def _budget_hwp(path, table):
    """The budget's [hwp] table as a HWP, or None."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ConfigError(f"budget {path}: [hwp] must be a table")
    unknown = sorted(set(table) - set(BUDGET_HWP_KEYS))
    if unknown:
        raise ConfigError(
            f"budget {path}: unknown key hwp.{unknown[0]}; allowed: {BUDGET_HWP_KEYS}"
        )
    if table.get("mode") not in ("continuous", "stepped"):
        raise ConfigError(f"budget {path}: hwp.mode must be 'continuous' or 'stepped'")
    if isinstance(table.get("angles_deg"), list):
        table = {**table, "angles_deg": tuple(table["angles_deg"])}
    try:
        with section_errors("hwp", HWP, table):
            return HWP(**table)
    except ConfigError as err:
        raise ConfigError(f"budget {path}: {err}") from None
