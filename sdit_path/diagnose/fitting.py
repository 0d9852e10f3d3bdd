"""The linear algebra of a fit and what it can claim: least squares with scaled
columns, columns the bar cannot see, residuals correlated in time, the coefficients'
covariance (the instrument's gain included), parameters propagated from them or read
from the curvature of a searched parameter's profile, and the sensor's noise."""

from __future__ import annotations

import logging
import math

import numpy as np

from ..reading.context import Context
from .effects import Effect, Samples

log = logging.getLogger(__name__)


def serial_correlation(r: np.ndarray, tau: np.ndarray) -> float:
    adj = np.diff(tau) < 0.0015
    if adj.sum() < 100:
        return 0.0
    a, b = r[:-1][adj], r[1:][adj]
    a, b = a - a.mean(), b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(np.clip((a @ b) / den, 0.0, 0.9999)) if den > 0 else 0.0


def unseen_columns(A: np.ndarray) -> np.ndarray:
    """Columns the bar cannot see (below 1e-8 um per unit everywhere)."""
    return np.sqrt((A * A).sum(0)) < 1e-8 * math.sqrt(max(len(A), 1))


def solve(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares with column scaling."""
    scale = np.sqrt((A * A).sum(0))
    # a column the bar cannot see stays at zero
    blind = unseen_columns(A)
    scale[blind] = np.inf
    # truncated at 1e-5 of the largest singular value: a combination of parameters
    # the data cannot tell apart gets the minimum-norm value, not 1e8
    coef, *_ = np.linalg.lstsq(A / scale, y, rcond=1e-5)
    return coef / scale


#: standard uncertainty of the instrument's gain: a ballbar's accuracy is about
#: +-(0.5 um + 0.3 %) of its reading (domain brief, typical of commercial ballbars); the
#: 0.5 um is a length, read as the bar length, the 0.3 % scales every coefficient at
#: once (a uniform spread: 0.3 % / sqrt(3))
GAIN_STD = 0.003 / math.sqrt(3.0)


def residual_variance(resid: np.ndarray, tau: np.ndarray) -> float:
    """The variance one sample's residual stands for: its mean square times
    (1 + rho) / (1 - rho) for its correlation from sample to sample."""
    if not len(resid):
        return 0.0
    rho = serial_correlation(resid, tau)
    return float(np.mean(resid * resid)) * (1.0 + rho) / (1.0 - rho)


def searched_std(eff: Effect, nl: dict, keys: list, labels, ctx: Context, S: Samples,
                  others: np.ndarray, y: np.ndarray, var: float
                  ) -> tuple[dict, list, dict]:
    """Standard uncertainties of parameters a finding's search set on a grid (a
    frequency, a time constant, a stick distance), each from the curvature of the
    joint fit's residual sum of squares as that parameter alone moves (every linear
    coefficient, the other findings' included, fitted again; the finding's other
    searched parameters held): a change of ``var`` (the residual's variance per
    sample, :func:`residual_variance`) is one standard uncertainty.  The step is sized
    until the change is between 0.3 and 300 of those (the sum is a parabola there, not
    yet the rounding of the sums); the distance from the value on the grid to the
    parabola's bottom is added in quadrature.  Beyond the parabola the fit is looked
    at :data:`SEARCH_SCAN` away: the uncertainty is at least the farthest of those
    steps that fits within one ``var`` of it.  A parameter the fit does not curve
    around (flat, or a maximum) is not determined by the recording; one whose columns
    cannot be made at the step keeps no uncertainty.

    What the searched parameter leaves open spills into the finding's other
    parameters (a cyclic error's phase at the machine's zero moves with its pitch):
    the third result is, per parameter, the variance to add: its change along the
    profile times the searched parameter's uncertainty, squared, or, where a value
    farther away fits as well, how far it lies from its value there.
    (std, undetermined, spill)."""
    # the others' columns projected out once (Frisch-Waugh-Lovell: the finding's
    # coefficients and the residual are the joint fit's); each trial then fits only its
    # own columns, not every column on every sample again
    U = np.zeros((len(y), 0))
    if others.shape[1]:
        u, sv, _ = np.linalg.svd(others, full_matrices=False)
        U = u[:, sv > 1e-10 * sv[0]] if len(sv) and sv[0] > 0 else U
    y_rest = y - U @ (U.T @ y)

    def fit(nl2) -> tuple[float, dict]:
        C, _ = eff.columns(ctx, S, nl2)
        C = C - U @ (U.T @ C)
        coef = solve(C, y_rest)
        r = y_rest - C @ coef
        with np.errstate(invalid="ignore", divide="ignore"):
            par = eff.parameters(coef, labels, nl2, ctx)
        return float(r @ r), par

    std, undetermined, spill = {}, [], {}
    if var <= 0.0 or not keys:
        return std, undetermined, spill
    failed = (ValueError, FloatingPointError, np.linalg.LinAlgError, ZeroDivisionError)
    r0, base = fit(nl)
    for key in keys:
        x0 = float(nl[key])
        if x0 == 0.0:
            continue
        h = 1e-3 * abs(x0)
        d2 = slope = math.nan
        try:
            for _ in range(8):
                (up, p_up), (down, p_down) = fit({**nl, key: x0 + h}), fit({**nl, key: x0 - h})
                d2, slope = up + down - 2.0 * r0, up - down
                size = max(d2, abs(slope)) / var
                if size > 300.0 and h > 1e-9 * abs(x0):
                    h /= 10.0
                elif size < 0.3 and h < 0.1 * abs(x0):
                    h *= 10.0
                else:
                    break
        except failed:
            continue
        if not (math.isfinite(d2) and d2 > 0.0):
            undetermined.append(key)
            continue
        curvature = d2 / (h * h)
        off = slope / (2.0 * h) / curvature  # grid value minus the parabola's bottom
        sd = math.sqrt(2.0 * var / curvature + off * off)
        # what the others move by: along the parabola, their change times sd
        moved = {}
        for name, a in p_up.items():
            b = p_down.get(name)
            if name != key and isinstance(a, float) and isinstance(b, float):
                change = abs(a - b) / (2.0 * h) * sd
                if math.isfinite(change):
                    moved[name] = change
        # a landscape with other valleys (a saw-tooth's period, a frequency) is not
        # its local parabola: a value up to 10 % away that fits as well (or better)
        # is as likely, the uncertainty is at least that far, and the others move by
        # as much as they differ there
        for rel in SEARCH_SCAN:
            if rel * abs(x0) <= sd:
                continue
            try:
                there = [fit({**nl, key: x0 * (1.0 + rel)}), fit({**nl, key: x0 * (1.0 - rel)})]
            except failed:
                continue
            if min(r for r, _ in there) - r0 > var:
                continue
            sd = rel * abs(x0)
            moved = {}
            for r, par in there:
                if r - r0 > var:
                    continue
                for name, a in par.items():
                    b = base.get(name)
                    if name != key and isinstance(a, float) and isinstance(b, float) \
                            and math.isfinite(a - b):
                        moved[name] = max(moved.get(name, 0.0), abs(a - b))
        std[key] = sd
        for name, change in moved.items():
            spill[name] = spill.get(name, 0.0) + change * change
    return std, undetermined, spill


#: relative steps at which a searched parameter's fit is looked at beyond its parabola
SEARCH_SCAN = (0.003, 0.01, 0.03, 0.1)


#: a static node's first second is left to the machine to settle (a lag of 150 ms has
#: settled to 1e-3 after 1 s): after it, no dynamic effect of the library acts
SETTLE_S = 1.0


def _at_rest(ctx: Context, idx: np.ndarray, settle_s: float = SETTLE_S) -> np.ndarray:
    """Which trajectory samples ``idx`` lie in a dwell at a static node, ``settle_s``
    or more after it began."""
    dwell = ctx.phase == "dwell"
    begins = dwell & ~np.r_[False, dwell[:-1]]
    first = np.maximum.accumulate(np.where(begins, np.arange(ctx.n), 0))
    return (dwell & (ctx.t_s - ctx.t_s[first] >= settle_s))[idx]


def at_rest_check(ctx: Context, A: np.ndarray, beta: np.ndarray, cov: np.ndarray,
                   y: np.ndarray, idx: np.ndarray, tau: np.ndarray, static: list) -> None:
    """The static findings' coefficients (``static``: their slices of ``A``; the set-up,
    the bar length, geometry, a play) read again from the settled dwells alone, where
    no dynamic finding acts, and ``cov`` widened in place where the two readings differ
    by more than their spread allows.

    Beside a dynamic finding (a lag, a smoothing) the fit reads the set-up partly from
    the motion, through that finding's model; where the model's shape is not the
    machine's, the set-up takes up the difference, many times its stated uncertainty,
    and the residual cannot show it (hard case: blind-bad-SDIT_C-s1-36, a servo lag);
    so does a dynamic effect too small to be named (hard case: blind-bad-SDIT5_C-s1-19,
    a 5-axis lag below the noise).  Were the models right, the two readings
    would differ with variance var(rest) - var(all); a difference beyond twice that
    spread adds its excess, as for the timing (:func:`settle`).  With too few settled
    samples nothing changes."""
    cols = np.concatenate([np.arange(A.shape[1])[sl] for sl in static]) if static else []
    if not len(cols):
        return
    rest = _at_rest(ctx, idx)
    if rest.sum() < max(200, 20 * len(cols)):
        return
    A_r, y_r = A[np.ix_(rest, cols)], y[rest]
    b_r = solve(A_r, y_r)
    cov_r = covariance(A_r, y_r - A_r @ b_r, tau[rest]) + GAIN_STD ** 2 * np.outer(b_r, b_r)
    with np.errstate(invalid="ignore"):
        spread = np.maximum(np.diag(cov_r) - np.diag(cov)[cols], 0.0)
        d2 = (beta[cols] - b_r) ** 2
        excess = np.where(np.isfinite(spread) & (d2 > 4.0 * spread), d2 - spread, 0.0)
    for c, b, e in zip(cols, b_r, excess):
        if e > 0.0 and math.isfinite(cov[c, c]):
            cov[c, c] += e
            log.debug("at rest, coefficient %d reads %.4g against %.4g: +- %.3g added",
                      c, b, beta[c], math.sqrt(e))


def covariance(A: np.ndarray, resid: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Covariance of :func:`solve`'s coefficients: the residual's variance (what the
    fit leaves, unexplained structure included: not only the sensor's noise), times
    (1 + rho) / (1 - rho) for the residual's correlation from sample to sample (samples
    count as fewer independent ones, as in the selection), through the pseudo-inverse
    at :func:`solve`'s threshold.  The instrument's gain scales the coefficients
    together: :data:`GAIN_STD` squared times ``coef coef^T`` is added by the caller,
    which has them.  A coefficient with a part in a combination the data
    cannot tell apart (below that threshold) gets an infinite variance; so does one the
    bar cannot see."""
    p = A.shape[1]
    if p == 0:
        return np.zeros((0, 0))
    var = residual_variance(resid, tau)
    scale = np.sqrt((A * A).sum(0))
    blind = unseen_columns(A)
    scale[blind] = np.inf
    _, sv, vt = np.linalg.svd(A / scale, full_matrices=False)
    keep = sv > 1e-5 * sv[0] if len(sv) and sv[0] > 0 else np.zeros(len(sv), bool)
    V = vt[keep].T
    cov = (V / sv[keep] ** 2) @ V.T * var
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = cov / np.outer(scale, scale)
    cov[blind, :] = 0.0
    cov[:, blind] = 0.0
    # the part of each coefficient's direction outside the determined subspace
    lost = 1.0 - (V * V).sum(1)
    open_ = blind | (lost > 1e-6)
    cov[open_, open_] = np.inf
    return cov


def seen_parameters(eff: Effect, C: np.ndarray, coef: np.ndarray, labels, nl: dict,
                     ctx: Context, cov: np.ndarray | None = None
                     ) -> tuple[dict, list, dict, list]:
    """A finding's parameters without those the bar cannot see (a column below
    :func:`solve`'s threshold everywhere: a spindle's Y drift on a B-C table set-up that
    keeps the bar in the XZ plane), which least squares leaves at 0 and which are not
    estimates; and the names of those left out.

    With ``cov``, the coefficients' covariance (:func:`covariance`), also each
    parameter's standard uncertainty, propagated through ``eff.parameters`` by central
    differences (a lag from a shrink's square root, an amplitude from a sine and a
    cosine), and the names of the parameters the data do not determine apart from the
    others (an infinite variance), which are left out like the unseen ones: never more
    numbers than the recording's rank.  Parameters the coefficients do not move (found
    by a search on a grid: a frequency, a time constant) get no uncertainty here."""
    blind = unseen_columns(C)
    coef = np.where(blind, np.nan, coef)
    with np.errstate(invalid="ignore"):
        out = eff.parameters(coef, labels, nl, ctx)
    unseen = [k for k, v in out.items() if isinstance(v, float) and math.isnan(v)]
    out = {k: v for k, v in out.items() if k not in unseen}
    if cov is None:
        return out, unseen, {}, []
    std, undetermined = _propagated(eff, coef, cov, labels, nl, ctx, out, blind)
    out = {k: v for k, v in out.items() if k not in undetermined}
    return out, unseen, std, undetermined


def _propagated(eff: Effect, coef: np.ndarray, cov: np.ndarray, labels, nl: dict,
                ctx: Context, params: dict, blind: np.ndarray) -> tuple[dict, list]:
    """Standard uncertainties of ``params`` (the float ones) from the coefficients'
    covariance, and the parameters that depend on an undetermined coefficient."""
    names = [k for k, v in params.items() if isinstance(v, float)]
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    open_ = ~np.isfinite(sd) & ~blind
    jac = np.zeros((len(names), len(coef)))
    for i in np.flatnonzero(~blind):
        h = 1e-3 * (sd[i] if np.isfinite(sd[i]) and sd[i] > 0 else max(abs(coef[i]), 1e-9))
        hi, lo = coef.copy(), coef.copy()
        hi[i] += h
        lo[i] -= h
        with np.errstate(invalid="ignore", divide="ignore"):
            up = eff.parameters(hi, labels, nl, ctx)
            down = eff.parameters(lo, labels, nl, ctx)
        for n, k in enumerate(names):
            a, b = up.get(k), down.get(k)
            if isinstance(a, float) and isinstance(b, float):
                jac[n, i] = (a - b) / (2.0 * h)
    moves = np.abs(jac) > 0
    undetermined = [k for n, k in enumerate(names) if (moves[n] & open_).any()]
    det = ~blind & ~open_
    sub = cov[np.ix_(det, det)]
    std = {}
    for n, k in enumerate(names):
        if k in undetermined or not moves[n].any():
            continue
        g = jac[n, det]
        v = float(g @ sub @ g)
        if math.isfinite(v) and v >= 0.0:
            std[k] = math.sqrt(v)
        else:
            undetermined.append(k)
    return std, undetermined


def noise_estimate(r: np.ndarray, tau: np.ndarray) -> float:
    """Sensor noise (um) from first differences of adjacent samples (robust): samples
    one sampling interval apart, at 100 Hz or faster (slower, the reading itself moves
    between two samples and the spread of the residual is all there is)."""
    gaps = np.diff(tau)
    dt = float(np.median(gaps)) if len(gaps) else math.inf
    adj = gaps < 1.5 * dt if dt <= 0.0101 else np.zeros(len(gaps), bool)
    d = np.diff(r)[adj]
    if len(d) < 10:
        return float(np.std(r))
    d = d - np.median(d)
    mad = 1.4826 * float(np.median(np.abs(d)))
    core = d[np.abs(d) <= 4.0 * max(mad, 1e-9)]  # quantised noise: trim, do not take the MAD
    return float(np.sqrt(np.mean(core * core) / 2.0)) if len(core) else mad / math.sqrt(2.0)
