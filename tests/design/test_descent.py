"""The one coordinate-descent loop: on a separable objective one pass that moves reaches the
enumerated optimum; the best of several starts is kept with one history row a pass; Ctrl-C
returns the best end point so far (or the running state's) marked interrupted."""

import itertools

import numpy as np

from boresight._util import interrupts
from boresight.design.descent import descend
from boresight.design.white import Design

COST = np.array([[3.0, 1.0, 2.0], [0.5, 4.0, 0.25], [2.0, 2.0, 1.5], [1.0, 0.0, 3.0]])
PAIR = -2.0  # added for each two consecutive units on the same choice: local minima


def _value(choice, pair=PAIR):
    same = np.sum(choice[1:] == choice[:-1])
    return float(COST[np.arange(len(choice)), choice].sum() + pair * same)


class _State:
    def __init__(self, start):
        self.choice = np.array(start)


def _sweep(state, interrupt_after=None, value=_value):
    """Each unit moved to its best choice with the others fixed; the moves made."""
    moves = 0
    for u in range(state.choice.size):
        if interrupt_after is not None and interrupt_after[0] == 0:
            raise interrupts.Interrupted()
        trial = []
        for k in range(COST.shape[1]):
            c = state.choice.copy()
            c[u] = k
            trial.append(value(c))
        best = int(np.argmin(trial))
        if trial[best] < value(state.choice) - 1e-12:
            state.choice[u] = best
            moves += 1
        if interrupt_after is not None:
            interrupt_after[0] -= 1
    return moves


def _run(starts, interrupt_after=None):
    return descend(
        starts,
        state_of=_State,
        sweep=lambda state: _sweep(state, interrupt_after),
        value_of=lambda state: _value(state.choice),
        design_of=lambda state, value, history: Design(state.choice.copy(), value, history),
        sweeps=8,
    )


def test_separable_the_descent_reaches_the_enumerated_optimum_in_one_pass_that_moves():
    grid = [np.array(c) for c in itertools.product(range(3), repeat=4)]
    optimum = min(_value(c, 0.0) for c in grid)
    found = descend(
        [np.zeros(4, int)],
        state_of=_State,
        sweep=lambda state: _sweep(state, value=lambda c: _value(c, 0.0)),
        value_of=lambda state: _value(state.choice, 0.0),
        design_of=lambda state, value, history: Design(state.choice.copy(), value, history),
        sweeps=8,
    )
    assert found.value == optimum
    assert [row["sweep"] for row in found.history] == [0, 1, 2]
    assert [row["moves"] for row in found.history][1:] == [4, 0]  # every unit moves once


def test_the_best_end_point_of_the_starts_is_kept_with_one_row_a_pass():
    starts = [np.array([1, 1, 1, 1]), np.array([1, 0, 1, 0]), np.array([2, 2, 2, 2])]
    alone = [_run([start]) for start in starts]
    found = _run(starts)
    best = min(alone, key=lambda d: d.value)
    assert found.value == best.value == _value(found.angles_deg)
    assert len({d.value for d in alone}) > 1  # the starts end apart: the choice matters
    np.testing.assert_array_equal(found.angles_deg, best.angles_deg)
    assert found.history == [dict(row, start=k) for k, d in enumerate(alone) for row in d.history]
    assert found.interrupted is None


def test_ctrl_c_returns_the_running_state_marked_interrupted():
    found = _run([np.zeros(4, int)], interrupt_after=[2])  # stopped in the first pass
    assert isinstance(found.interrupted, interrupts.Interrupted)
    assert found.value == _value(found.angles_deg)
    assert [row["sweep"] for row in found.history] == [0]
    first = _run([np.zeros(4, int)])
    units = 4 * (len(first.history) - 1)  # the units the first start's passes visit
    found = _run([np.zeros(4, int), np.array([1, 0, 1, 0])], interrupt_after=[units + 1])
    assert isinstance(found.interrupted, interrupts.Interrupted)
    assert found.value == first.value  # the first start's end point, the second's cut short
    np.testing.assert_array_equal(found.angles_deg, first.angles_deg)
    assert [row["start"] for row in found.history] == [0] * len(first.history) + [1]
