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
from ruckig import InputParameter, Result, Ruckig, RuckigError, Trajectory

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
    return plan_state(length_mm, 0.0, 0.0, limits, label)


def change_distance(v1: float, v2: float, a: float, j: float) -> float:
    """Path length a jerk-limited change from speed v1 to v2 takes (zero acceleration at
    both ends): the profile is symmetric, so its mean speed is (v1 + v2) / 2."""
    dv = abs(v2 - v1)
    t = dv / a + a / j if dv * j >= a * a else 2.0 * np.sqrt(dv / j)
    return 0.5 * (v1 + v2) * t


def _largest(fits, lo: float, hi: float, steps: int = 50) -> float:
    """Largest value in [lo, hi] for which the monotone predicate ``fits`` holds
    (``lo`` is assumed to fit)."""
    if fits(hi):
        return hi
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if fits(mid):
            lo = mid
        else:
            hi = mid
    return lo


def _reachable(v_from: float, length: float, budget, cap: float, slack: float) -> float:
    """Largest speed <= cap that can be changed to or from ``v_from`` within ``length``,
    with the window's budget at the higher of the two speeds."""
    def fits(v: float) -> bool:
        a, j = budget.at(max(v, v_from))
        return a > 0 and j > 0 and change_distance(v_from, v, a * slack, j * slack) <= length

    return _largest(fits, min(v_from, cap), cap)


def _peak(v0: float, v1: float, length: float, budget, slack: float) -> float:
    """Highest speed a window can reach between boundary speeds v0 and v1."""
    def fits(v: float) -> bool:
        a, j = budget.at(v)
        return a > 0 and j > 0 and (change_distance(v0, v, a * slack, j * slack)
                                    + change_distance(v, v1, a * slack, j * slack)) <= length

    return _largest(fits, max(v0, v1), budget.v_cap)


def plan_state(length_mm: float, v_start: float, v_end: float, limits: PathLimits,
               label: str) -> Profile:
    """ruckig from (0, v_start, 0) to (length, v_end, 0) under ``limits``."""
    otg = Ruckig(1)
    inp = InputParameter(1)
    inp.current_position = [0.0]
    inp.current_velocity = [float(v_start)]
    inp.current_acceleration = [0.0]
    inp.target_position = [float(length_mm)]
    inp.target_velocity = [float(v_end)]
    inp.target_acceleration = [0.0]
    inp.max_velocity = [max(limits.v_max, v_start, v_end)]
    inp.max_acceleration = [limits.a_max]
    inp.max_jerk = [limits.j_max]
    inp.min_velocity = [0.0]
    traj = Trajectory(1)
    try:
        result = otg.calculate(inp, traj)
    except (RuntimeError, RuckigError) as exc:
        raise PlanError(f"{label}: ruckig could not time the run: {exc}") from None
    if result not in (Result.Working, Result.Finished):
        raise PlanError(f"{label}: ruckig could not time the run ({result})")
    prof = traj.profiles[0][0]
    t0 = np.concatenate([[0.0], np.cumsum(np.array(prof.t, dtype=float))])
    return Profile(float(length_mm), limits, frozen(t0), frozen(prof.p[:7]), frozen(prof.v[:7]),
                   frozen(prof.a[:7]), frozen(prof.j[:7]))


@dataclass(frozen=True, slots=True)
class ChainProfile:
    """Consecutive window profiles of one run: ``s0``/``t0`` where each starts."""

    parts: tuple[Profile, ...]
    s0: np.ndarray
    t0: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t0[-1] + self.parts[-1].duration_s)

    @property
    def length_mm(self) -> float:
        return float(self.s0[-1] + self.parts[-1].length_mm)

    @property
    def limits(self) -> PathLimits:
        """The limits of the slowest window (what bound the run most)."""
        return min((p.limits for p in self.parts), key=lambda x: x.v_max)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, len(self.parts) - 1)
        s = np.empty_like(t)
        v, a, j = np.empty_like(t), np.empty_like(t), np.empty_like(t)
        for w in np.unique(k):
            sel = k == w
            sw, vw, aw, jw, _ = self.parts[w].evaluate(t[sel] - self.t0[w])
            s[sel], v[sel], a[sel], j[sel] = sw + self.s0[w], vw, aw, jw
        eps = 1e-6 * max(1.0, float(np.abs(a).max()) if a.size else 1.0)
        phase = np.where(a > eps, 0, np.where(a < -eps, 6, 3))
        return s, v, a, j, phase


def _spans(windows: list[tuple[float, object]], reach: int) -> dict[tuple[int, int], object]:
    """The budget of every stretch of up to ``reach`` consecutive windows, keyed by
    (first boundary, last boundary): the weakest of its windows."""
    spans = {}
    for k in range(len(windows)):
        bud = windows[k][1]
        spans[(k, k + 1)] = bud
        for m in range(k + 2, min(len(windows), k + reach) + 1):
            bud = bud.weaker(windows[m - 1][1])
            spans[(k, m)] = bud
    return spans


def _boundary_speeds(windows: list[tuple[float, object]], spans: dict, cum: np.ndarray,
                     reach: int, slack: float) -> np.ndarray:
    """Backward and forward reachability passes over the window boundaries.

    A speed change may span up to ``reach`` windows under the weakest of their
    budgets, so one change is not cut into steps that each start and end at zero
    acceleration.  A stretch is only used where its speed cap admits the speed it
    starts from."""
    n = len(windows)
    caps = [min(windows[k - 1][1].v_cap, windows[k][1].v_cap) for k in range(1, n)]
    vb = np.array([0.0] + caps + [0.0])
    for k in range(n - 1, -1, -1):  # backward: able to slow down in time
        best = 0.0
        for m in range(k + 1, min(n, k + reach) + 1):
            bud = spans[(k, m)]
            if bud.v_cap >= vb[m] * (1.0 - 1e-12):
                best = max(best, _reachable(vb[m], cum[m] - cum[k], bud,
                                            min(vb[k], bud.v_cap), slack))
        vb[k] = min(vb[k], best)
    for m in range(1, n + 1):  # forward: able to speed up in time
        best = 0.0
        for k in range(max(0, m - reach), m):
            bud = spans[(k, m)]
            if bud.v_cap >= vb[k] * (1.0 - 1e-12):
                best = max(best, _reachable(vb[k], cum[m] - cum[k], bud,
                                            min(vb[m], bud.v_cap), slack))
        vb[m] = min(vb[m], best)
    return vb


def _fastest_split(windows: list[tuple[float, object]], cum: np.ndarray, reach: int,
                   label: str, slack: float) -> list[tuple[int, Profile]] | None:
    """Boundary speeds, then the split of the run into stretches of up to ``reach``
    windows (one ruckig profile each, rest-to-rest in acceleration at the stretch
    ends) with the least total time, by dynamic programming over the boundaries.
    None if no split fits the boundary speeds."""
    n = len(windows)
    spans = _spans(windows, reach)
    vb = _boundary_speeds(windows, spans, cum, reach, slack)
    cost = np.full(n + 1, np.inf)
    cost[0] = 0.0
    choice: list[tuple[int, Profile] | None] = [None] * (n + 1)
    for m in range(1, n + 1):
        for k in range(max(0, m - reach), m):
            if not np.isfinite(cost[k]):
                continue
            bud, length = spans[(k, m)], cum[m] - cum[k]
            low = max(vb[k], vb[m])
            if low > bud.v_cap * (1.0 + 1e-9):
                continue
            a, j = bud.at(low)
            if not (a > 0 and j > 0) or (change_distance(vb[k], vb[m], a * slack, j * slack)
                                         > length * (1.0 + 1e-9)):
                continue
            top = _peak(vb[k], vb[m], length, bud, slack)
            try:
                prof = plan_state(length, vb[k], vb[m], bud.limits(top), label)
            except PlanError:
                continue
            if cost[k] + prof.duration_s < cost[m]:
                cost[m] = cost[k] + prof.duration_s
                choice[m] = (k, prof)
    if not np.isfinite(cost[n]):
        return None
    split, m = [], n
    while m > 0:
        k, prof = choice[m]
        split.append((k, prof))
        m = k
    return split[::-1]


def plan_chain(windows: list[tuple[float, object]], label: str, slack: float = 0.98,
               reach: int = 8) -> ChainProfile:
    """Rest-to-rest over consecutive windows ``(length, budget)``.

    Boundary speeds come from backward and forward reachability passes in which a
    speed change may span up to ``reach`` windows; the run is then split into
    stretches of up to ``reach`` windows, each planned by ruckig with the weakest
    budget of its windows at the highest speed it reaches, and the split with the
    least total time is kept.  Each window still gets acceleration and jerk at the
    speed it runs, and a ramp is no longer cut into steps at every window boundary.
    Should no split fit (rounding at a boundary), the run is planned window by window,
    which always fits."""
    cum = np.concatenate([[0.0], np.cumsum([w[0] for w in windows])])
    split = _fastest_split(windows, cum, reach, label, slack) if reach > 1 else None
    if split is None:
        spans = _spans(windows, 1)
        vb = _boundary_speeds(windows, spans, cum, 1, slack)
        split = []
        for k, (length, bud) in enumerate(windows):
            top = _peak(vb[k], vb[k + 1], length, bud, slack)
            split.append((k, plan_state(length, vb[k], vb[k + 1], bud.limits(top), label)))
    parts = tuple(prof for _, prof in split)
    s0 = np.array([cum[k] for k, _ in split])
    t0 = np.concatenate([[0.0], np.cumsum([p.duration_s for p in parts])[:-1]])
    return ChainProfile(parts, frozen(s0), frozen(t0))
