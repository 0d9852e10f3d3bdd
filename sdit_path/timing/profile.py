"""Rest-to-rest jerk-limited motion along a run's path parameter, planned by ruckig.

ruckig is used as a one-degree-of-freedom state-to-state planner (``Ruckig(1)``: never
with waypoint capacity, which in the community version sends the problem to a cloud
service).  A run is cut into windows, each with the budget its curvature leaves
(:mod:`~sdit_path.timing.limits`).  Speed changes span several windows and are cut
into speed bands; each band is one ruckig profile (velocity interface) from one speed
and acceleration to the next, limited by the windows it crosses at the speed it
reaches, so a ramp is one motion that accelerates hard while slow and gently where
speed eats the budget.  Every profile (a seven-phase jerk-up, constant acceleration,
jerk-down, cruise, and the mirror) is kept as its phase boundaries and evaluated
here, vectorised, exactly as ruckig's polynomials.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    Result,
    Ruckig,
    RuckigError,
    Trajectory,
)

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
    return _solve(otg, inp, limits, f"{label}: ruckig could not time the run", float(length_mm))


def _solve(otg: Ruckig, inp: InputParameter, limits: PathLimits, failure: str,
           length_mm: float | None = None) -> Profile:
    """Run ruckig on ``inp`` and keep its profile; its length is ``length_mm`` (the
    target) or, if None, the path the profile covers."""
    traj = Trajectory(1)
    try:
        result = otg.calculate(inp, traj)
    except (RuntimeError, RuckigError) as exc:
        raise PlanError(f"{failure}: {exc}") from None
    if result not in (Result.Working, Result.Finished):
        raise PlanError(f"{failure} ({result})")
    prof = traj.profiles[0][0]
    t0 = np.concatenate([[0.0], np.cumsum(np.array(prof.t, dtype=float))])
    if length_mm is None:
        length_mm = float(traj.at_time(traj.duration)[0][0])
    return Profile(length_mm, limits, frozen(t0), frozen(prof.p[:7]), frozen(prof.v[:7]),
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


def plan_velocity(v_start: float, a_start: float, v_end: float, a_end: float,
                  limits: PathLimits, label: str) -> Profile:
    """ruckig (velocity interface) from speed and acceleration (v_start, a_start) to
    (v_end, a_end); the profile's length is the path it covers on the way."""
    otg = Ruckig(1)
    inp = InputParameter(1)
    inp.control_interface = ControlInterface.Velocity
    inp.current_position = [0.0]
    inp.current_velocity = [float(v_start)]
    inp.current_acceleration = [float(a_start)]
    inp.target_velocity = [float(v_end)]
    inp.target_acceleration = [float(a_end)]
    inp.max_velocity = [max(v_start, v_end) * 2.0 + 1.0]
    inp.max_acceleration = [limits.a_max]
    inp.max_jerk = [limits.j_max]
    return _solve(otg, inp, limits, f"{label}: ruckig could not time a speed change")


def cruise_profile(length_mm: float, limits: PathLimits) -> Profile:
    """Constant speed ``limits.v_max`` over ``length_mm``."""
    v = limits.v_max
    t = length_mm / v
    z = np.zeros(7)
    return Profile(float(length_mm), limits, frozen(np.array([0, 0, 0, 0, t, t, t, t], float)),
                   frozen(np.array([0, 0, 0, 0, length_mm, length_mm, length_mm], float)),
                   frozen(np.full(7, float(v))), frozen(z), frozen(z.copy()))


def _band(v0: float, a0: float, v1: float, a1: float, a_max: float, j_max: float
          ) -> tuple[float, float]:
    """Path length and time of the time-optimal speed-up from (v0, a0) to (v1, a1),
    accelerations in [0, a_max] (jerk up to a peak, hold, jerk down: what ruckig's
    velocity interface returns).  The ends must satisfy |a1^2 - a0^2| <= 2 j (v1 - v0).
    A slow-down over the same band, run backwards, takes the same length and time."""
    dv = v1 - v0
    ramps = (2.0 * a_max * a_max - a0 * a0 - a1 * a1) / (2.0 * j_max)
    if ramps <= dv:
        peak, hold = a_max, (dv - ramps) / a_max
    else:
        peak, hold = math.sqrt(max(j_max * dv + 0.5 * (a0 * a0 + a1 * a1), 0.0)), 0.0
    t1, t3 = (peak - a0) / j_max, (peak - a1) / j_max
    d1 = v0 * t1 + a0 * t1 * t1 / 2.0 + j_max * t1 ** 3 / 6.0
    va = v0 + a0 * t1 + j_max * t1 * t1 / 2.0
    d2 = va * hold + peak * hold * hold / 2.0
    vb = va + peak * hold
    d3 = vb * t3 + peak * t3 * t3 / 2.0 - j_max * t3 ** 3 / 6.0
    return d1 + d2 + d3, t1 + hold + t3


@dataclass(frozen=True, slots=True)
class _Ramp:
    """A speed change in bands: speeds ``u`` at the band edges, acceleration magnitude
    ``alpha`` there, and each band's limits ``a_max``, ``j_max``."""

    length_mm: float
    duration_s: float
    u: tuple
    alpha: tuple
    a_max: tuple
    j_max: tuple


class _Ramps:
    """Speed changes over consecutive windows ``(length, budget)``, in speed bands.

    A change from v_lo to v_hi is cut into bands of at most ``band`` mm/s.  Each band
    gets the acceleration and jerk that every window it crosses allows at the band's
    top speed, so the slow part of a ramp is not held to the budget of its fast end
    (on a 5-axis machine the C axis near the pole leaves a fast path little of either).
    Bands join with the acceleration both allow, so the ramp is one motion with zero
    acceleration only at its ends.  Which windows a band crosses depends on its limits,
    so the limits are taken again over the windows found until they no longer change.
    """

    def __init__(self, windows: list[tuple[float, object]], band: float = 8.0):
        self.windows = windows
        self.band = band
        self.cum = np.concatenate([[0.0], np.cumsum([w[0] for w in windows])])
        self._edges = self.cum.tolist()
        self.caps = [w[1].v_cap for w in windows]

    def window(self, s: float) -> int:
        return min(max(bisect.bisect_right(self._edges, s) - 1, 0), len(self.windows) - 1)

    def _limits(self, first: int, last: int, v: float, seen: dict) -> tuple[float, float]:
        """The acceleration and jerk every window first..last allows at speed ``v``
        ((0, 0) if one cannot run that fast); ``seen`` keeps each window's answer at
        each speed for the ramp being built, which asks again as a band's cover grows."""
        a = j = math.inf
        for w in range(first, last + 1):
            got = seen.get((w, v))
            if got is None:
                got = (() if v > self.caps[w] * (1.0 + 1e-9) else self.windows[w][1].at(v))
                seen[w, v] = got
            if not got:
                return 0.0, 0.0
            aw, jw = got
            if aw < a:
                a = aw
            if jw < j:
                j = jw
        return a, j

    def ramp(self, v_lo: float, v_hi: float, anchor: float, direction: int,
             within: float = math.inf) -> _Ramp | None:
        """From v_lo up to v_hi starting at arc length ``anchor`` (direction +1), or
        from v_hi down to v_lo ending there (-1).  None if it takes longer than
        ``within`` mm, leaves the run, or crosses a window that cannot run that fast."""
        if v_hi - v_lo <= 1e-9:
            return _Ramp(0.0, 0.0, (v_lo,), (0.0,), (), ())
        n = max(1, math.ceil((v_hi - v_lo) / self.band))
        u = [v_lo + (v_hi - v_lo) * i / n for i in range(n + 1)]
        w0 = self.window(anchor + direction * 1e-9)
        cover = [(w0, w0)] * n
        seen: dict = {}
        lim = [self._limits(w0, w0, u[i + 1], seen) for i in range(n)]
        for _ in range(len(self.windows) + 2):
            if any(a <= 0.0 or j <= 0.0 for a, j in lim):
                return None
            alpha = [0.0] * (n + 1)
            for i in range(1, n):  # what both bands allow, reachable from either end
                alpha[i] = min(lim[i - 1][0], lim[i][0],
                               math.sqrt(alpha[i - 1] ** 2 + 2.0 * lim[i - 1][1] * (u[i] - u[i - 1])))
            for i in range(n - 1, 0, -1):
                alpha[i] = min(alpha[i], math.sqrt(alpha[i + 1] ** 2
                                                   + 2.0 * lim[i][1] * (u[i + 1] - u[i])))
            pos, time, grown = anchor, 0.0, []
            for i in range(n):
                d, t = _band(u[i], alpha[i], u[i + 1], alpha[i + 1], *lim[i])
                end = pos + direction * d
                if (not -1e-9 <= end <= self._edges[-1] + 1e-9
                        or abs(end - anchor) > within * (1.0 + 1e-9)):
                    return None
                a, b = sorted((self.window(pos + direction * 1e-9),
                               self.window(end - direction * 1e-9)))
                grown.append((min(a, cover[i][0]), max(b, cover[i][1])))
                pos, time = end, time + t
            if grown == cover:
                return _Ramp(abs(pos - anchor), time, tuple(u), tuple(alpha),
                             tuple(a for a, _ in lim), tuple(j for _, j in lim))
            lim = [lim[i] if grown[i] == cover[i] else self._limits(*grown[i], u[i + 1], seen)
                   for i in range(n)]
            cover = grown
        return None

    def realise(self, ramp: _Ramp, direction: int, top: float, binding: str,
                label: str) -> list[Profile]:
        """ruckig profiles of the bands, in time order."""
        parts = []
        for i in range(len(ramp.a_max)):
            lim = PathLimits(top, ramp.a_max[i], ramp.j_max[i], binding)
            u0, u1, a0, a1 = ramp.u[i], ramp.u[i + 1], ramp.alpha[i], ramp.alpha[i + 1]
            parts.append(plan_velocity(u0, a0, u1, a1, lim, label) if direction > 0
                         else plan_velocity(u1, -a1, u0, -a0, lim, label))
        return parts if direction > 0 else parts[::-1]


def _boundary_speeds(ramps: _Ramps, reach: int) -> list[float]:
    """Backward and forward reachability passes over the window boundaries: the
    highest speed at each from which the run can still slow down in time and which it
    can reach in time, with speed changes spanning up to ``reach`` windows.

    Each boundary takes the best over the spans that end (or start) there.  The longest
    span is tried first, as it usually allows the most; a span that cannot even reach
    the best so far is passed over after one ramp instead of a search (its own search
    would end below that best, so the answer is the same)."""
    n, cum, caps = len(ramps.windows), ramps.cum, ramps.caps
    vb = [0.0] + [min(caps[k - 1], caps[k]) for k in range(1, n)] + [0.0]

    def better(best: float, fits, lo: float, hi: float) -> float:
        if hi <= best or (lo < best and not fits(best)):
            return best
        return max(best, _largest(fits, lo, hi, 20))

    for k in range(n - 1, -1, -1):  # backward: able to slow down in time
        best = 0.0
        for m in range(min(n, k + reach), k, -1):
            cap, length = min(caps[k:m]), cum[m] - cum[k]
            if cap < vb[m] * (1.0 - 1e-12):
                continue

            def fits(v: float, m=m, length=length) -> bool:
                return ramps.ramp(vb[m], v, cum[m], -1, length) is not None
            best = better(best, fits, min(vb[m], cap, vb[k]), min(vb[k], cap))
        vb[k] = min(vb[k], best)
    for m in range(1, n + 1):  # forward: able to speed up in time
        best = 0.0
        for k in range(max(0, m - reach), m):
            cap, length = min(caps[k:m]), cum[m] - cum[k]
            if cap < vb[k] * (1.0 - 1e-12):
                continue

            def fits(v: float, k=k, length=length) -> bool:
                return ramps.ramp(vb[k], v, cum[k], +1, length) is not None
            best = better(best, fits, min(vb[k], cap, vb[m]), min(vb[m], cap))
        vb[m] = min(vb[m], best)
    return vb


def _stretch(ramps: _Ramps, vb: list[float], k: int, m: int
             ) -> tuple[float, float, _Ramp, _Ramp] | None:
    """Fastest motion from boundary k to m between their speeds: speed up to the
    highest top speed that still leaves room to slow down, cruise, slow down.
    (time, top, up, down), or None if even the boundary speeds do not fit."""
    cum = ramps.cum
    length, cap = cum[m] - cum[k], min(ramps.caps[k:m])

    def build(top: float):
        up = ramps.ramp(vb[k], top, cum[k], +1, length)
        down = None if up is None else ramps.ramp(vb[m], top, cum[m], -1, length - up.length_mm)
        if down is None:
            return None
        return up, down

    low = max(vb[k], vb[m])
    if low > cap * (1.0 + 1e-9) or build(low) is None:
        return None
    top = _largest(lambda v: build(v) is not None, low, cap, 18)
    up, down = build(top)
    rest = max(length - up.length_mm - down.length_mm, 0.0)
    return up.duration_s + down.duration_s + (rest / top if top > 0 else 0.0), top, up, down


def _fastest_split(ramps: _Ramps, reach: int, label: str) -> list[Profile] | None:
    """Boundary speeds, then the split of the run into stretches of up to ``reach``
    windows (zero acceleration at the stretch ends) with the least total time, by
    dynamic programming over the boundaries; realised by ruckig.  None if no split
    fits the boundary speeds or ruckig's profiles do not cover the run."""
    n, cum = len(ramps.windows), ramps.cum
    vb = _boundary_speeds(ramps, reach)
    cost = [math.inf] * (n + 1)
    cost[0] = 0.0
    choice: list = [None] * (n + 1)
    for m in range(1, n + 1):
        for k in range(max(0, m - reach), m):
            if not cost[k] + (cum[m] - cum[k]) / min(ramps.caps[k:m]) < cost[m]:
                continue  # not even at its speed cap all the way would it be quicker
            found = _stretch(ramps, vb, k, m)
            if found is not None and cost[k] + found[0] < cost[m]:
                cost[m] = cost[k] + found[0]
                choice[m] = (k, found)
    if not math.isfinite(cost[n]):
        return None
    chosen, m = [], n
    while m > 0:
        k, found = choice[m]
        chosen.append((k, m, found))
        m = k
    parts = []
    for k, m, (_, top, up, down) in chosen[::-1]:
        binding = min((ramps.windows[w][1] for w in range(k, m)), key=lambda b: b.v_cap).binding
        rise = ramps.realise(up, +1, top, binding, label)
        fall = ramps.realise(down, -1, top, binding, label)
        covered = sum(p.length_mm for p in rise + fall)
        rest = cum[m] - cum[k] - covered
        if rest < -1e-9 * max(1.0, cum[m] - cum[k]):
            return None  # ruckig's profiles are longer than the band formula said
        if rest > 1e-12:
            rise.append(cruise_profile(rest, PathLimits(top, 0.0, 0.0, binding)))
        parts += rise + fall
    return parts


def plan_chain(windows: list[tuple[float, object]], label: str, reach: int = 8,
               band_mm_per_s: float = 8.0) -> ChainProfile:
    """Rest-to-rest over consecutive windows ``(length, budget)``.

    Boundary speeds come from backward and forward reachability passes in which a
    speed change may span up to ``reach`` windows; the run is then split into
    stretches of up to ``reach`` windows (speed up, cruise, slow down) and the split
    with the least total time is kept.  Every speed change is cut into bands of at
    most ``band_mm_per_s`` (see :class:`_Ramps`), each planned by ruckig with the
    limits of the windows it crosses at the speed it reaches.  Should no split fit
    (rounding at a boundary), the run is planned window by window at each window's
    constant limits, which always fits."""
    ramps = _Ramps(windows, band_mm_per_s)
    parts = _fastest_split(ramps, reach, label) if reach > 1 else None
    if parts is None:
        vb = _window_speeds(windows, ramps.cum)
        parts = []
        for k, (length, bud) in enumerate(windows):
            top = _peak(vb[k], vb[k + 1], length, bud, 0.98)
            parts.append(plan_state(length, vb[k], vb[k + 1], bud.limits(top), label))
    s0 = np.concatenate([[0.0], np.cumsum([p.length_mm for p in parts])[:-1]])
    t0 = np.concatenate([[0.0], np.cumsum([p.duration_s for p in parts])[:-1]])
    return ChainProfile(tuple(parts), frozen(s0), frozen(t0))


def _window_speeds(windows: list[tuple[float, object]], cum: np.ndarray,
                   slack: float = 0.98) -> np.ndarray:
    """Boundary speeds for the window-by-window fallback (constant limits per window)."""
    n = len(windows)
    caps = [min(windows[k - 1][1].v_cap, windows[k][1].v_cap) for k in range(1, n)]
    vb = np.array([0.0] + caps + [0.0])
    for k in range(n - 1, -1, -1):
        bud = windows[k][1]
        vb[k] = min(vb[k], _reachable(vb[k + 1], cum[k + 1] - cum[k], bud,
                                      min(vb[k], bud.v_cap), slack))
    for m in range(1, n + 1):
        bud = windows[m - 1][1]
        vb[m] = min(vb[m], _reachable(vb[m - 1], cum[m] - cum[m - 1], bud,
                                      min(vb[m], bud.v_cap), slack))
    return vb
