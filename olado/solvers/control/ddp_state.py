"""The state of one DDP / stagewise Newton solve (olado.solvers.control.ddp; paper 001 sec. 2.2):
the iterate with its derivatives, the shift schedule of mu (Tassa, Erez and Todorov 2012, or the
inertia correction of Waechter and Biegler 2006), the work arrays of the sweeps, counters and
history. The solver object holds only options; a solve owns one :class:`DPState`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from ...result import Status
from ..common import Stoppable


class ShiftSchedule:
    """The shift mu of Q_uu and the factor delta of the 'tassa' schedule (module docstring)."""

    def __init__(self, options):
        self.o = options
        self.inertia = options.shift_schedule == "inertia"
        self.mu = float(options.shift_init)
        self.delta = 1.0
        self.last_shift = 0.0     # inertia schedule: the last nonzero shift that worked

    def start(self):
        """The shift of an iteration's first backward pass (inertia: the unshifted Newton step first)."""
        if self.inertia:
            self.mu = 0.0
        return self.mu

    def raise_(self):
        """Raise mu after a failed backward pass or line search; True when it exceeds shift_max."""
        o = self.o
        if self.inertia:            # Waechter & Biegler (2006) sec. 3.1, kappa- = 1/3, kappa+ = 8, 100
            if self.mu == 0.0:
                self.mu = max(o.shift_min, self.last_shift / 3.0) if self.last_shift > 0 else max(o.shift_min, 1e-4)
            else:
                self.mu = self.mu * (8.0 if self.last_shift > 0 else 100.0)
        else:
            self.delta = max(o.shift_factor, self.delta * o.shift_factor)
            self.mu = max(o.shift_min, self.mu * self.delta)
        return self.mu > o.shift_max

    def decrease(self):
        """After a successful iteration (Tassa et al. 2012; inertia: remember the shift)."""
        o = self.o
        if self.inertia:
            self.last_shift = self.mu if self.mu > 0 else self.last_shift
        else:
            self.delta = min(1.0 / o.shift_factor, self.delta / o.shift_factor)
            self.mu = self.mu * self.delta if self.mu * self.delta >= o.shift_min else 0.0


class Sweeps:
    """Work arrays of the backward pass (gains, value function) and the linear forward sweep."""

    def __init__(self, N, n, m):
        self.kff = np.empty((N, m)); self.Kfb = np.empty((N, m, n))
        self.Vx = np.empty((N + 1, n)); self.Vxx = np.empty((N + 1, n, n))
        self.dU = np.empty((N, m)); self.dX = np.empty((N + 1, n))


class Accepted(NamedTuple):
    """A step the line search accepted."""

    alpha: float
    X: np.ndarray
    U: np.ndarray
    J: float
    dV: float           # the expected change dV(alpha)


@dataclasses.dataclass
class DPState(Stoppable):
    """One DDP / stagewise Newton solve: the iterate and its derivatives, the shift schedule,
    work arrays, counters and history."""

    X: np.ndarray
    U: np.ndarray
    J: float
    d: Any                      # the derivatives at (X, U) (ddp._Derivatives)
    shift: ShiftSchedule
    sweeps: Sweeps
    message: str
    limits: Any = None          # the solve's olado.interrupts.Limits
    status: Status = Status.MAX_ITERATIONS
    it: int = 0
    n_backward: int = 0
    n_trials: int = 0
    last_step: bool = False     # the expected decrease is below decrease_tol: take the full step and stop
    trial_X: np.ndarray | None = None   # the last trial point of the line searches
    trial_U: np.ndarray | None = None
    history: list = dataclasses.field(default_factory=list)
