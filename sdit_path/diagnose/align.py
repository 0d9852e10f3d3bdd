"""Aligning a measured trace with the program: the recording offset and the
instrument's clock rate.

The instrument starts at an unknown moment before the program and runs on its own
clock (up to +-200 ppm off).  Measured time ``t_m`` and program time ``tau`` are
related by ``t_m = offset_s + tau * (1 + clock_ppm * 1e-6)``.

Coarse: at 10 Hz, for every clock rate on a grid and every offset, a linear model of
the features every trace shares - the simulated reading, the dwell/motion pattern of
the static nodes (a step in the reading when motion starts: lag, smoothing), the bar
direction (set-up offsets) and a constant - is fitted by FFT correlations; the best
(offset, rate) wins.  Fine: Gauss-Newton on the offset and rate at the full rate with
the same model.  Before the program and after it the machine stands at its first and
last pose.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import RecordingError
from ..reading.context import Context, sample_at, sample_made
from ..reading.rows import gradient_rows
from .tall import Made, RowModel, is_tall


class AlignmentError(RecordingError):
    """The recording cannot be aligned to its program."""


@dataclass(frozen=True, slots=True)
class Alignment:
    offset_s: float
    clock_ppm: float
    offset_std_s: float
    clock_std_ppm: float
    rms_um: float
    #: why the uncertainties are wider than the fit's own (one line each)
    widened_by: tuple[str, ...] = ()

    def program_time(self, t_m: np.ndarray) -> np.ndarray:
        return (np.asarray(t_m) - self.offset_s) / (1.0 + self.clock_ppm * 1e-6)

    def measured_time(self, tau: np.ndarray) -> np.ndarray:
        return self.offset_s + np.asarray(tau) * (1.0 + self.clock_ppm * 1e-6)


def timing_is_weak(al: Alignment, offset_s: float = 0.002, clock_ppm: float = 5.0) -> bool:
    """The recording's timing is known worse than ``offset_s`` or ``clock_ppm``."""
    return not (al.offset_std_s <= offset_s and al.clock_std_ppm <= clock_ppm)



#: the documented contract: a recorder's clock within this many ppm of the control's
CLOCK_LIMIT_PPM = 200.0


def generic_columns(ctx: Context, expected_um: np.ndarray,
                    extra: np.ndarray | list[np.ndarray] | None = None,
                    consume: bool = False) -> np.ndarray:
    """``(n, m)`` on the trajectory grid: expected reading (if it varies), constant,
    bar direction, a smoothed motion indicator, -v^2/(2L), time, the reading of the
    axes' accelerations and a step at each reversal of every linear axis.

    Every machine lags.  An equal lag of every axis is a later start up to its second
    order, which follows the axes' accelerations (a first-order lag tau leaves
    tau^2 * a / 2 beyond the pure delay) and the path's curvature (v^2 / (2 L)); on a
    slow program whose reading hardly moves (a 5-axis test at 10 mm/s: 0.4 um/s) that
    remainder, a tenth of a micrometre, otherwise pulls the clock to the end of its
    range.  ``extra``: more columns, or blocks of them (stacked here once); with
    ``consume``, a list of blocks nothing else holds, emptied here and each block let go
    once copied (tall ones: the blocks and the model are not held whole at once)."""
    base, spread = _generic_base(ctx)
    blocks, spreads = [base], [spread]
    if np.ptp(expected_um) > 1e-3:
        blocks.insert(0, np.asarray(expected_um, float)[:, None])
        spreads.insert(0, np.ptp(blocks[0], axis=0))
    parts = extra if isinstance(extra, list) else [] if extra is None else [extra]
    generic = len(blocks)
    for part in parts:
        if is_tall(part):  # made where read (a long program's geometry)
            blocks.append(part)
            spreads.append(part.spread())
            continue
        part = np.asarray(part, float).reshape(ctx.n, -1)
        blocks.append(part)
        # every column's spread at once (row-major: column by column reads the whole
        # matrix once per column)
        spreads.append(np.ptp(part, axis=0))
    part = None  # (the loop's last block: held here, it could not be let go below)
    if consume and isinstance(extra, list):
        extra.clear()
    keep = np.concatenate(spreads) > 1e-9
    keep[0] = True
    if any(is_tall(b) for b in blocks):
        return RowModel(blocks, keep, generic)  # type: ignore[return-value]
    # the kept columns written into one matrix (tall: no second copy to drop columns
    # from), laid out as numpy lays out the columns it picks: by column where some are
    # dropped (the products with it, and so every alignment, are the same to the bit)
    X = np.empty((ctx.n, int(keep.sum())), order="C" if keep.all() else "F")
    at = col = 0
    for b in range(len(blocks)):
        block, blocks[b] = blocks[b], None  # (let go once copied, where consumed)
        kept = keep[at:at + block.shape[1]]
        at += block.shape[1]
        if kept.all():
            X[:, col:col + block.shape[1]] = block
            col += block.shape[1]
            continue
        for j in np.flatnonzero(kept):  # one by one: picking them would copy the block
            X[:, col] = block[:, j]
            col += 1
    return X


def _generic_base(ctx: Context) -> tuple[np.ndarray, np.ndarray]:
    """The generic columns that depend on the program alone, and their spreads (made
    once per context: the timing searches build the model dozens of times; on a tall
    program made where they are read, 11 columns on every sample being 0.3 GB an
    hour)."""
    key = ("generic",)
    if key not in ctx.cache:
        mov = ctx.moving.astype(float)
        k = max(1, int(round(0.02 / max(float(np.median(np.diff(ctx.t_s))), 1e-6))))
        mov = np.convolve(mov, np.ones(k) / k, mode="same")
        if ctx.tall:
            base = Made(ctx.n, lambda idx: _generic_rows(ctx, mov, idx))
            ctx.cache[key] = (base, base.spread())
            return ctx.cache[key]
        cols = [np.ones(ctx.n), ctx.u[:, 0], ctx.u[:, 1], ctx.u[:, 2], mov,
                -(ctx.speed_mm_per_s ** 2) / (2 * ctx.length_mm) * 1e3, ctx.t_s / 3600.0,
                _axis_acceleration_reading(ctx)]
        cols += [ctx.gain[:, j] * ctx.direction[:, j] for j in ctx.linear if j in ctx.observable]
        base = np.column_stack(cols)
        base.setflags(write=False)
        ctx.cache[key] = (base, np.ptp(base, axis=0))
    return ctx.cache[key]


def _generic_rows(ctx: Context, mov: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The rows ``idx`` of :func:`_generic_base`'s columns (the same arithmetic)."""
    u, g, d = ctx.u[idx], ctx.gain[idx], ctx.direction[idx]
    cols = [np.ones(len(idx)), u[:, 0], u[:, 1], u[:, 2], mov[idx],
            -(ctx.speed_mm_per_s[idx] ** 2) / (2 * ctx.length_mm[idx]) * 1e3,
            ctx.t_s[idx] / 3600.0, axis_acceleration_readings(ctx, idx).sum(axis=1)]
    cols += [g[:, j] * d[:, j] for j in ctx.linear if j in ctx.observable]
    return np.column_stack(cols)


def axis_acceleration_readings(ctx: Context, idx: np.ndarray | None = None) -> np.ndarray:
    """``(n, k)``: gain_j * qddot_j of each observable axis j, what an error following
    that axis' acceleration reads (um per unit, scaled later); at the samples ``idx``
    only if given (the same numbers)."""
    obs = list(ctx.observable)
    if len(ctx.t_s) < 3 or not obs:
        return np.zeros((ctx.n if idx is None else len(idx), 0))
    if idx is None:
        return ctx.gain[:, obs] * np.gradient(ctx.qdot[:, obs], ctx.t_s, axis=0)
    return ctx.gain[idx][:, obs] * gradient_rows(ctx.t_s, ctx.uniform_step(),
                                                 lambda i: ctx.qdot[i][:, obs], idx)


def _axis_acceleration_reading(ctx: Context) -> np.ndarray:
    """sum_j gain_j * qddot_j: what equal accelerations of every axis' error read."""
    return axis_acceleration_readings(ctx).sum(axis=1)


def _block_mean(x: np.ndarray, w: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted means of ``x`` over index blocks [edges[i], edges[i+1])."""
    return _block_mean_of(_running_sums(x, w), edges)


def _running_sums(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The running sums of ``x * w`` and of ``w`` from 0 (what :func:`_block_mean` reads
    any blocks' means from)."""
    return np.r_[0.0, np.cumsum(np.where(w > 0, x, 0.0) * w)], np.r_[0.0, np.cumsum(w)]


def _block_mean_of(sums: tuple[np.ndarray, np.ndarray], edges: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_block_mean` from the running sums (:func:`_running_sums`)."""
    cx, cw = sums
    sx = cx[edges[1:]] - cx[edges[:-1]]
    sw = cw[edges[1:]] - cw[edges[:-1]]
    return np.where(sw > 0, sx / np.maximum(sw, 1e-12), 0.0), sw


def column_rms(X: np.ndarray, width: int = 8) -> np.ndarray:
    """``sqrt(mean(X * X, axis=0))`` to the bit, squaring ``width`` columns at a time
    (numpy sums a block of three or more columns row by row, as it sums the whole
    matrix; so the last block takes the columns before it too)."""
    m = X.shape[1]
    if m < 3:
        return np.sqrt(np.mean(X * X, axis=0))
    out = np.empty(m)
    for a in range(0, m, width):
        b = min(a + width, m)
        lo = min(a, max(b - width, 0))
        out[a:b] = np.sqrt(np.mean(X[:, lo:b] * X[:, lo:b], axis=0))[a - lo:]
    return out


#: the coarse search correlates directly (a matrix product) when offsets x program
#: blocks is at most this many times the transform length (the product is several times
#: faster up to a few hundred offsets, and slower beyond)
DIRECT_CORRELATION = 200


def coarse(ctx: Context, X: np.ndarray, t_m: np.ndarray, y: np.ndarray,
           ppm_limit: float = CLOCK_LIMIT_PPM, block_s: float = 0.1, drift_s: float = 0.01,
           candidates: int = 1, apart_s: float = 0.25
           ) -> list[tuple[float, float]]:
    """The best (offset_s, clock_ppm) on a grid, best first: offsets at ``block_s``,
    rates at a step that keeps the drift over the program under ``drift_s``.  With
    ``candidates`` > 1, that many distinct minima (offsets at least ``apart_s`` apart):
    at 10 Hz and on a rate grid the true alignment can lose to a near-equal other one,
    which the full-rate fit then tells apart."""
    T = ctx.duration_s
    dt_p = float(np.median(np.diff(ctx.t_s)))
    per = max(1, int(round(block_s / dt_p)))
    nb = ctx.n // per
    if nb < 4:
        raise AlignmentError("program too short to align")
    edges_p = np.arange(nb + 1) * per
    # columns at unit RMS: the small ridge that keeps the solves regular must not
    # penalise a column for its units (it biases the search by tenths of a second)
    # (the scaled matrix and its squares would be two more copies of a tall one)
    if isinstance(X, RowModel):  # (made a block of rows at a time)
        unit = np.maximum(X.column_rms(), 1e-12)
        Xb = X.block_means(per, nb, unit)
    else:
        unit = np.maximum(column_rms(X), 1e-12)
        Xb = np.column_stack([_block_mean(X[:, a] / unit[a], np.ones(ctx.n), edges_p)[0]
                              for a in range(X.shape[1])])
    x0, xT = X[0] / unit, X[-1] / unit
    valid = np.isfinite(y)
    # the recording's running sums, read by every rate (made there, they were six arrays
    # of the recording's length a rate)
    sums = _running_sums(np.where(valid, y, 0.0), valid.astype(float))
    step_ppm = max(1.0, drift_s / max(T, 1e-9) * 1e6)
    rates = np.arange(-ppm_limit, ppm_limit + 0.5 * step_ppm, step_ppm)
    dt_m = float(np.median(np.diff(t_m)))
    found: list[tuple[float, float, float]] = []
    m = X.shape[1]
    # every correlation at once: in the frequency domain (the program side the same at
    # every rate) or, when the recording holds few more blocks than the program (a lead
    # of seconds: a few hundred offsets), as one product with the windows of the
    # recording's blocks, several times faster than the transforms
    n_max = int((t_m[-1] - t_m[0]) / (per * dt_p * (1 - ppm_limit * 1e-6))) + 1
    nfft = sfft.next_fast_len(n_max + nb)
    ia, ic = np.triu_indices(m)
    XXb = Xb[:, ia] * Xb[:, ic]
    direct = (n_max - nb + 1) * nb <= DIRECT_CORRELATION * nfft
    if not direct:
        Fx = np.conj(sfft.rfft(Xb, nfft, axis=0))
        Fxx = np.conj(sfft.rfft(XXb, nfft, axis=0))
    for ppm in rates:
        d = per * dt_p * (1 + ppm * 1e-6)  # one program block in instrument time
        n_m = int((t_m[-1] - t_m[0]) / d)
        if n_m < nb:
            continue
        edges_m = np.clip(np.round((t_m[0] + np.arange(n_m + 1) * d - t_m[0]) / dt_m).astype(int),
                          0, len(y))
        yb, wb = _block_mean_of(sums, edges_m)
        wb = wb / max(wb.max(), 1e-12)
        wy = wb * yb
        L = n_m - nb + 1
        if direct:  # b[j] = sum_i wy[j + i] Xb[i], g likewise
            b = sliding_window_view(wy, nb)[:L] @ Xb
            g = sliding_window_view(wb, nb)[:L] @ XXb
        else:
            b = sfft.irfft(sfft.rfft(wy, nfft)[:, None] * Fx, nfft, axis=0)[:L]
            g = sfft.irfft(sfft.rfft(wb, nfft)[:, None] * Fxx, nfft, axis=0)[:L]
        G = np.empty((L, m, m))
        G[:, ia, ic] = g
        G[:, ic, ia] = g
        j = np.arange(len(b))
        cw = np.r_[0.0, np.cumsum(wb)]
        cwy = np.r_[0.0, np.cumsum(wy)]
        pre_w, pre_y = cw[j], cwy[j]
        post_w, post_y = cw[-1] - cw[j + nb], cwy[-1] - cwy[j + nb]
        G += pre_w[:, None, None] * np.outer(x0, x0) + post_w[:, None, None] * np.outer(xT, xT)
        b += pre_y[:, None] * x0 + post_y[:, None] * xT
        G += np.eye(m) * (1e-9 * np.trace(G, axis1=1, axis2=2)[:, None, None] + 1e-12)
        beta = np.linalg.solve(G, b[..., None])[..., 0]
        rss = float((wb * yb * yb).sum()) - np.einsum("ja,ja->j", b, beta)
        # this rate's lowest local minima
        inner = np.flatnonzero((rss[1:-1] <= rss[:-2]) & (rss[1:-1] <= rss[2:])) + 1
        ends = [i for i in (0, len(rss) - 1) if len(rss) == 1 or
                rss[i] <= rss[1 if i == 0 else i - 1]]
        for k in sorted(np.r_[inner, ends].astype(int), key=lambda i: rss[i])[:candidates]:
            frac = 0.0
            if 0 < k < len(rss) - 1:
                den = rss[k - 1] - 2 * rss[k] + rss[k + 1]
                frac = 0.5 * (rss[k - 1] - rss[k + 1]) / den if den > 0 else 0.0
            found.append((float(rss[k]), (k + frac) * d + float(t_m[0]), float(ppm)))
    if not found:
        raise AlignmentError("the trace is shorter than the program at every clock rate")
    best: list[tuple[float, float]] = []
    for _, off, ppm in sorted(found):
        if all(abs(off - o) >= apart_s for o, _ in best):
            best.append((off, ppm))
            if len(best) == candidates:
                break
    return best


def pinv_gram(G: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Pseudo-inverse of a Gram matrix (columns scaled to unit norm first, so that the
    cut-off is about the columns' directions, not their units)."""
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    w, V = np.linalg.eigh(G / np.outer(d, d))
    keep = w > rcond * max(float(w[-1]), 1e-300)
    return (V[:, keep] / w[keep]) @ V[:, keep].T / np.outer(d, d)


def lsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares through the normal equations (rank-revealing): the same answer as
    ``lstsq`` for the well-scaled, tall problems here, several times faster."""
    return pinv_gram(A.T @ A) @ (A.T @ y)


def _fit_rms(X, t, tm, yy, offset_s, k):
    tau = np.clip((tm - offset_s) / (1 + k), t[0], t[-1])
    Xs = sample_at(t, X, tau)
    beta = lsq(Xs, yy)
    r = yy - Xs @ beta
    return float(np.sqrt(np.mean(r * r))), tau, Xs, beta


def _rate_at(ctx: Context, X: np.ndarray, beta: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``sample_at(t, np.gradient(X @ beta, t), tau)``: the model's rate at the program
    times ``tau``.  A tall model's product is made only at the rows that reads and their
    neighbours (a pass over every row of a long program makes every column again)."""
    t = ctx.t_s
    if not isinstance(X, RowModel):
        return sample_at(t, np.gradient(X @ beta, t), tau)

    def rates(need):
        around = np.unique(np.clip(np.r_[need - 1, need, need + 1], 0, ctx.n - 1))
        f = X.product_at(around, beta)[:, None]
        return gradient_rows(t, ctx.uniform_step(), lambda r: f[np.searchsorted(around, r)],
                             need)[:, 0]

    return sample_made(t, tau, rates)


def _timing_std(JJ: np.ndarray, r: np.ndarray) -> tuple[float, float]:
    """Standard uncertainties of the last two columns of ``J`` (given as ``JJ = J.T @ J``;
    offset in s, clock in ppm) with the model columns before them projected out (rank-revealing, so that
    redundant model columns cannot make them singular), the residual variance inflated
    by the residual's correlation in time (an effective sample count), so that a
    structured residual does not pass as thousands of independent samples.  Timing
    the data cannot see at all gets a bound, not infinity: 1 s and 1000 ppm."""
    n = len(r)
    rho = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.999)) if n > 2 else 0.0
    var = float(np.mean(r * r)) * (1 + rho) / (1 - rho)
    M = JJ[-2:, -2:] - JJ[-2:, :-2] @ pinv_gram(JJ[:-2, :-2]) @ JJ[:-2, -2:]
    bounds = (1.0, 1000.0)
    try:
        cov = np.linalg.inv(M) * var
        return tuple(float(min(np.sqrt(max(cov[i, i], 0.0)), b)) for i, b in enumerate(bounds))
    except np.linalg.LinAlgError:
        return bounds


def _rows_read(y: np.ndarray, max_samples: int) -> np.ndarray:
    """The samples of ``y`` :func:`refine` reads: the finite ones, at most
    ``max_samples`` of them drawn at random (seeded: the same every time)."""
    valid = np.flatnonzero(np.isfinite(y))
    if len(valid) > max_samples:
        valid = np.sort(np.random.default_rng(0).choice(valid, max_samples, replace=False))
    return valid


def coefficients_at(ctx: Context, X: np.ndarray, t_m: np.ndarray, y: np.ndarray,
                    al: Alignment, max_samples: int = 120_000) -> np.ndarray:
    """The linear model ``X``'s coefficients at the timing ``al`` on the samples
    :func:`refine` reads (with the same ``max_samples``): the fit it ended with."""
    valid = _rows_read(y, max_samples)
    return _fit_rms(X, ctx.t_s, t_m[valid], y[valid], al.offset_s, al.clock_ppm * 1e-6)[3]


def refine(ctx: Context, X: np.ndarray, t_m: np.ndarray, y: np.ndarray, offset_s: float,
           ppm: float, ppm_limit: float = CLOCK_LIMIT_PPM, iterations: int = 8,
           max_samples: int = 120_000, max_step_s: float = 0.05, check: bool = True,
           tolerance: float = 0.01) -> Alignment:
    """Gauss-Newton on (offset, rate) with the linear model ``X`` at the full rate;
    a step that does not lower the residual is halved, the rate stays within
    ``ppm_limit`` (a rate that ends at that edge gets the uncertainty of the whole range).
    It stops when a step would move the offset and the rate by less than ``tolerance``
    of their standard uncertainties (see :func:`_negligible`)."""
    valid = _rows_read(y, max_samples)
    tm, yy = t_m[valid], y[valid]
    t = ctx.t_s
    T = t[-1]
    k = ppm * 1e-6
    kmax = ppm_limit * 1e-6
    std = (np.inf, np.inf)
    rms, tau, Xs, beta = _fit_rms(X, t, tm, yy, offset_s, k)
    for _ in range(iterations):
        fd = _rate_at(ctx, X, beta, tau)
        raw = (tm - offset_s) / (1 + k)
        inside = (raw > t[0]) & (raw < T)
        # d tau / d offset = -1/(1+k); d tau / d k = -tau/(1+k)
        J = np.column_stack([Xs, -fd * inside / (1 + k), -fd * tau * inside / (1 + k) * 1e-6])
        JJ = J.T @ J  # once for the step and its uncertainty
        sol = pinv_gram(JJ) @ (J.T @ yy)
        r = yy - Xs @ beta
        # (tall, and not read again: the trials below make their own)
        del J, Xs
        std = _timing_std(JJ, r)
        d_off = float(np.clip(sol[-2], -max_step_s, max_step_s))
        d_k = float(sol[-1]) * 1e-6
        if _negligible(d_off, d_k, std, tolerance):
            break
        for _half in range(6):
            k_new = float(np.clip(k + d_k, -kmax, kmax))
            trial = _fit_rms(X, t, tm, yy, offset_s + d_off, k_new)
            if trial[0] <= rms:
                break
            d_off, d_k = d_off / 2, d_k / 2
        else:
            break
        offset_s, k = offset_s + d_off, k_new
        rms, tau, Xs, beta = trial
        if abs(d_off) < 1e-6 and abs(d_k) < 1e-8:
            break
    if check:
        std = _consistency(X, t, tm, yy, offset_s, k, std)
    if abs(k) >= kmax * (1 - 1e-3):
        std = _at_bound(t, X @ beta, tau, std, ppm_limit)
    return Alignment(offset_s, k * 1e6, std[0], std[1], rms)


def _negligible(d_off: float, d_k: float, std: tuple[float, float], tolerance: float) -> bool:
    """Is a Gauss-Newton step of ``d_off`` s and ``d_k`` (relative rate) below
    ``tolerance`` of the standard uncertainties ``std`` (s, ppm)?  Never more than 0.1 ms
    and 0.1 ppm (an uncertainty at its bound says the data do not see the timing, not
    that any step is small), never less than 1 us and 0.01 ppm (below that the steps
    chase rounding: the residual agrees to eight digits while the search goes on
    halving sub-microsecond steps)."""
    off_tol = max(1e-6, min(tolerance * std[0], 1e-4))
    ppm_tol = max(0.01, min(tolerance * std[1], 0.1))
    return abs(d_off) <= off_tol and abs(d_k) * 1e6 <= ppm_tol


def _at_bound(t: np.ndarray, f: np.ndarray, tau: np.ndarray, std: tuple[float, float],
              ppm_limit: float) -> tuple[float, float]:
    """Uncertainties of a clock rate that ended at the edge of the documented range.

    The residual still falls beyond the range, so the rate is not where the data put
    it but where the contract stopped it: the model misses something that a clock
    error mimics.  The truth is then anywhere in the range: the rate's uncertainty is
    that of a uniform spread over twice the range (the estimate at one edge, the truth
    possibly at the other), and the offset, which the data tie to the rate at the
    program time where the timing information lies (its centroid), inherits it."""
    fd = sample_at(t, np.gradient(f, t), tau)
    w = fd * fd
    tau_c = float(np.sum(w * tau) / max(float(np.sum(w)), 1e-300))
    clk = 2 * ppm_limit / np.sqrt(3.0)
    off = float(np.hypot(std[0], tau_c * clk * 1e-6))
    return min(max(off, std[0]), 1.0), max(std[1], clk)


def _window_shift(tw: np.ndarray, t: np.ndarray, X: np.ndarray, yw: np.ndarray,
                  shifts: np.ndarray) -> tuple[float, float]:
    """Best time shift of one stretch (program time ``tw - shift``) and its standard
    uncertainty from the curvature of the residual (infinite where the residual is
    flat or the best shift lies at the edge of the search)."""
    rss = np.empty(len(shifts))
    for i, d in enumerate(shifts):
        A = sample_at(t, X, tw - d)
        beta = lsq(A, yw)
        r = yw - A @ beta
        rss[i] = float(r @ r)
    j = int(np.argmin(rss))
    if not 0 < j < len(rss) - 1:
        return float(shifts[j]), np.inf
    h = float(shifts[1] - shifts[0])
    den = rss[j - 1] - 2 * rss[j] + rss[j + 1]
    if den <= 0:
        return float(shifts[j]), np.inf
    var = rss[j] / max(len(yw) - X.shape[1] - 1, 1)
    frac = 0.5 * (rss[j - 1] - rss[j + 1]) / den
    return float(shifts[j] + frac * h), float(np.sqrt(2 * var * h * h / den))


def _consistency(X: np.ndarray, t: np.ndarray, tm: np.ndarray, yy: np.ndarray,
                 offset_s: float, k: float, std: tuple[float, float], windows: int = 8,
                 half_s: float = 0.1, step_s: float = 0.004, per_window: int = 3000
                 ) -> tuple[float, float]:
    """Uncertainties that also hold when the model misses something.

    The program is cut into ``windows`` stretches and each one's time shift is searched
    on its own.  A model that explains the recording puts every stretch at shift 0
    within its noise; unmodelled effects pull stretches apart, or all of them off the
    global alignment.  A straight line through the shifts (weighted, in program time)
    measures both: its scatter scales its own uncertainty, and its value at 0 and its
    slope - how far the stretches say the global offset and clock are off - are added
    to the uncertainties (never subtracted: a stated uncertainty only grows)."""
    tau = (tm - offset_s) / (1 + k)
    # each stretch shifts the whole model as fitted (one scale): refitting every column
    # on every stretch would throw away what the stretches share, and the stretches'
    # scatter would then state the timing ten to a hundred times worse than it is
    f = (X @ lsq(sample_at(t, X, np.clip(tau, t[0], t[-1])), yy))[:, None]
    edges = np.linspace(t[0], t[-1], windows + 1)
    grid = np.arange(-half_s, half_s + step_s / 2, step_s)
    c, d, sd = [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = np.flatnonzero((tau >= a + half_s) & (tau < b - half_s))
        if len(sel) < 100:
            continue
        sel = sel[:: max(1, len(sel) // per_window)]
        shift, s = _window_shift(tau[sel], t, f, yy[sel], grid)
        if np.isfinite(s):
            c.append(0.5 * (a + b))
            d.append(shift)
            sd.append(max(s, 1e-5))
    if len(d) < 3:
        return std
    c, d, w = np.array(c), np.array(d), 1.0 / np.array(sd) ** 2
    A = np.column_stack([np.ones(len(c)), c])
    cov = np.linalg.pinv(A.T @ (A * w[:, None]))
    coef = cov @ (A.T @ (w * d))
    chi2 = float(np.sum(w * (d - A @ coef) ** 2)) / max(len(d) - 2, 1)
    scale = max(1.0, chi2)
    off = float(np.sqrt(std[0] ** 2 + cov[0, 0] * scale + coef[0] ** 2))
    clk = float(np.sqrt(std[1] ** 2 + (cov[1, 1] * scale + coef[1] ** 2) * 1e12))
    return min(off, 1.0), min(clk, 1000.0)


def check_span(span_s: float, program_s: float, ppm_limit: float = CLOCK_LIMIT_PPM) -> None:
    """A recording must last at least its program and not absurdly longer (a recording
    of another program, or times written in milliseconds)."""
    if span_s < program_s * (1 - ppm_limit * 1e-6):
        raise AlignmentError(f"the trace lasts {span_s:.3f} s, the program {program_s:.3f} s: "
                             f"the recording is shorter than the program")
    if span_s > 2.0 * program_s + 120.0:
        raise AlignmentError(f"the trace lasts {span_s:.6g} s, the program {program_s:.3f} s: "
                             f"far longer than the program (another program's recording, or "
                             f"times in milliseconds?)")


#: programs longer than this are searched globally with the generic columns only
COARSE_ALL_COLUMNS_S = 1200.0


def align(ctx: Context, expected_um: np.ndarray, t_m: np.ndarray, y: np.ndarray,
          ppm_limit: float = CLOCK_LIMIT_PPM,
          extra: np.ndarray | Callable[[], np.ndarray] | None = None, candidates: int = 5,
          seeds: tuple[tuple[float, float], ...] = (), model: np.ndarray | None = None,
          search: bool = True, noise_um: float | None = None) -> Alignment:
    """The global search (``candidates`` distinct minima, plus ``seeds``: alignments
    found before) polished at the full rate; the lowest residual wins.  ``extra``:
    columns beside the generic ones, or what makes them (called once).  ``model``:
    ``generic_columns(ctx, expected_um, extra)`` if the caller has it already; without
    ``search``, only the seeds are polished.  With ``noise_um`` (the recording's
    noise), a searched result that leaves more than ``LOCAL_SCAN_EXPLAINED`` times it
    is checked against its neighbourhood (:func:`local_scan`)."""
    if callable(extra):  # made here and let go as X is filled (tall: see alignment_blocks)
        X = generic_columns(ctx, expected_um, extra(), consume=True) if model is None else model
        extra = True
    else:
        X = generic_columns(ctx, expected_um, extra) if model is None else model
    check_span(t_m[-1] - t_m[0], ctx.duration_s, ppm_limit)
    valid = int(np.isfinite(y).sum())
    if valid < max(1000, 0.5 * len(y)):
        raise AlignmentError(f"only {valid} of {len(y)} samples hold a reading (the rest are "
                             f"dropouts); at least half are needed")
    # the global search with every column costs (columns)^2 correlations per clock rate:
    # on long programs (an hour at a crawl) it searches with the generic columns only
    # and the full model polishes
    few = extra is not None and ctx.duration_s > COARSE_ALL_COLUMNS_S
    if search or not seeds:
        # (a tall model's generic part: the same columns, made where read)
        generic = (X.generic_part() if isinstance(X, RowModel) else
                   generic_columns(ctx, expected_um)) if few else X
        found = coarse(ctx, generic, t_m, y, ppm_limit, candidates=candidates)
        generic = None
    else:
        found = []
    found = [*found, *[s for s in seeds
                       if all(abs(s[0] - o) >= 0.005 or abs(s[1] - p) > 1.0 for o, p in found)]]
    if len(found) > 1:
        # the candidates told apart at the full rate (a few polishing steps each)
        trial = [refine(ctx, X, t_m, y, off, ppm, ppm_limit, iterations=3,
                        max_samples=30_000, check=False) for off, ppm in found]
        best = min(trial, key=lambda a: a.rms_um)
        found = [(best.offset_s, best.clock_ppm)]
    al = refine(ctx, X, t_m, y, *found[0], ppm_limit)
    if search and noise_um is not None and al.rms_um > LOCAL_SCAN_EXPLAINED * noise_um:
        al = local_scan(ctx, X, t_m, y, al, ppm_limit)
    return al


#: a searched alignment whose residual is within this factor of the noise explains the
#: recording: no neighbour can fit better by more than the noise
LOCAL_SCAN_EXPLAINED = 1.15


def local_scan(ctx: Context, X: np.ndarray, t_m: np.ndarray, y: np.ndarray, al: Alignment,
                ppm_limit: float, half_s: float = 0.032, step_s: float = 0.004,
                half_ppm: float = 60.0, step_ppm: float = 20.0, samples: int = 5000
                ) -> Alignment:
    """The neighbourhood of a polished alignment that does not explain the recording,
    scanned on a grid (offsets ``half_s`` either side, rates ``half_ppm``) on an even
    subsample; the best point, polished in full, replaces ``al`` if it fits better.

    The global search places the start to a block of 0.1 s and the rate to its grid
    (100 ppm on a 95 s program), and Gauss-Newton from there stops in the nearest
    minimum.  With reversal-locked shapes in the model the residual has minima a few
    ms apart: a large play is polished into one of them, tens of ms and ppm from the
    truth with a residual well above the truth's neighbourhood's, and a spurious pulse
    then holds the start there while the timing states a fraction of a millisecond
    (hard case: blind-bad-SDIT_B-s2-38)."""
    valid = np.flatnonzero(np.isfinite(y))
    if len(valid) < 100:
        return al
    sub = valid[:: max(1, len(valid) // samples)]
    tm, yy = t_m[sub], y[sub]
    best = (np.inf, al.offset_s, al.clock_ppm)
    for ppm in np.arange(-half_ppm, half_ppm + step_ppm / 2, step_ppm) + al.clock_ppm:
        if abs(ppm) > ppm_limit:
            continue
        for d in np.arange(-half_s, half_s + step_s / 2, step_s):
            rms = _fit_rms(X, ctx.t_s, tm, yy, al.offset_s + d, ppm * 1e-6)[0]
            if rms < best[0]:
                best = (rms, al.offset_s + float(d), float(ppm))
    if abs(best[1] - al.offset_s) < step_s / 2 and abs(best[2] - al.clock_ppm) < step_ppm / 2:
        return al
    other = refine(ctx, X, t_m, y, best[1], best[2], ppm_limit)
    return other if other.rms_um < al.rms_um else al


@dataclass(frozen=True, slots=True)
class SetupStep:
    """A step of the set-up during the recording: at measured time ``t_s`` the set-up
    offset (as the ``setup_offset`` finding reads it: machine frame, reading -u.shift)
    changed by ``shift_um``."""
    t_s: float
    shift_um: tuple[float, float, float]

    def reading_um(self, ctx: Context, al: Alignment, t_m: np.ndarray) -> np.ndarray:
        """What the step adds to the reading at measured times ``t_m``."""
        U = sample_at(ctx.t_s, ctx.u, np.clip(al.program_time(t_m), ctx.t_s[0], ctx.t_s[-1]))
        return -(U @ np.asarray(self.shift_um)) * (np.asarray(t_m) >= self.t_s)


def setup_step(ctx: Context, X: np.ndarray, t_m: np.ndarray, y: np.ndarray, al: Alignment,
               share: float = 0.3, versus_drift: float = 0.7, margin: float = 0.05,
               max_samples: int = 60_000, at_s: float | None = None) -> SetupStep | None:
    """A step of the set-up half-way through the recording (the ball mount slipped, a
    magnet let go), when such a step explains at least ``share`` of what the model
    ``X`` leaves of the trace and leaves at most ``versus_drift`` of what a drift of
    the set-up (u*t) would leave; else None.  ``at_s``: its measured time is known,
    only its size is estimated (with the alignment ``al``).

    No effect of the library holds it, and the timing search, left to itself, bends
    the clock or moves the start by seconds to make up for it.  The step happens at a
    moment of the recording, not of the program: it is taken out of the reading before
    the timing is searched again, and stays in the gap."""
    tau = al.program_time(t_m)
    t = ctx.t_s
    ok = np.flatnonzero(np.isfinite(y) & (tau >= t[0]) & (tau <= t[-1]))
    if len(ok) < 100:
        return None
    ok = ok[:: max(1, len(ok) // max_samples)]
    tau, yy, tm = tau[ok], y[ok], t_m[ok]
    A = sample_at(t, X, tau)
    U = sample_at(t, ctx.u, tau)

    def fit(C):
        M = np.column_stack([A, C])
        beta = lsq(M, yy)
        e = yy - M @ beta
        return float(e @ e), beta[-3:]

    if at_s is not None:
        return SetupStep(float(at_s), tuple(-float(v) for v in fit(U * (tm >= at_s)[:, None])[1]))
    r = yy - A @ lsq(A, yy)
    # every step time at once: sums over the samples after it (tau is increasing), the
    # constant set-up (u) projected out
    S = np.cumsum((U[:, :, None] * U[:, None, :])[::-1], axis=0)[::-1]
    b = np.cumsum((U * r[:, None])[::-1], axis=0)[::-1]
    G = S[0]
    span = t[-1] - t[0]
    lo, hi = np.searchsorted(tau, [t[0] + margin * span, t[-1] - margin * span])
    if hi - lo < 10:
        return None
    i = np.arange(lo, hi, max(1, (hi - lo) // 2000))
    P = S[i] - S[i] @ np.linalg.pinv(G) @ S[i] + np.eye(3) * 1e-12 * np.trace(G)
    gain = np.einsum("ka,ka->k", b[i], np.linalg.solve(P, b[i][..., None])[..., 0])
    k = i[int(np.argmax(gain))]
    (step, shift), (drift, _) = fit(U * (tau >= tau[k])[:, None]), fit(U * tau[:, None])
    if step > (1 - share) * float(r @ r) or step > versus_drift * drift:
        return None
    return SetupStep(float(tm[k]), tuple(-float(v) for v in shift))
