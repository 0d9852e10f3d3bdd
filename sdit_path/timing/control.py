"""A run's timing as a control runs it, sampled every servo period.

:class:`SampledProfile` has the interface of :class:`~sdit_path.timing.profile.ChainProfile`
(``duration_s``, ``length_mm``, ``evaluate``), so a :class:`~sdit_path.timing.trajectory.TimedRun`
can carry either: the ball stays on the planned curve, only its progress along it
follows the control.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from .trajectory import RunParameter, TimedDwell, TimedLayer, TimedLine, TimedRun


@dataclass(frozen=True, slots=True)
class SampledProfile:
    """Progress along a run sampled every ``period_s``: ``s_mm : (n,) float``, from 0 at
    the run's start to its length at rest, non-decreasing."""

    s_mm: np.ndarray
    period_s: float

    def __post_init__(self):
        s = np.maximum.accumulate(np.asarray(self.s_mm, dtype=float))
        s.setflags(write=False)
        object.__setattr__(self, "s_mm", s)

    @property
    def duration_s(self) -> float:
        return (len(self.s_mm) - 1) * self.period_s

    @property
    def length_mm(self) -> float:
        return float(self.s_mm[-1])

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(s, v, a, j, phase)`` at times ``t`` (s): position, its first three time
        derivatives (differences of the samples, interpolated linearly) and the phase
        (0 speeding up, 3 cruising, 6 slowing down)."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        h = self.period_s
        grid = np.arange(len(self.s_mm)) * h
        v = np.gradient(self.s_mm, h) if len(self.s_mm) > 1 else np.zeros(1)
        a = np.gradient(v, h) if len(v) > 1 else np.zeros(1)
        j = np.gradient(a, h) if len(a) > 1 else np.zeros(1)
        s_t, v_t, a_t, j_t = (np.interp(t, grid, x) for x in (self.s_mm, v, a, j))
        eps = 1e-6 * max(1.0, float(np.abs(a).max()) if a.size else 1.0)
        phase = np.where(a_t > eps, 0, np.where(a_t < -eps, 6, 3))
        return s_t, v_t, a_t, j_t, phase


def progress_along(points_mm: np.ndarray, length_mm: float) -> np.ndarray:
    """A control's path ``points_mm : (n, 3)`` (the ball in the table frame, every servo
    period) as progress along a run of ``length_mm``: the distance travelled, scaled to
    the run's length (the control's chords are within micrometres of the curve and a
    few parts per million shorter; the scale spreads that evenly)."""
    step = np.linalg.norm(np.diff(points_mm, axis=0), axis=1)
    travelled = np.r_[0.0, np.cumsum(step)]
    total = travelled[-1]
    if total <= 0.0:
        return np.zeros(len(points_mm))
    return travelled * (length_mm / total)


def control_layer(timed: TimedLayer, paths: Sequence[np.ndarray], period_s: float) -> TimedLayer:
    """``timed`` as a control runs it.  ``paths[k] : (n_k + 1, 3)`` is the ball in the
    table frame during the k-th stretch of motion between two standstills (dwells,
    program stops): where the stretch starts, then after each of the n_k servo periods
    from the first that moves to the last.  Every run and repositioning line keeps its
    geometry; its progress along it, and so its duration, follow the control; dwells
    keep theirs.  Runs with no dwell between them (a pass turning back on itself) are one
    stretch, as are the lines of a repositioning between its two program stops; such a
    stretch is shared out by the distance travelled."""
    groups: list[list] = [[]]
    for item in timed.items:
        if isinstance(item, TimedDwell):
            groups.append([])
        elif groups[-1] and isinstance(groups[-1][-1], TimedRun) != isinstance(item, TimedRun):
            groups.append([item])  # a program stop between a run and repositioning lines
        else:
            groups[-1].append(item)
    groups = [g for g in groups if g]
    if len(groups) != len(paths):
        raise ValueError(f"layer {timed.layer}: the control moves in {len(paths)} stretches, "
                         f"the plan in {len(groups)}")
    profiles: dict[int, SampledProfile] = {}
    for group, path in zip(groups, paths):
        lengths = np.array([_item_length(i) for i in group])
        travelled = progress_along(np.asarray(path, dtype=float), float(lengths.sum()))
        ends = np.cumsum(lengths)
        first = 0
        for k, (item, length) in enumerate(zip(group, lengths)):
            last = (len(travelled) - 1 if k == len(group) - 1 else
                    max(first, int(np.searchsorted(travelled, ends[k] - 1e-9))))
            s = np.clip(travelled[first:last + 1] - (ends[k] - length), 0.0, length)
            s[0], s[-1] = 0.0, length
            profiles[id(item)] = SampledProfile(s, period_s)
            first = last
    items, t = [], 0.0
    for item in timed.items:
        if isinstance(item, TimedDwell):
            items.append(replace(item, start_s=t))
            t += item.duration_s
            continue
        prof = profiles[id(item)]
        if isinstance(item, TimedRun):
            items.append(TimedRun(item.geometry, prof, t, item.carry_in,
                                  RunParameter(item.geometry.length_mm)))
        else:
            items.append(replace(item, profile=prof, start_s=t))
        t += prof.duration_s
    return TimedLayer(timed.layer, tuple(items), t, timed.axis_names, timed.axis_units)


def _item_length(item) -> float:
    if isinstance(item, TimedRun):
        return float(item.geometry.length_mm)
    if isinstance(item, TimedLine):
        return float(np.linalg.norm(np.asarray(item.b_mm) - item.a_mm))
    raise TypeError(f"no length for {type(item).__name__}")
