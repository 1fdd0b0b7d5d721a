"""A design's budget file: its tables read and checked, one clear error for each bad one."""

import pytest
from helpers import budget_file

from boresight import design, predict
from boresight.config import ConfigError


@pytest.mark.parametrize(
    "tables, message",
    [
        (
            dict(
                noise="net_uk_sqrt_s = -300.0\nn_detectors = 10\nyears = 1.0\nfsky = 0.1\n"
                "fwhm_arcmin = 30.0"
            ),
            "net_uk_sqrt_s",
        ),  # fmt: skip
        (dict(systematics="ellipticity = 0.01"), "ellipticity"),
        (dict(design="angles_deg = []"), "angles_deg"),
        (dict(design="group = 'week'"), "group"),
        (dict(design="evaluation = 'nearest'"), "evaluation"),
        (dict(noise=None), "noise"),
        (dict(systematics="dg = 0.0"), "no non-zero"),
        (dict(systematics="ellipticity_b = 0.99"), "ellipticity_b"),
        (dict(systematics="dfwhm_b_arcmin = -40.0"), "FWHM"),
        (
            dict(systematics="dg = {mean = 0.0, rms = 0.01}", instrument="pair_angles_deg = [0.0]"),
            "m_4",
        ),  # fmt: skip
        (
            dict(systematics="dg = 0.01", instrument="pair_angles_deg = 'hexagonal'\nn_pairs = 6"),
            "preset",
        ),  # fmt: skip
        (dict(hwp="mode = 'spinning'"), "hwp.mode"),
        (dict(systematics="dg = 0.01", hwp="mode = 'stepped'\nangles_deg = []"), "angles"),
        (
            dict(systematics="dg = 0.01", hwp="mode = 'continuous'\nfrequency_hz = -2.0"),
            "frequency",
        ),
        (dict(hwp="mode = 'stepped'"), "rho_arcmin behind a HWP"),
        (dict(systematics="dg = 0.01", hwp="mode = 'stepped'\nangle_jitter_deg = 0.1"), "jitter"),
        (
            dict(systematics="dg = 0.01", design="evaluation = 'exact'", hwp="mode = 'stepped'"),
            "not with",
        ),  # fmt: skip
        (dict(systematics="dg = 0.0", hwp="mode = 'stepped'"), "no non-zero"),
        (dict(deprojection="templates = 'gain'"), "must be a list"),
        (dict(deprojection="templates = ['width']"), "not in its objective yet"),
        (dict(deprojection="templates = ['gain']\ntemplate_map = 't.fits'"), "template map"),
        (dict(deprojection="templates = ['gain']\nblock_hours = -1.0"), "block_hours"),
        (dict(deprojection="templates = ['pointing']"), "evaluation = 'exact'"),
        (
            dict(
                systematics="dg = 0.01", deprojection="templates = ['gain']", hwp="mode = 'stepped'"
            ),
            "without a plate",
        ),  # fmt: skip
        (dict(filter="poly_order = -1"), "poly_order"),
        (dict(filter="order = 3"), "filter.order"),
        (dict(filter="poly_order = 3\nskies = 1"), "skies"),
        (dict(filter="ground_split = true"), "ground template"),
        (dict(filter="skies = 8"), "filters nothing"),
        (
            dict(filter="poly_order = 3", deprojection="templates = ['gain']\nblock_hours = 2.0"),
            "block_hours",
        ),  # fmt: skip
        (dict(systematics="dg = 0.01", filter="poly_order = 3", hwp="mode = 'stepped'"), "[hwp]"),
        (dict(filter="poly_order = 3", operations="preset = 'so-sat'"), "[operations]"),
        (dict(filter="poly_order = 3", instrument='focalplane = "axis"'), "focalplane"),
    ],
)
def test_bad_budgets_are_one_clear_error(tmp_path, tables, message):
    with pytest.raises(ConfigError, match=message):
        design.load_budget(budget_file(tmp_path, **tables))


def test_a_budget_focal_plane_is_checked(tmp_path):
    bad = tmp_path / "fp.csv"
    bad.write_text("name,xi_deg,eta_deg,gamma_deg\nD0A,0,0,0\nD0B,0,0,90\nD1A,1,0,0\n")
    with pytest.raises(ConfigError, match="D1A"):
        design.load_budget(budget_file(tmp_path, instrument='focalplane = "fp.csv"'))
    with pytest.raises(ConfigError, match="pair_angles_deg"):
        design.load_budget(
            budget_file(tmp_path, instrument='focalplane = "axis"\npair_angles_deg = [0.0]')
        )
    with pytest.raises(ConfigError, match="dg has 2 entries but the instrument has 37 pairs"):
        design.load_budget(budget_file(tmp_path, instrument='focalplane = "hexagon:37:35"'))
    budget = design.load_budget(
        budget_file(tmp_path, systematics="dg = {mean = 0.0, rms = 0.01}",
                instrument='focalplane = "hexagon:37:35"')
    )  # fmt: skip
    assert budget.focalplane.n_pairs == 37 and predict.supports(budget.instrument)


def test_a_budget_that_deprojects_says_which_templates(tmp_path):
    """[deprojection] gives the budget its Deprojection; without it nothing is deprojected."""
    plain = design.load_budget(budget_file(tmp_path))
    assert plain.deprojection is None and plain.deprojected == ()
    tables = dict(
        design="nside = 32\nevaluation = 'exact'",
        deprojection="templates = ['pointing', 'gain']\nblock_hours = 10.0",
    )
    budget = design.load_budget(budget_file(tmp_path, **tables))
    assert budget.deprojected == ("gain", "pointing") and budget.deprojection.block_hours == 10.0


def test_a_budget_that_filters_says_how(tmp_path):
    """[filter] gives the budget its Filtering (the CLI's p3+ground-split) and the skies of its
    objective; the pipeline is the filter, and without the table raw."""
    plain = design.load_budget(budget_file(tmp_path))
    assert plain.filtering is None and not plain.pipeline
    table = "poly_order = 3\nground_order = 5\nground_split = true\nskies = 6"
    budget = design.load_budget(budget_file(tmp_path, filter=table))
    assert str(budget.pipeline) == "p3+ground5-split" and budget.filter_skies == 6
    default = design.load_budget(budget_file(tmp_path, filter="ground_bin_deg = 2.0"))
    assert str(default.pipeline) == "groundbin2" and default.filter_skies == 4
    both = design.load_budget(
        budget_file(tmp_path, filter="poly_order = 3", deprojection="templates = ['gain']")
    )
    assert str(both.pipeline) == "p3+deproject(gain)" and both.deprojected == ("gain",)
