"""Coordinate descent over the units' choices: the one search loop that the design's objectives
share.

An objective brings its own state (the running sums that make a move cheap) and its own pass of
moves (:func:`boresight.design.exact.search` of one and two units on the exact objective,
:func:`boresight.design.focalplane.descend` on a focal plane's dense form); this loop runs the
passes from each start until one moves nothing or ``sweeps`` are done, keeps the best end point,
writes one history row per pass, and on Ctrl-C returns the best found so far with
``interrupted`` set.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._util import interrupts

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from .white import Design


def descend(
    starts: Sequence,
    *,
    state_of: Callable,
    sweep: Callable,
    value_of: Callable,
    design_of: Callable,
    sweeps: int,
) -> Design:
    """The best end point of coordinate descent from each of ``starts``.

    Parameters
    ----------
    starts : sequence
        The start assignments, in the order run.
    state_of : callable
        ``state_of(start)``: the search state of a start.
    sweep : callable
        ``sweep(state)``: one pass of moves, in place; returns the moves made.
    value_of : callable
        ``value_of(state)``: the objective at the state's assignment, computed afresh.
    design_of : callable
        ``design_of(state, value, history)``: the :class:`~boresight.design.white.Design` of a
        state (copies of its choice).
    sweeps : int
        Most passes per start.

    Returns
    -------
    Design
        ``history`` has one row per pass: start, sweep, objective, moves (sweep 0 the start).
    """
    best, history, state = None, [], None
    try:
        for k, start in enumerate(starts):
            state = state_of(start)
            history.append(dict(start=k, sweep=0, objective=value_of(state), moves=0))
            for n in range(1, sweeps + 1):
                moves = sweep(state)
                history.append(dict(start=k, sweep=n, objective=value_of(state), moves=moves))
                if moves == 0:
                    break
            value = value_of(state)  # re-anchored: no drift from the running sums
            if best is None or value < best.value:
                best = design_of(state, value, history)
    except KeyboardInterrupt as err:  # the command line's Interrupted, or a notebook's Ctrl-C
        stop = err if isinstance(err, interrupts.Interrupted) else interrupts.Interrupted()
        if best is None:
            if state is None:
                raise stop from None
            best = design_of(state, value_of(state), history)
        best.interrupted = stop
    best.history = history
    return best
