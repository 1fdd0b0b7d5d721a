"""Ctrl-C and SIGTERM: noted by a signal handler, acted on between chunks of work.

Python runs a signal handler between bytecodes of the main thread. One that raises there can land
while a numba kernel or a C extension returns, which surfaces as a ``SystemError`` traceback, or is
swallowed. So :func:`handled` installs handlers that only note the signal, and the loops of every
long job call :func:`check` between chunks (the engine's pixel chunks, a schedule's sample chunks,
each stage of a :class:`boresight._util.provenance.Timer`, each unit of the design's search, each wait
on a background transform), which raises :class:`Interrupted` there, a ``KeyboardInterrupt``. The
job's ``finally`` and ``with`` blocks then remove what it was writing, and the command line exits
130 (Ctrl-C) or 143 (SIGTERM). A second Ctrl-C while the first waits for a check raises at once.

This module imports nothing but the standard library, so the command line installs its handlers
before it imports numba and the rest of boresight.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import signal
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator

#: the exit code of each signal: 128 + its number, as a shell reports it
EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
#: seconds between checks while waiting on a background job
POLL_SECONDS = 0.05

_pending: list[int] = []  #: signals noted and not yet raised


class Interrupted(KeyboardInterrupt):
    """A job stopped by Ctrl-C or SIGTERM at a safe point.

    Parameters
    ----------
    signum : int
        The signal.
    kept : str, optional
        What the job kept for the user (e.g. "the best schedule found so far is in OUT"); by
        default nothing was written.
    """

    def __init__(self, signum: int = signal.SIGINT, kept: str | None = None):
        super().__init__(signum)
        self.signum = signum
        self.kept = kept

    @property
    def exit_code(self) -> int:
        return EXIT_CODES.get(self.signum, 130)

    @property
    def verb(self) -> str:
        return "terminated" if self.signum == signal.SIGTERM else "interrupted"


def _note(signum, frame):
    if _pending and signum == signal.SIGINT:  # a second Ctrl-C before a check: the user means it
        signum = _pending[0]
        _pending.clear()
        raise Interrupted(signum)
    _pending.append(signum)


def pending() -> bool:
    """Whether a signal is waiting for a check."""
    return bool(_pending)


def check() -> None:
    """Raise :class:`Interrupted` if Ctrl-C or SIGTERM came since the handlers were installed, or
    since the last one was raised: each signal raises once, so a job that catches it (the design's
    search keeps its best schedule) can go on to write what it keeps.

    Raises
    ------
    Interrupted
    """
    if _pending:
        signum = _pending[0]
        _pending.clear()
        raise Interrupted(signum)


def result(future: concurrent.futures.Future):
    """A background job's result, checking for signals while waiting.

    Parameters
    ----------
    future : concurrent.futures.Future

    Returns
    -------
    object
        ``future.result()``.
    """
    while True:
        check()
        try:
            return future.result(timeout=POLL_SECONDS)
        except concurrent.futures.TimeoutError:
            continue


def install_early() -> None:
    """Note SIGINT and SIGTERM from the console script's first import of boresight on, so that a
    Ctrl-C while the command line imports ends in one line, not in a traceback:
    :func:`handled` keeps what was noted here."""
    for s in EXIT_CODES:
        signal.signal(s, _note)


@contextlib.contextmanager
def handled() -> Iterator[None]:
    """Inside the block, SIGINT and SIGTERM are noted for :func:`check` instead of raising.

    The previous handlers come back after it; a signal still pending then is dropped (the block's
    caller has seen it through :func:`check` or :func:`pending`).
    """
    previous = {s: signal.signal(s, _note) for s in EXIT_CODES}
    if any(handler is not _note for handler in previous.values()):
        _pending.clear()  # noted before by another block; kept if noted since install_early()
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _pending.clear()
