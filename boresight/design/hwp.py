"""The budget's half-wave plate as the design sees it: a continuous plate's unit moments of
psi + 2 chi, a stepped plate's allowed steps and the baselines' steps, and the plate the TOD sees
on an assignment."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..moments.units import UnitMoments, unit_moments

if TYPE_CHECKING:
    from ..instrument.hwp import HWP


class Plate(NamedTuple):
    """The budget's HWP, as the design sees it: a continuous plate's unit moments of psi + 2 chi
    (where the pairs carry systematics), a stepped plate's allowed steps, and the steps of the
    baselines (the allowed steps in turn, unit by unit)."""

    hwp: HWP | None = None
    moments: UnitMoments | None = None
    allowed: tuple | None = None
    baseline: np.ndarray | None = None

    @classmethod
    def of(cls, budget, schedule, moments):
        hwp = budget.hwp
        if hwp is None:
            return cls()
        if hwp.stepped:
            turn = np.asarray(hwp.angles_deg)[np.arange(moments.n_units) % len(hwp.angles_deg)]
            return cls(hwp, allowed=hwp.angles_deg, baseline=turn)
        opts = budget.design
        spun = None
        if budget.systematics.has_amplitude:
            spun = unit_moments(schedule, opts.nside, opts.group, hwp=hwp)
        return cls(hwp, spun)

    def pairs_h(self, moments, angles, steps):
        """The h_n of the pairs' reflected angle (their own without a plate)."""
        if self.hwp is None:
            return moments.h(angles)
        if self.hwp.stepped:
            return moments.h(np.asarray(angles) + 2 * np.asarray(steps))
        return (self.moments or moments).h(angles)  # no pair terms where there are none

    def seen(self, moments, steps):
        """The HWP the TOD sees on an assignment (a stepped plate at its units' steps)."""
        if self.hwp is None or self.hwp.spinning:
            return self.hwp
        return moments.stepped_plate(self.hwp, steps)
