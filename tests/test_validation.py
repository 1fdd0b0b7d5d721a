"""Checks at the boundary: numbers name the field and refuse NaN and infinity, results holding
NaN are refused, and every error a user can fix is a BoresightError."""

import math

import pytest

from boresight import validation
from boresight.validation import (
    BoresightError,
    ConfigError,
    MemoryLimitError,
    OutputError,
    OutputExistsError,
    ResultError,
    ScheduleError,
    TimeLimitError,
)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_numbers_refuse_nan_and_infinity_and_name_the_field(value):
    with pytest.raises(ValueError, match="fwhm_arcmin"):
        validation.number("fwhm_arcmin", value, 0.0, 600.0)


def test_numbers_in_range_pass_and_out_of_range_say_the_limits():
    assert validation.number("x", 3, 0.0, 10.0) == 3.0
    with pytest.raises(ValueError, match=r">= 0 and <= 10"):
        validation.number("x", 11.0, 0.0, 10.0)
    with pytest.raises(TypeError, match="x"):
        validation.number("x", "3", 0.0, 10.0)


def test_a_result_with_nan_is_refused():
    validation.require_finite("the spectrum", [1.0, 2.0])
    with pytest.raises(ResultError, match="the spectrum holds NaN"):
        validation.require_finite("the spectrum", [1.0, math.nan])


@pytest.mark.parametrize(
    "error",
    [ConfigError, ScheduleError, OutputError, OutputExistsError, MemoryLimitError, TimeLimitError],
)
def test_every_user_error_is_a_boresight_error_and_a_value_error(error):
    assert issubclass(error, BoresightError) and issubclass(error, ValueError)


def test_an_existing_output_is_also_a_file_exists_error():
    assert issubclass(OutputExistsError, FileExistsError)
