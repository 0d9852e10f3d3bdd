"""The timing a recording shows, run by run: where the machine stood still, which of the
program's dwells each still stretch is, and so when every run between two dwells began
and ended.

Every program dwells at known nodes between its runs, and a real set-up's centring
residual makes the reading wander while the ball moves and hold still while it stands:
the recording's still stretches (:func:`still_stretches`) are the dwells, whatever the
control did between them.  They are matched to the program's dwells in order
(:func:`match_dwells`: a run may take from half to four times its planned time, a
still stretch inside a run is skipped at a cost, and a run whose reading does not move
at all is carried inside one stretch), which places every run's start and end to the
resolution of the stillness test.  :func:`refine_runs` then moves each run's start and
end to where the model of the reading fits best, with the uncertainty the fit's
curvature gives (widened by the residual's correlation in time), or keeps the still
stretch's edge with the uncertainty of its resolution where the reading does not tell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..reading.context import sample_at
from ..reading.trace import block_means, standstill_floor
from ..timing.retime import Retiming
from .align import lsq, pinv_gram

#: the stillness test's block (s)
BLOCK_S = 0.1
#: how well the still stretches place a run's ends (s, one standard uncertainty)
PRIOR_S = 0.5
#: how much longer or shorter than programmed a dwell may last (s, one standard
#: uncertainty: a control's dwell follows its wall clock and waits for the axes)
DWELL_SLACK_S = 0.05
#: a run may take this share of its planned time at least, and at most
RATIO_RANGE = (0.5, 4.0)


@dataclass(frozen=True, slots=True)
class Stretch:
    """A still stretch of the recording (measured time, s)."""
    start_s: float
    end_s: float

    @property
    def length_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True, slots=True)
class RunTiming:
    """When each run of a program began and ended in the recording (measured time), with
    standard uncertainties; ``planned``: the runs' program-time starts and ends;
    ``told``: whether the reading placed each knot (False: the still stretch's edge)."""
    planned: tuple[tuple[float, float], ...]
    measured: tuple[tuple[float, float], ...]
    std_s: tuple[tuple[float, float], ...]
    told: tuple[tuple[bool, bool], ...]
    labels: tuple[tuple[str, str], ...]
    #: standard uncertainty of each run's duration (its ends' covariance included);
    #: empty: the ends taken as independent
    duration_std_s: tuple[float, ...] = ()

    def retiming(self, end_s: float) -> Retiming:
        """Program time to machine time (from the program's start): the first dwell as
        planned before the first run, the last after the last run, every run and dwell
        between as measured."""
        src, dst = [0.0], []
        for (a, b) in self.planned:
            src += [a, b]
        src.append(end_s)
        first = self.start_s()
        for (a, b) in self.measured:
            dst += [a - first, b - first]
        dst = [0.0, *dst, dst[-1] + end_s - self.planned[-1][1]]
        return Retiming(tuple(src), tuple(dst))

    def start_s(self) -> float:
        """Measured time of the program's start (the first dwell as planned)."""
        return self.measured[0][0] - self.planned[0][0]

    def durations(self) -> list[tuple[float, float, float]]:
        """Per run: planned duration, measured duration (s, measured clock), standard
        uncertainty of the measured one."""
        sd = self.duration_std_s or tuple(math.hypot(sa, sb) for sa, sb in self.std_s)
        return [(b - a, mb - ma, s) for (a, b), (ma, mb), s
                in zip(self.planned, self.measured, sd)]

    def placed_std_s(self) -> float:
        """How well the reading placed the runs: the median standard uncertainty of the
        runs' starts and ends (s, k=1)."""
        return float(np.median([v for pair in self.std_s for v in pair]))

    def as_table(self, planned_s: list[float] | None = None) -> list[dict]:
        """Per run: its first and last segment, the plan's duration (``planned_s``: the
        plan's own where the runs re-time a control's motion, whose duration is then
        ``model_s``), the measured one and its standard uncertainty, and whether the
        reading placed both its ends."""
        rows = []
        for k, ((f, t), (p, m, s), (ka, kb)) in enumerate(zip(self.labels, self.durations(),
                                                              self.told)):
            row = {"from": f, "to": t, "planned_s": round(p, 4)}
            if planned_s is not None and k < len(planned_s):
                row = {"from": f, "to": t, "planned_s": round(planned_s[k], 4),
                       "model_s": round(p, 4)}
            rows.append({**row, "measured_s": round(m, 4), "std_s": round(s, 4),
                         "told": bool(ka and kb)})
        return rows


def program_runs(samples) -> list[tuple[float, float, str, str]]:
    """The runs between standstills of a trajectory (a
    :class:`~sdit_path.timing.trajectory.Samples`): start, end (its time), first and
    last segment."""
    t_s = np.asarray(samples.t_s, float)
    phase = np.asarray(samples.phase, dtype=object)
    segment = np.asarray(samples.segment, dtype=object)
    moving = (phase != "dwell") & (phase != "reposition")
    edges = np.flatnonzero(np.diff(np.r_[0, moving.astype(int), 0]))
    return [(float(t_s[max(a - 1, 0)]), float(t_s[min(b, len(t_s) - 1)]), str(segment[a]),
             str(segment[b - 1])) for a, b in zip(edges[::2], edges[1::2])]


def still_stretches(t_m: np.ndarray, y: np.ndarray, noise_um: float, least_s: float,
                    window_s: float = 1.0) -> list[Stretch]:
    """Stretches of at least ``least_s`` where the reading stands still: every window of
    ``window_s`` (stepped by :data:`BLOCK_S`) whose straight-line fit has no slope the
    noise cannot explain (3 sigma) and whose scatter about it is
    the noise's (both on 50 ms means, out of which a steady vibration averages);
    overlapping still windows at one level join, a single window that fails between two
    at the same level is bridged (the test fails by chance now and then)."""
    if np.isfinite(y).sum() < 100:
        return []
    # on 50 ms means: a steady vibration of the structure averages out of them
    noise_um = standstill_floor(t_m, y, noise_um)
    t, v, _ = block_means(t_m, y)
    starts = np.arange(t[0], t[-1] - window_s, BLOCK_S)
    lo = np.searchsorted(t, starts)
    hi = np.searchsorted(t, starts + window_s)
    # per window, a line fit from cumulative sums
    c1 = np.r_[0.0, np.cumsum(t - t[0])]
    c2 = np.r_[0.0, np.cumsum((t - t[0]) ** 2)]
    cy = np.r_[0.0, np.cumsum(v)]
    cty = np.r_[0.0, np.cumsum((t - t[0]) * v)]
    cyy = np.r_[0.0, np.cumsum(v * v)]
    n = (hi - lo).astype(float)
    good = n >= 6
    n = np.maximum(n, 1.0)
    st, stt = c1[hi] - c1[lo], c2[hi] - c2[lo]
    sy, sty, syy = cy[hi] - cy[lo], cty[hi] - cty[lo], cyy[hi] - cyy[lo]
    sxx = np.maximum(stt - st * st / n, 1e-12)
    slope = (sty - st * sy / n) / sxx
    mean = sy / n
    resid = np.maximum(syy - sy * sy / n - slope * slope * sxx, 0.0) / np.maximum(n - 2, 1)
    slope_std = noise_um / np.sqrt(sxx)
    still = (good & (np.abs(slope) <= 3 * slope_std)
             & (np.sqrt(resid) <= 1.2 * noise_um + 0.01))
    # bridge single failures between two still windows at one level
    level_tol = 4 * noise_um / np.sqrt(n) + 0.02
    gap = ~still[1:-1] & still[:-2] & still[2:] & (np.abs(mean[:-2] - mean[2:]) <= level_tol[1:-1])
    still[1:-1] |= gap
    out: list[Stretch] = []
    i = 0
    while i < len(still):
        if not still[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(still) and still[j + 1] and abs(mean[j + 1] - mean[i:j + 1].mean()) \
                <= 2 * level_tol[j + 1]:
            j += 1
        out.append(Stretch(float(starts[i]), float(starts[j] + window_s)))
        i = j + 1
    return [s for s in out if s.length_s >= least_s]


def match_dwells(runs: list[tuple[float, float, str, str]], stretches: list[Stretch],
                 dwell_s: float) -> tuple[float, list[tuple[int, int]]] | None:
    """The cost of the best match and, for every run, the still stretches it leaves and
    reaches (indices), in order; None when the stretches do not fit the program's
    dwells at all (another program or plan).

    Dynamic programming over (dwell, stretch): dwell i (before run i; the last after
    the last run) sits in a stretch at least as late as dwell i-1's.  A run between
    two stretches costs the square of how far its log duration ratio lies from the
    common one (a control is often uniformly slower); a still stretch skipped inside a
    run costs its length over the dwell's; a run inside one still stretch (its reading
    did not move) costs a constant; a dwell in a stretch shorter than half the dwell
    costs (a ringing start)."""
    n, m = len(runs), len(stretches)
    if n == 0 or m < 2:
        return None
    planned = np.array([b - a for a, b, _, _ in runs])
    lo, hi = RATIO_RANGE
    best = None
    for common in _common_ratios(runs, stretches):
        path = _dp(planned, stretches, dwell_s, common, lo, hi)
        if path is not None and (best is None or path[0] < best[0]):
            best = path
    return best


def _common_ratios(runs, stretches) -> list[float]:
    """Candidate uniform time scales: the program's total motion against the recording's
    (first stretch's end to the last's start), and 1."""
    moving = sum(b - a for a, b, _, _ in runs)
    dwells = 0.0
    span = stretches[-1].start_s - stretches[0].end_s
    if len(runs) > 1:
        dwells = sum(runs[i + 1][0] - runs[i][1] for i in range(len(runs) - 1))
    est = (span - dwells) / max(moving, 1e-9)
    return sorted({1.0, float(np.clip(est, *RATIO_RANGE))})


def _dp(planned, stretches, dwell_s, common, lo, hi):
    n, m = len(planned), len(stretches)
    inf = math.inf
    # cost[i][j]: dwell i (i = 0..n) placed in stretch j
    cost = np.full((n + 1, m), inf)
    back = np.full((n + 1, m), -1, int)
    lengths = np.array([s.length_s for s in stretches]) / dwell_s
    # a dwell seen shorter than 3/4 of itself (a ringing start, a creeping end) costs;
    # a still stretch skipped inside a run costs little when short (a crawl whose
    # reading hardly moves), much when as long as a dwell
    short = np.where(lengths < 0.75, ((0.75 - lengths) / 0.25) ** 2 * 2.0, 0.0)
    skip = 10.0 * np.maximum(lengths - 0.5, 0.0) ** 2 + 0.2
    skipped = np.r_[0.0, np.cumsum(skip)]
    cost[0] = skipped[:m] * 4.0  # the program starts in the first still stretch
    for i in range(1, n + 1):
        for j in range(m):
            best, arg = inf, -1
            for a in range(j + 1):
                if not math.isfinite(cost[i - 1, a]):
                    continue
                if a == j:
                    # the run's reading did not move: it passed inside the stretch
                    c = cost[i - 1, a] + 6.0
                else:
                    d = stretches[j].start_s - stretches[a].end_s
                    r = d / planned[i - 1]
                    if not lo <= r <= hi:
                        continue
                    c = (cost[i - 1, a] + (math.log(r / common) / 0.7) ** 2
                         + skipped[j] - skipped[a + 1])
                if c < best:
                    best, arg = c, a
            if arg >= 0:
                cost[i, j] = best + (short[j] if 0 < i < n else 0.0)
                back[i, j] = arg
    # the program ends in the last still stretch (whatever stands still after it is
    # the recording's tail)
    end = cost[n] + (skipped[m] - skipped[1:m + 1]) * 4.0
    j = int(np.argmin(end))
    if not math.isfinite(end[j]):
        return None
    path = [j]
    for i in range(n, 0, -1):
        path.append(int(back[i, path[-1]]))
    path.reverse()
    return float(end[j]), [(path[i], path[i + 1]) for i in range(n)]


def first_timing(runs, stretches: list[Stretch], pairs: list[tuple[int, int]],
                 dwell_s: float) -> RunTiming | None:
    """Run starts and ends at the still stretches' edges (each dwell in the middle of
    its stretch); runs inside a stretch (their reading did not move) at their planned
    times from the nearest run the stretches place; None where the knots so placed do
    not follow one another."""
    planned = [(a, b) for a, b, _, _ in runs]
    # a still stretch holds its dwell and the slow first and last moments of the runs
    # either side (a run leaves and reaches its node at a crawl): the dwell sits about
    # in its middle
    inner = [stretches[j].length_s - dwell_s for (_, j) in pairs[:-1]]
    slop = float(np.median(np.clip(inner, 0.0, None))) / 2 if inner else 0.0

    def dwell_at(j: int) -> tuple[float, float]:
        st = stretches[j]
        if st.length_s <= dwell_s:
            return st.start_s, st.end_s
        mid = 0.5 * (st.start_s + st.end_s)
        return mid - dwell_s / 2, mid + dwell_s / 2

    meas: list[list[float]] = []
    std: list[tuple[float, float]] = []
    last = len(pairs) - 1
    for r, ((a, b), (i, j)) in enumerate(zip(planned, pairs)):
        if i == j:
            meas.append([math.nan, math.nan])
            std.append((math.nan, math.nan))
            continue
        start = stretches[i].end_s - slop if r == 0 else dwell_at(i)[1]
        end = stretches[j].start_s + slop if r == last else dwell_at(j)[0]
        meas.append([start, end])
        std.append((PRIOR_S, PRIOR_S))
    arr = np.array(meas)
    known = np.isfinite(arr[:, 0])
    if not known.any():
        return None
    p = np.array(planned)
    # runs inside a still stretch: placed at their planned times from the nearest run
    # the stretches place (before it, else after it)
    for k in np.flatnonzero(~known):
        before = [i for i in np.flatnonzero(known) if i < k]
        i = before[-1] if before else int(np.flatnonzero(known)[0])
        arr[k] = arr[i, 0] + (p[k] - p[i, 0])
        std[k] = (PRIOR_S, PRIOR_S)
    labels = tuple((f, t) for _, _, f, t in runs)
    return _checked(RunTiming(tuple(map(tuple, planned)),
                              tuple((float(a), float(b)) for a, b in arr), tuple(std),
                              tuple((bool(k), bool(k)) for k in known), labels))


def _checked(timing: RunTiming) -> RunTiming | None:
    """``timing`` if its knots follow one another (every run and every dwell between
    them lasting 50 ms or more), else None."""
    flat = np.array([v for ab in timing.measured for v in ab])
    return timing if np.all(np.diff(flat) > 0.05) else None


def anchored_timing(runs, start_s: float, rate: float) -> RunTiming:
    """Run starts and ends where a timing of the whole program puts them (the measured
    time of the program's start and the ratio of measured to program time): the start
    of a search that needs no still stretch."""
    planned = [(a, b) for a, b, _, _ in runs]
    return RunTiming(tuple(planned),
                     tuple((start_s + a * rate, start_s + b * rate) for a, b in planned),
                     tuple((PRIOR_S, PRIOR_S) for _ in planned),
                     tuple((True, True) for _ in planned),
                     tuple((f, t) for _, _, f, t in runs))


def fit_runs(timing: RunTiming, t_grid: np.ndarray, X: np.ndarray, t_m: np.ndarray,
             y: np.ndarray, dwell_s: float, duration_prior: float | None = None,
             iterations: int = 12, max_samples: int = 40_000,
             max_step_s: float = 0.3, widths_s: tuple[float, ...] = (1.0, 0.3, 0.1)
             ) -> tuple[RunTiming, float]:
    """Every run's measured start and end fitted together with the linear model ``X``
    (on the grid ``t_grid`` of the trajectory the runs re-time; pose-locked columns:
    they do not depend on the time law), Gauss-Newton.  Measured time maps to
    trajectory time piecewise linearly through the knots: moving a run's start
    stretches the whole run's content, so that the whole run, not its edge alone, says
    when it began.  Priors: the knots where they start (:data:`PRIOR_S`), every dwell
    as long as programmed (:data:`DWELL_SLACK_S`) and, with ``duration_prior``, every
    run as long as the time law says, to that share of it (a control's own planner's
    law: a quiet reading must not stretch a run by seconds to fit its noise).  The reading and the model are first
    compared smoothed over ``widths_s`` (a knot seconds off is in no reach of the
    unsmoothed reading's finest features), then as they are.  Returns the timing with
    the uncertainties of the knots (the model's columns projected out, the residual's
    correlation in time allowed for) and the fit's RMS (um)."""
    from scipy.ndimage import uniform_filter1d

    P = np.array([v for ab in timing.planned for v in ab], float)
    M = np.array([v for ab in timing.measured for v in ab], float)
    M0 = M.copy()
    nM = len(M)
    T = float(t_grid[-1])
    dt_g = float(np.median(np.diff(t_grid)))
    valid = np.flatnonzero(np.isfinite(y))
    if len(valid) < 100 or nM == 0:
        return timing, math.nan
    y_full = np.interp(np.arange(len(y)), valid, y[valid])
    dt_m = float(np.median(np.diff(t_m)))
    sub = valid[:: int(math.ceil(len(valid) / max_samples))]
    tm = t_m[sub]
    # priors as rows: knots near the still stretches' places, dwells as programmed
    rows = [np.eye(nM) / PRIOR_S]
    target = [M0 / PRIOR_S]
    if nM >= 4:
        D = np.zeros((nM // 2 - 1, nM))
        for r in range(nM // 2 - 1):
            D[r, 2 * r + 1], D[r, 2 * r + 2] = -1.0 / DWELL_SLACK_S, 1.0 / DWELL_SLACK_S
        rows.append(D)
        target.append(np.full(nM // 2 - 1, dwell_s / DWELL_SLACK_S))
    if duration_prior is not None:
        R = np.zeros((nM // 2, nM))
        d0 = P[1::2] - P[0::2]  # as long as the time law says (the clock's ppm aside)
        sd = duration_prior * d0 + 0.01
        for r in range(nM // 2):
            R[r, 2 * r], R[r, 2 * r + 1] = -1.0 / sd[r], 1.0 / sd[r]
        rows.append(R)
        target.append(d0 / sd)
    Pm, pt = np.vstack(rows), np.concatenate(target)

    def knots(Mv):
        return np.r_[Mv[0] - P[0], Mv, Mv[-1] + T - P[-1]], np.r_[0.0, P, T]

    def monotone(Mv):
        return bool(np.all(np.diff(knots(Mv)[0]) > 0.05))

    def evaluate(Mv, Xw, yw):
        tau = np.clip(np.interp(tm, *knots(Mv)), 0.0, T)
        A = sample_at(t_grid, Xw, tau)
        beta = lsq(A, yw)
        e = yw - A @ beta
        return tau, A, beta, e

    def jacobian(Mv, Xw, tau, beta):
        fd = sample_at(t_grid, np.gradient(Xw @ beta, t_grid), tau)
        xs, ys = knots(Mv)
        k = np.clip(np.searchsorted(xs, tm, side="right") - 1, 0, len(xs) - 2)
        dx, dy = xs[k + 1] - xs[k], ys[k + 1] - ys[k]
        r = np.clip((tm - xs[k]) / dx, 0.0, 1.0)
        J = np.zeros((len(tm), nM))
        at = np.arange(len(tm))
        for idx, g in ((k - 1, -fd * dy * (1 - r) / dx), (k, -fd * dy * r / dx)):
            sel = (idx >= 0) & (idx < nM)
            J[at[sel], idx[sel]] = g[sel]
        return J

    def objective(e, Mv, var):
        p = Pm @ Mv - pt
        return float(e @ e) / var + float(p @ p)

    for width in widths_s:
        if width > 0:
            Xw = uniform_filter1d(X, max(1, int(round(width / dt_g))), axis=0, mode="nearest")
            yw = uniform_filter1d(y_full, max(1, int(round(width / dt_m))), mode="nearest")[sub]
        else:
            Xw, yw = X, y_full[sub]
        tau, A, beta, e = evaluate(M, Xw, yw)
        # the residual's variance per independent sample: smoothed (and with what the
        # model lacks) neighbouring samples repeat each other, and the priors must not
        # be outweighed by a count of samples that are not independent
        var = max(_effective_variance(e), 1e-12)
        cur = objective(e, M, var)
        for _ in range(iterations):
            J = jacobian(M, Xw, tau, beta)
            JA = np.column_stack([A, J])
            G = JA.T @ JA / var
            g = JA.T @ e / var
            nA = A.shape[1]
            G[nA:, nA:] += Pm.T @ Pm
            g[nA:] -= Pm.T @ (Pm @ M - pt)
            step = np.clip((pinv_gram(G) @ g)[nA:], -max_step_s, max_step_s)
            moved = False
            for _half in range(6):
                trial = M + step
                if monotone(trial):
                    t_tau, t_A, t_beta, t_e = evaluate(trial, Xw, yw)
                    new = objective(t_e, trial, var)
                    if new < cur:
                        M, cur, moved = trial, new, True
                        tau, A, beta, e = t_tau, t_A, t_beta, t_e
                        break
                step = step / 2
            if not moved or np.max(np.abs(step)) < 1e-4:
                break
    # uncertainties at the last resolution (the linear columns projected out): finer
    # features than that - a control's chords, every one like the next - place a run's
    # ends to a millisecond modulo their period, and a fit cannot tell the periods apart
    J = jacobian(M, Xw, tau, beta)
    del Xw
    var = _effective_variance(e)
    H = (J.T @ J - J.T @ A @ pinv_gram(A.T @ A) @ A.T @ J) / var + Pm.T @ Pm
    cov = np.linalg.inv(H)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    half = nM // 2
    told = sd < 0.5 * PRIOR_S
    dur = tuple(math.sqrt(max(float(cov[2 * i, 2 * i] + cov[2 * i + 1, 2 * i + 1]
                                     - 2 * cov[2 * i, 2 * i + 1]), 0.0)) for i in range(half))
    out = RunTiming(timing.planned,
                    tuple((float(M[2 * i]), float(M[2 * i + 1])) for i in range(half)),
                    tuple((float(sd[2 * i]), float(sd[2 * i + 1])) for i in range(half)),
                    tuple((bool(told[2 * i]), bool(told[2 * i + 1])) for i in range(half)),
                    timing.labels, dur)
    return out, float(np.sqrt(np.mean(e * e)))


def _effective_variance(e: np.ndarray) -> float:
    """The residual's variance scaled by its correlation between neighbouring samples
    (an AR(1) effective sample count)."""
    rho = float(np.clip(np.corrcoef(e[:-1], e[1:])[0, 1], 0.0, 0.999)) if len(e) > 2 else 0.0
    return float(np.mean(e * e)) * (1 + rho) / (1 - rho)
