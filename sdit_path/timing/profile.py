"""Rest-to-rest jerk-limited motion along a run's arc length, planned by ruckig.

ruckig is used as a one-degree-of-freedom state-to-state planner (``Ruckig(1)``: never
with waypoint capacity, which in the community version sends the problem to a cloud
service).  The resulting seven-phase profile (jerk-up, constant acceleration,
jerk-down, cruise, and the mirror) is kept as its phase boundaries and evaluated
here, vectorised, exactly as ruckig's polynomials.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from ..arrays import frozen
from ..errors import PlanError
from .limits import PathLimits

#: Phase names by ruckig phase index (0-2 accelerate, 3 cruise, 4-6 decelerate).
PHASES = ("accelerate",) * 3 + ("cruise",) + ("decelerate",) * 3


@dataclass(frozen=True, slots=True)
class Profile:
    """``t0 : (8,)`` phase start times (s, from the profile start) with the end last;
    ``p0, v0, a0 : (7,)`` state at each phase start; ``jerk : (7,)``."""

    length_mm: float
    limits: PathLimits
    t0: np.ndarray
    p0: np.ndarray
    v0: np.ndarray
    a0: np.ndarray
    jerk: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t0[-1])

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """Arc length, speed, acceleration, jerk and phase index at times ``t``."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, 6)
        dt = t - self.t0[k]
        j = self.jerk[k]
        a = self.a0[k] + j * dt
        v = self.v0[k] + self.a0[k] * dt + j * dt * dt / 2.0
        s = self.p0[k] + self.v0[k] * dt + self.a0[k] * dt * dt / 2.0 + j * dt ** 3 / 6.0
        return s, v, a, j, k


def plan_profile(length_mm: float, limits: PathLimits, label: str = "run") -> Profile:
    """Time-optimal jerk-limited rest-to-rest motion over ``length_mm``."""
    otg = Ruckig(1)
    inp = InputParameter(1)
    inp.current_position = [0.0]
    inp.current_velocity = [0.0]
    inp.current_acceleration = [0.0]
    inp.target_position = [float(length_mm)]
    inp.target_velocity = [0.0]
    inp.target_acceleration = [0.0]
    inp.max_velocity = [limits.v_max]
    inp.max_acceleration = [limits.a_max]
    inp.max_jerk = [limits.j_max]
    inp.min_velocity = [0.0]  # never run backwards to reach the target
    traj = Trajectory(1)
    try:
        result = otg.calculate(inp, traj)
    except RuntimeError as exc:  # ruckig raises on invalid input
        raise PlanError(f"{label}: ruckig could not time the run: {exc}") from None
    if result not in (Result.Working, Result.Finished):
        raise PlanError(f"{label}: ruckig could not time the run ({result})")
    prof = traj.profiles[0][0]
    durations = np.array(prof.t, dtype=float)
    t0 = np.concatenate([[0.0], np.cumsum(durations)])
    return Profile(float(length_mm), limits, frozen(t0), frozen(prof.p[:7]), frozen(prof.v[:7]),
                   frozen(prof.a[:7]), frozen(prof.j[:7]))
