"""A trajectory re-timed run by run: the same path, every run and every dwell lasting as
long as a recording says the machine took.

A real control ramps, blends and slows down by its own rules and dwells by its wall
clock; where the recording's still windows and its reading say when each run began and
ended, the trajectory is stretched between those moments (:class:`Retiming`): the path,
its order and its dwells stay the plan's, the time each piece takes is the machine's.
Inside a run the time law keeps its shape, scaled to the run's measured duration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from .trajectory import Samples


@dataclass(frozen=True, slots=True)
class Retiming:
    """A monotone piecewise-linear map from the trajectory's own time (``source_s``) to
    the time the machine took (``target_s``, from the same start): knots at the start
    and end of every run and at both ends of the trajectory."""

    source_s: tuple[float, ...]
    target_s: tuple[float, ...]

    def __post_init__(self) -> None:
        s, t = np.asarray(self.source_s), np.asarray(self.target_s)
        if len(s) != len(t) or len(s) < 2 or np.any(np.diff(s) <= 0) or np.any(np.diff(t) <= 0):
            raise ValueError("a retiming needs increasing knots, as many on either side")

    def forward(self, tau: np.ndarray) -> np.ndarray:
        """Machine time of trajectory time ``tau`` (linear beyond the ends)."""
        return _interp(np.asarray(tau, float), self.source_s, self.target_s)

    def inverse(self, t: np.ndarray) -> np.ndarray:
        return _interp(np.asarray(t, float), self.target_s, self.source_s)


def _interp(x: np.ndarray, xs, ys) -> np.ndarray:
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    out = np.interp(x, xs, ys)
    lo, hi = x < xs[0], x > xs[-1]
    out[lo] = ys[0] + (x[lo] - xs[0]) * (ys[1] - ys[0]) / (xs[1] - xs[0])
    out[hi] = ys[-1] + (x[hi] - xs[-1]) * (ys[-1] - ys[-2]) / (xs[-1] - xs[-2])
    return out


def retime(samples: Samples, retiming: Retiming) -> Samples:
    """``samples`` on a grid of the same period in machine time: the positions at the
    trajectory time each grid instant maps back to (cubic Hermite between samples, with
    the trajectory's own velocities scaled by the run's time scale, so that speed and
    acceleration stay smooth inside a run); labels of the nearest sample."""
    t = np.asarray(samples.t_s, float)
    if len(t) < 3:
        return samples
    period = float(np.median(np.diff(t)))
    end = float(retiming.forward(np.array([t[-1]]))[0] - retiming.forward(np.array([t[0]]))[0])
    n = int(np.floor(end / period + 1e-9)) + 1
    t_new = np.arange(n) * period
    tau = np.clip(retiming.inverse(t_new + float(retiming.forward(np.array([t[0]]))[0])),
                  t[0], t[-1])
    pos = np.column_stack([np.asarray(samples.ball_mm, float), np.asarray(samples.axes, float)])
    spline = CubicHermiteSpline(t, pos, np.gradient(pos, t, axis=0), axis=0)
    moved = spline(tau)
    near = np.clip(np.rint((tau - t[0]) / period).astype(int), 0, len(t) - 1)
    ball = moved[:, :3]
    speed = np.r_[0.0, np.linalg.norm(np.diff(ball, axis=0), axis=1) / period]
    phase = np.asarray(samples.phase, dtype=object)[near]
    speed[(phase == "dwell") | (phase == "reposition")] = 0.0
    return Samples(t_new, ball, moved[:, 3:], np.asarray(samples.segment, dtype=object)[near],
                   phase, speed, tuple(samples.axis_names), tuple(samples.axis_units))
