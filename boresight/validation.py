"""Checks at the package's boundary, and boresight's errors.

Each check raises ``ValueError`` (or ``TypeError`` for a value of the wrong kind) with a message
that names the field and what is allowed, so that a config error, an API error and a CLI error read
the same. NaN and infinity never pass: every comparison below is written so that NaN fails it.

Bad input that a user can fix is a :class:`BoresightError`: a config, a schedule, an output path,
a job too large for the machine, a result holding NaN. The command line prints one of these in
one line and exits 2; any other exception is a bug, and it shows its traceback. Each class is
also a ``ValueError``, so that code catching those keeps working.
"""

from __future__ import annotations

import numbers
from dataclasses import field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from typing import Any


class BoresightError(Exception):
    """Input a user can fix, named in the message: what the command line reports and exits 2 for."""


class ConfigError(BoresightError, ValueError):
    """A configuration problem, with the offending key (and file) in the message."""


class ScheduleError(ConfigError):
    """A schedule file that cannot be read, with the file, row and key in the message."""


class OutputError(BoresightError, ValueError):
    """An output path boresight must not or cannot write (found before any work)."""


class OutputExistsError(OutputError, FileExistsError):
    """An earlier output where a job would write, which only ``--force`` (or ``--repair``)
    replaces."""


class MemoryLimitError(BoresightError, ValueError):
    """A job whose estimated memory exceeds what the machine has."""


class TimeLimitError(BoresightError, ValueError):
    """A job estimated to run longer than the limit, without ``--yes``."""


class ResultError(BoresightError, ValueError):
    """A result that holds NaN or infinite values: nothing is written."""


def require_finite(what: str, values: object) -> None:
    """Refuse to report NaN or infinity as a result.

    Parameters
    ----------
    what : str
        The result's name, for the message.
    values : array_like

    Raises
    ------
    ResultError
    """
    if not np.isfinite(np.asarray(values, dtype=np.float64)).all():
        raise ResultError(f"{what} holds NaN or infinite values; nothing was written")


def _describe(lo, hi):
    if lo is None and hi is None:
        return "a finite number"
    if hi is None:
        return f"finite and >= {lo:g}"
    if lo is None:
        return f"finite and <= {hi:g}"
    return f">= {lo:g} and <= {hi:g} (finite)"


def number(name: str, value: object, lo: float | None = None, hi: float | None = None) -> float:
    """A real, finite number within bounds.

    Parameters
    ----------
    name : str
        The field's name in messages.
    value : object
    lo, hi : float, optional
        Inclusive bounds.

    Returns
    -------
    float

    Raises
    ------
    TypeError
        Not a real number (a bool is not).
    ValueError
        NaN, infinite or out of range.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number {_describe(lo, hi)}, got {value!r}")
    x = float(value)
    if not (np.isfinite(x) and (lo is None or x >= lo) and (hi is None or x <= hi)):
        raise ValueError(f"{name} must be {_describe(lo, hi)}, got {value!r}")
    return x


def integer(name: str, value: object, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (not a bool) within bounds.

    Parameters
    ----------
    name : str
    value : object
    lo, hi : int, optional

    Returns
    -------
    int

    Raises
    ------
    TypeError, ValueError
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} = {value!r} is not an integer")
    if not ((lo is None or value >= lo) and (hi is None or value <= hi)):
        bounds = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise ValueError(f"{name} = {value!r} is out of range; allowed: an integer {bounds}")
    return int(value)


def label(name: str, value: object) -> str:
    """A one-word-or-more text label that schedule files can hold: non-empty, printable, with no
    ``|``, ``#`` or line break (the field separator and comment mark of TOAST's text schedules).

    Parameters
    ----------
    name : str
    value : object

    Returns
    -------
    str

    Raises
    ------
    TypeError, ValueError
    """
    if not isinstance(value, str):
        raise TypeError(f"{name} = {value!r} is not a string")
    if not value.strip() or not value.isprintable() or any(c in value for c in "|#"):
        raise ValueError(f"{name} = {value!r} must be printable text without '|' or '#'")
    return value


def numbers_array(
    name: str, value: object, lo: float | None = None, hi: float | None = None
) -> np.ndarray:
    """A scalar or 1-d sequence of real numbers, each finite within bounds.

    Parameters
    ----------
    name : str
    value : object
    lo, hi : float, optional

    Returns
    -------
    numpy.ndarray, float64

    Raises
    ------
    TypeError, ValueError
    """
    if isinstance(value, np.ndarray) and value.dtype.kind in "iuf":  # numbers already
        if value.ndim > 1:
            raise ValueError(f"{name} must be a number or a 1-d list of numbers")
        arr = value.astype(np.float64)
    else:
        items = np.asarray(value, dtype=object)
        if items.ndim > 1:
            raise ValueError(f"{name} must be a number or a 1-d list of numbers, got {value!r}")
        for item in items.ravel():
            if isinstance(item, (bool, np.bool_)) or not isinstance(item, numbers.Real):
                raise TypeError(f"{name} must hold numbers {_describe(lo, hi)}, got {value!r}")
        arr = items.astype(np.float64)
    ok = np.isfinite(arr).all() and (lo is None or (arr >= lo).all())
    if not ok or (hi is not None and not (arr <= hi).all()):
        raise ValueError(f"{name} must be {_describe(lo, hi)}, got {value!r}")
    return arr


def option(
    default: object, help: str, types: tuple | None = None, choices: tuple | None = None
) -> Any:
    """A dataclass field that documents itself.

    :mod:`boresight.config` builds the study file's schema, its error messages and the command-line
    flags from these.

    Parameters
    ----------
    default : object
    help : str
    types : tuple of type, optional
        TOML types accepted (default: from the default's type).
    choices : tuple, optional
        Allowed values.

    Returns
    -------
    dataclasses.Field
    """
    if types is None:
        kind = type(default)
        types = {bool: (bool,), int: (int,), float: (int, float), str: (str,), tuple: (list,)}[kind]
    meta = {"help": help, "types": types, "choices": choices}
    return field(default=default, metadata=meta)
