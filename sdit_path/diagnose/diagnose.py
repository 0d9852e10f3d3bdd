"""Diagnosing the gap: align, localise, explain with the effect library, and check on
held-out segments.

The gap is the measured reading minus the simulated one (geometry of the model, if
any).  Effects are added by forward selection: at each step every candidate searches
its nonlinear parameters on the current residual, the one that lowers the training
residual most is tried, and it is kept only when (1) an information criterion (BIC
with an effective sample count that accounts for the residual's correlation in time)
says the data support its parameters, and (2) the residual on held-out segments -
a third of the program's stretches, balanced over the dwells and each sub-segment's
place and pass, never used for fitting - shrinks too.
"""

from __future__ import annotations

import logging
import math
import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..errormodel.chain import actual_ball
from ..errormodel.errorset import ErrorSet
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..reading.trace import Trace
from ..sim.simulate import error_values
from .align import CLOCK_LIMIT_PPM, Alignment, SetupStep, sample_at, local_scan, lsq, align, \
    axis_acceleration_readings, generic_columns, refine, setup_step
from ..reading.context import Context, build_context, strided
from .effects import GEOMETRIC, PRIOR_ORDER, Backlash, Effect, GeometryBeyond, LateralPlay, \
    SECOND_ORDER, ReversalSpike, Samples, ScaleMismatch, ServoMismatch, Squareness, projection_gain, \
    fitted_beside, library, linear_axes

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Options:
    """``heldout_every``: one in n stretches of each kind is held out (``held_stretches``);
    ``max_fit_samples``: samples used for fitting (a seeded choice of 0.5 s blocks);
    ``min_heldout_gain``: relative held-out MSE drop a new effect must bring;
    (the noise threshold below scales with the share of samples the effect acts on)
    ``bic_margin``: extra BIC units an effect must win; ``min_effect_noise``: the
    held-out mean square it explains must exceed (this x noise)^2; ``mimic_r2``: share of a
    finding's signal another effect must reproduce to be reported as its mimic;
    ``max_rate_hz``: a recording sampled faster is read at every n-th sample, n the
    largest that keeps this rate (500 Hz keeps every reversal and dwell and modes up to
    the library's 250 Hz, and halves the time of a 1 kHz recording); None reads all."""

    heldout_every: int = 3
    max_fit_samples: int = 300_000
    min_heldout_gain: float = 0.01
    bic_margin: float = 10.0
    mimic_r2: float = 0.8
    min_effect_noise: float = 0.35
    max_effects: int = 6
    max_rate_hz: float | None = None


@dataclass
class Finding:
    effect: str
    title: str
    parameters: dict
    nonlinear: dict
    labels: tuple
    rms_before_um: float
    rms_after_um: float
    heldout_rms_before_um: float
    heldout_rms_after_um: float
    delta_bic: float
    runner_up: str | None = None
    runner_up_ratio: float = math.inf
    mimics: list = field(default_factory=list)
    confidence: str = "low"
    where: dict = field(default_factory=dict)
    contribution_rms_um: float = 0.0
    geometry_doubt: bool = False
    ambiguous_with: list = field(default_factory=list)
    separate_by: str = ""
    #: parameters the bar cannot see in this program (not estimated, not reported)
    unseen: list = field(default_factory=list)
    #: parameter -> standard uncertainty (a searched one whose columns could not be made
    #: at the steps around it has none)
    uncertainty: dict = field(default_factory=dict)
    #: parameters the recording does not determine apart from the others' (not reported)
    undetermined: list = field(default_factory=list)


@dataclass
class Diagnosis:
    program: str
    alignment: Alignment
    gap: dict
    findings: list
    unexplained: dict
    noise_um: float
    samples: dict
    series: dict  # arrays for the pictures: tau, gap, fitted, residual, idx


def expected_reading(plan: PlanFiles, ctx: Context, model: ErrorSet | None) -> np.ndarray:
    """The simulated bar reading (um) on the trajectory grid: exact chain, no noise."""
    cfg = plan.config
    if model is None:
        return np.zeros(ctx.n)
    kin = Kinematics(cfg.machine)
    em, theta = error_values(plan, model)
    k = strided(ctx.n, ctx.ball_mm)  # smooth in the pose: a coarser grid, interpolated
    ball = actual_ball(kin, em, theta, ctx.q[k])
    val = (np.linalg.norm(ball - ctx.pivot_mm, axis=1) - cfg.ballbar.bar_length_mm) * 1e3
    return np.interp(np.arange(ctx.n), k, val)


def stretch_numbers(ctx: Context) -> np.ndarray:
    """Stretch number of every grid sample: a new stretch at every label change."""
    seg = ctx.segment
    change = np.r_[True, seg[1:] != seg[:-1]]
    return np.cumsum(change) - 1


def held_stretches(ctx: Context, every: int) -> np.ndarray:
    """Which stretches (numbered as ``stretch_numbers``) are held out: one in ``every`` of each
    kind, a kind being the dwells, the transfers, or a sub-segment's place in its sector
    on one pass (``D3-2`` on its first run, on its second ...).  Taking every n-th stretch
    of the program instead locks to the program's period: with two sub-segments a sector,
    every n = 3 holds out every descending half, and the fit sees the ball only rise, so
    that a play reversing with the motion cannot be told from the set-up.  The kinds are
    staggered so that one sector is not held out whole."""
    seg = ctx.segment
    starts = np.flatnonzero(np.diff(stretch_numbers(ctx), prepend=-1))
    held = np.zeros(len(starts), dtype=bool)
    runs: dict[str, int] = {}
    count: dict[tuple, int] = {}
    stagger: dict[tuple, int] = {}
    for u, i in enumerate(starts):
        label = str(seg[i])
        if ctx.phase[i] == "dwell":
            kind: tuple = ("dwell",)
        elif ">" in label:
            kind = ("transfer",)
        else:
            kind = ("segment", label.rsplit("-", 1)[-1], runs.get(label, 0))
        runs[label] = runs.get(label, 0) + 1
        j = count.get(kind, 0)
        count[kind] = j + 1
        k = stagger.setdefault(kind, len(stagger))
        held[u] = (j + k) % every == every - 1
    return _balance_reversals(ctx, held, every)


def _balance_reversals(ctx: Context, held: np.ndarray, every: int) -> np.ndarray:
    """Each linear axis's reversals split between the fitted and the held-out stretches,
    about one in ``every`` held out, at least one on each side.  An axis that reverses
    a few times only, each time at the same place of a sector (SDIT_B's X: three
    reversals, every sixth sector, at sub-segment 3), had them all held out, and an
    effect that acts only there (a 10 um reversal spike) was invisible to the fit.
    The rarest axis first; a stretch balanced for one axis is not moved for another."""
    held = held.copy()
    units = stretch_numbers(ctx)
    events = []
    for j in linear_axes(ctx):
        t_rev = np.asarray(ctx.reversal_times[j], float)
        # the stretch an event acts in: just after the reversal (a pulse, a play's step)
        at = np.minimum(np.searchsorted(ctx.t_s, t_rev + 0.01), ctx.n - 1)
        us = list(dict.fromkeys(int(u) for u in units[at]))
        if len(us) >= 2:
            events.append(us)
    locked: set[int] = set()
    for us in sorted(events, key=len):
        want = min(max(1, round(len(us) / every)), len(us) - 1)
        free = [u for u in us if u not in locked]
        now = sum(held[u] for u in us)
        if now > want:
            for u in [u for u in free if held[u]][:now - want]:
                held[u] = False
        elif now < want:
            spare = [u for u in free if not held[u]]
            for u in spare[every - 1::every][:want - now] or spare[:want - now]:
                held[u] = True
        locked.update(us)
    return held


def block_choice(candidates: np.ndarray, quota: int, rng, block: int = 500) -> np.ndarray:
    if len(candidates) <= quota:
        return candidates
    nb = int(math.ceil(len(candidates) / block))
    pick = np.sort(rng.choice(nb, max(1, quota // block), replace=False))
    out = (pick[:, None] * block + np.arange(block)[None, :]).ravel()
    return candidates[out[out < len(candidates)]]


def support(C: np.ndarray) -> float:
    """Share of samples an effect acts on (any column above 10 % of its peak, where
    the effect is more than its own tail): a local effect (stick-slip near reversals, a
    mode rung by the starts and stops) must explain its own samples, not the whole
    trace, to pass the noise threshold.  (At 1 % a mode's deflection with the slow
    accelerations along the curves took in 4 % of the samples against 0.2 % above
    10 %, and a 0.85 um per m/s^2 mode, 0.2 um at its peak, was refused.)"""
    if C.size == 0:
        return 1.0
    peak = np.abs(C).max(axis=0)
    active = (np.abs(C) > 0.1 * np.where(peak > 0, peak, np.inf)).any(axis=1)
    return float(active.mean())


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
    machine's, the set-up takes up the difference and the residual cannot show it (a
    servo lag of the blind check's generator moved dz by 0.14 um against a stated
    0.006), and so does a dynamic effect too small to be named (a 5-axis lag below the
    noise moved it by 0.38 um against 0.02).  Were the models right, the two readings
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


#: the least held-out drop, in noise variances summed over the held-out samples, that
#: counts as more than chance whatever the effect's support
HELDOUT_CHI2 = 25.0


def heldout_need(opt: "Options", mse_ho: float, noise: float, C_ho: np.ndarray) -> float:
    """The held-out MSE drop an effect acting through ``C_ho`` must bring: its size
    where it acts, both parts in proportion to the share of samples it acts on (a mode
    ringing after each start and stop must explain its own samples, not the whole
    trace), and never less than :data:`HELDOUT_CHI2` noise variances over the held-out
    samples (the floor a local effect's tiny share would otherwise take to nothing)."""
    practical = max(opt.min_heldout_gain * mse_ho, (opt.min_effect_noise * noise) ** 2)
    return max(practical * support(C_ho), HELDOUT_CHI2 * noise ** 2 / max(len(C_ho), 1))


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


def diagnose(plan: PlanFiles, program: str, trace: Trace, model: ErrorSet | None = None,
             options: Options = Options(), progress=None, ctx: Context | None = None,
             alignment: Alignment | None = None) -> Diagnosis:
    """``ctx``: the program's context if the caller has built it already; ``alignment``:
    the recording's first alignment if the caller has made it already (as
    :func:`..recording.align_recording` does); it is refined with what is found."""
    def step(msg):
        log.info(msg)
        if progress:
            progress(msg)

    step("context")
    ctx = ctx or build_context(plan, program)
    expected = expected_reading(plan, ctx, model)
    t_m, y = np.asarray(trace.t_s, float), np.asarray(trace.delta_l_um, float)
    if options.max_rate_hz and len(t_m) > 1 and t_m[-1] > t_m[0]:
        stride = int((len(t_m) - 1) / (t_m[-1] - t_m[0]) / options.max_rate_hz + 1e-6)
        if stride > 1:
            t_m, y = t_m[::stride], y[::stride]
    step("alignment")
    base = alignment_columns(plan, ctx)
    if alignment is None:
        ok = np.isfinite(y)
        al = align(ctx, expected, t_m, y, extra=base, noise_um=noise_estimate(y[ok], t_m[ok]))
    elif model is not None:
        # the caller aligned without the geometry; the reading's geometric part holds
        # timing of its own (a golden_small recording aligned without it was 35 ppm off,
        # +- 58, and the first pass then named play and stick-slip for a servo mismatch):
        # polished with it
        al = refine(ctx, generic_columns(ctx, expected, base), t_m, y, alignment.offset_s,
                    alignment.clock_ppm)
    else:
        al = alignment
    lib = library(plan.config.machine, plan.tested_travel())
    first = _explain(ctx, lib, expected, t_m, y, al, options, step, finalize=False)
    # realign with the explained model (the first alignment already searched with what
    # any trace may hold, so polishing it is enough), then explain again with what was
    # found (the nonlinear parameters searched afresh)
    # searched afresh with what was found and nothing more: what was found may hold the
    # timing the first search missed, and the columns that made that search safe
    # (every kind of geometry, lag, reversal) blur the timing of a trace they do not
    # describe
    log.debug("first pass: %s at offset %.4f s, clock %.1f ppm",
              [(f.effect, f.nonlinear) for f in first.findings], al.offset_s, al.clock_ppm)
    X = model_columns(ctx, lib, expected, first.findings)
    pose = needed_blocks(ctx, expected, t_m, y, al, X[:, 2:],
                          pose_blocks(plan, ctx), options.bic_margin)
    first_al = al
    al, jump, names = settle_timing(ctx, lib, expected, t_m, y, pose, first.findings, first_al)
    step("realigned with the findings")
    geometry = GeometryBeyond(plan.config.machine, plan.tested_travel())

    by = {e.name: e for e in lib}

    def profiled(findings) -> dict:
        # a lag profiled with the timing keeps that value: searched again on the
        # residual at a fixed timing, it drifts to what makes up for the timing (a
        # mismatch's common lag went from 0 to the grid's end, 100 ms, and left 2.5 um
        # at every dwell)
        return {f.effect: {by[f.effect].timing_parameter[0]:
                           f.nonlinear[by[f.effect].timing_parameter[0]]}
                for f in findings if by[f.effect].timing_parameter
                and by[f.effect].timing_parameter[0] in f.nonlinear}

    def explain(names, al, jump, pinned):
        # a step of the set-up is no effect: taken out before the effects are judged
        # again, so that none of them (lateral play, backlash) is named for it
        y_fit = y if jump is None else y - jump.reading_um(ctx, al, t_m)
        return _explain(ctx, [e for e in lib if e.name in names], expected, t_m, y_fit, al,
                        options, step, mimic_library=lib, geometry=geometry, pinned=pinned)

    # the bar length is judged again at the settled timing: at the first timing a
    # position-locked effect (a scale error at the clock's edge) may have stood in for it
    # and the first pass named only what helped there (SDIT_B case 43: a cyclic error
    # left behind a spurious scale error)
    result = explain(names | {"bar_length"}, al, jump, profiled(first.findings))
    kept = {f.effect for f in result.findings}
    dropped = {f.effect for f in first.findings} - kept
    if kept != names and any(by[f.effect].timing_parameter for f in result.findings):
        # a lag kept without what it shared the first timing with (a contour smoothing
        # found beside it) reads the start afresh: once more with what was kept
        log.debug("settling again with %s", sorted(kept))
        al, jump, _ = settle_timing(ctx, lib, expected, t_m, y, pose, result.findings, first_al,
                              partners=False)
        result = explain(kept, al, jump, profiled(result.findings))
    elif dropped:
        # the first pass named what the settled timing no longer needs: those findings
        # may have stood in for a wrong first timing and bent the settled one (SDIT_C, a
        # cyclic error of Z: first aligned 2.3 s early, settled with a play, a smoothing
        # and a drift at the clock's edge).  Settled again with what was kept - and the
        # new timing taken only where the settled one said it could lie: unconditionally,
        # it moved a mount slip's start by 4.8 s against a stated 10 ms
        again, jump2, _ = settle_timing(ctx, lib, expected, t_m, y, pose, result.findings, first_al,
                                  partners=False)
        log.debug("settling again without %s: offset %.4f -> %.4f s, clock %.1f -> %.1f ppm",
                  sorted(dropped), al.offset_s, again.offset_s, al.clock_ppm, again.clock_ppm)
        if consistent(again, al) and again.rms_um <= al.rms_um:
            al, jump = again, jump2
            result = explain(kept, al, jump, profiled(result.findings))
    elif jump is None and (moved := reshaped(first.findings, result.findings)):
        # the same findings with other shapes at the settled timing than at the first
        # one, which the settled timing was polished with (a play's slack at the start
        # read 0.99 um there and 4.6 here, a spurious play of Z gone: the start stayed
        # 6.1 ms late, stated +- 0.74 ms): the timing polished again from the settled
        # one with the shapes read there, and kept where it fits better nearby
        again, _, _ = settle_timing(ctx, lib, expected, t_m, y, pose, result.findings, al,
                              partners=False)
        log.debug("settling again with the shapes of %s: offset %.4f -> %.4f s, clock %.1f "
                  "-> %.1f ppm, rms %.5f -> %.5f um", ", ".join(moved), al.offset_s,
                  again.offset_s, al.clock_ppm, again.clock_ppm, al.rms_um, again.rms_um)
        if (again.rms_um < al.rms_um and abs(again.offset_s - al.offset_s) <= RESHAPED_S
                and abs(again.clock_ppm - al.clock_ppm) <= RESHAPED_PPM):
            al = again
            result = explain(kept, al, jump, profiled(result.findings))
    earlier = {f.effect: f for f in first.findings}
    for f in result.findings:  # the competition was the whole library in the first pass
        if f.effect in earlier:
            f.runner_up = earlier[f.effect].runner_up
            f.runner_up_ratio = earlier[f.effect].runner_up_ratio
            judge_confidence(f)
    result.findings = pair_ambiguity(result.findings)
    if timing_is_weak(result.alignment):
        # effects read through their timing (a lag of milliseconds) cannot be named
        # with confidence when the recording's timing is this uncertain
        for f in result.findings:
            if f.effect in TIME_LOCKED and f.confidence == "high":
                f.confidence = "medium"
    if jump is not None:
        result.gap["setup_step"] = {"at_s": jump.t_s, "shift_um": list(jump.shift_um),
                                    "size_um": float(np.linalg.norm(jump.shift_um))}
        result.unexplained["significant"] = True
        result.unexplained.setdefault(
            "note", "a step of the set-up during the recording (out of the library) was "
                    "taken out before the effects were fitted")
    result.program = program
    entry = next((p for p in plan.manifest.get("programs", []) if p["name"] == program), {})
    result.gap["where"] = {"layer": entry.get("layer", ""), **result.gap["where"]}
    return result


#: how far (s, ppm) the timing polished again with a finding's new shapes may move: the
#: neighbourhood of valleys a few ms apart, not a new search
RESHAPED_S = 0.05
RESHAPED_PPM = 100.0
#: a nonlinear parameter that moved by this share (or appeared or went) reshapes a finding
RESHAPED_SHARE = 0.2


def reshaped(before: list, after: list) -> list[str]:
    """The effects found in both ``before`` and ``after`` whose nonlinear parameters
    (not a servo mismatch's second-order hints) differ by more than
    :data:`RESHAPED_SHARE`, or of which one holds a parameter the other does not."""
    old = {f.effect: f.nonlinear for f in before}
    out = []
    for f in after:
        if f.effect not in old:
            continue
        a = {k: v for k, v in old[f.effect].items() if not k.startswith(SECOND_ORDER)}
        b = {k: v for k, v in f.nonlinear.items() if not k.startswith(SECOND_ORDER)}
        if set(a) != set(b) or any(
                isinstance(a[k], float) and isinstance(b[k], float)
                and abs(a[k] - b[k]) > RESHAPED_SHARE * max(abs(a[k]), abs(b[k]))
                or not isinstance(a[k], float) and a[k] != b[k] for k in a):
            out.append(f.effect)
    return out


def consistent(new: Alignment, old: Alignment, k: float = 3.0) -> bool:
    """Does ``new`` lie where ``old`` said the timing could be: offset and clock rate
    each within ``k`` combined standard uncertainties?"""
    return (abs(new.offset_s - old.offset_s) <= k * math.hypot(new.offset_std_s, old.offset_std_s)
            and abs(new.clock_ppm - old.clock_ppm) <= k * math.hypot(new.clock_std_ppm,
                                                                     old.clock_std_ppm))


#: the settling after a stretch a finding's model leaves open (s), and the largest share
#: of the samples left out so (beyond it, none are: the timing read from a remnant would
#: rest on less than the stretches it leaves out)
UNSURE_MARGIN_S = 0.02
UNSURE_SHARE = 0.5


def _unsure_effects(lib: list[Effect], findings: list) -> list[str]:
    """The findings whose model may leave the reading open somewhere (``unsure_in_time``)."""
    by = {e.name: e for e in lib}
    return sorted(f.effect for f in findings
                  if type(by[f.effect]).unsure_in_time is not Effect.unsure_in_time)


def _timing_reading(ctx: Context, lib: list[Effect], X: np.ndarray, t_m: np.ndarray,
                    y: np.ndarray, findings: list, al: Alignment) -> np.ndarray:
    """``y`` without the samples (as not finite) where a finding, fitted at ``al`` with
    the others (``X``: their :func:`model_columns`), says its model leaves the reading
    open (``unsure_in_time``), widened by the settling after them and by three of
    ``al``'s offset uncertainties (at most 50 ms); ``y`` itself when there are none."""
    by = {e.name: e for e in lib}
    unsure = _unsure_effects(lib, findings)
    if not unsure:
        return y
    ok = np.isfinite(y)
    tau = al.program_time(t_m)
    inside = np.flatnonzero(ok & (tau >= ctx.t_s[0]) & (tau <= ctx.t_s[-1]))
    inside = inside[::max(1, -(-len(inside) // REFINE_SAMPLES))]  # sizes, not timing
    beta = solve(sample_at(ctx.t_s, X, tau[inside]), y[inside])
    mask = np.zeros(ctx.n, bool)
    at = 2  # after the expected reading and the constant
    for f in filter(timed, findings):
        width = len(f.labels)
        if f.effect in unsure:
            m = by[f.effect].unsure_in_time(
                ctx, {lab: float(c) for lab, c in zip(f.labels, beta[at:at + width])})
            if m is not None:
                mask |= m
        at += width
    if not mask.any():
        return y
    widen = UNSURE_MARGIN_S + 3.0 * min(al.offset_std_s, 0.05 / 3.0)
    edges = np.flatnonzero(np.diff(np.r_[False, mask, False].astype(np.int8)))
    start, stop = ctx.t_s[edges[::2]] - widen, ctx.t_s[edges[1::2] - 1] + widen
    k = np.searchsorted(start, tau, side="right") - 1
    out = (k >= 0) & (tau <= stop[np.maximum(k, 0)])
    if (out & ok).sum() > UNSURE_SHARE * ok.sum():
        return y
    log.debug("timing read without %.1f %% of the samples (%s)", 100 * (out & ok).mean(),
              ", ".join(sorted(unsure)))
    return np.where(out, np.nan, y)


def settle_timing(ctx: Context, lib: list[Effect], expected: np.ndarray, t_m: np.ndarray,
            y: np.ndarray, pose: list[np.ndarray], findings: list, first_al: Alignment,
            partners: bool = True) -> tuple[Alignment, SetupStep | None, set]:
    """The timing searched afresh with ``findings`` (and the pose blocks), their lags
    profiled with it; with ``partners``, a finding one feed cannot tell from its partner
    also tried with the partner in its place.  The alignment, the set-up step (or None)
    and the effects to judge again."""
    X = model_columns(ctx, lib, expected, findings)
    D = shape_columns(ctx, lib, findings)
    al, jump = realign(ctx, expected, t_m, y, np.column_stack([*pose, X[:, 2:], D]), first_al)
    shifted, widen_s, why_s = shape_scan(ctx, lib, expected, t_m, y, pose, findings, al, jump)
    seed = first_al
    if shifted is not None:
        # a shape that held the timing in the wrong valley: the timing polished from the
        # new one, and from there after the profile too (from the first timing it went
        # back to a valley 6 ms from it)
        X = model_columns(ctx, lib, expected, findings)
        D = shape_columns(ctx, lib, findings)
        al, jump = realign(ctx, expected, t_m, y, np.column_stack([*pose, X[:, 2:], D]),
                            shifted)
        seed = al
    changed, widen = profile_timing(ctx, lib, expected, t_m, y, pose, findings, al, jump)
    if changed:
        # the lagged findings' columns changed with it: the timing searched again
        X = model_columns(ctx, lib, expected, findings)
        D = shape_columns(ctx, lib, findings)
        al, jump = realign(ctx, expected, t_m, y, np.column_stack([*pose, X[:, 2:], D]), seed)
    by = {e.name: e for e in lib}
    lagged = sorted(f.effect for f in findings if by[f.effect].timing_parameter)
    al = widened(al, widen, f"what the lag of {' and '.join(lagged)}, profiled with the "
                             f"timing, leaves open")
    al = widened(al, widen_s, why_s)
    y_sure = _timing_reading(ctx, lib, X, t_m, y, findings, first_al)
    if y_sure is not y:
        # the timing read again without what a finding's model leaves open.  Were the
        # model right there, the two readings would differ by the information the
        # samples left out carry (the difference's variance is that of the reading
        # without them less that of the reading with them); where they differ by more
        # than twice that, the excess is part of the timing's uncertainty.  The estimate
        # from every sample is kept (without them a slow program lost most of its
        # timing: SDIT_C's stick-slip 6 went from 1.2 ms off to 10.8, within what the
        # information lost explains)
        sure, _ = realign(ctx, expected, t_m, y_sure,
                           np.column_stack([*pose, X[:, 2:], D]), first_al)
        log.debug("timing without the unsure samples: offset %.4f +- %.2f ms vs %.4f s, "
                  "clock %.1f +- %.1f vs %.1f ppm", sure.offset_s, sure.offset_std_s * 1e3,
                  al.offset_s, sure.clock_ppm, sure.clock_std_ppm, al.clock_ppm)

        def excess(d: float, s_sure: float, s_all: float) -> float:
            spread = max(s_sure * s_sure - s_all * s_all, 0.0)
            return math.sqrt(d * d - spread) if d * d > 4.0 * spread else 0.0

        unsure = _unsure_effects(lib, findings)
        wide = widened(al, (excess(sure.offset_s - al.offset_s, sure.offset_std_s,
                                    al.offset_std_s),
                             excess(sure.clock_ppm - al.clock_ppm, sure.clock_std_ppm,
                                    al.clock_std_ppm)),
                        f"read without the samples {' and '.join(unsure)} leaves open, the "
                        f"start moved {(sure.offset_s - al.offset_s) * 1e3:+.2f} ms and the "
                        f"clock {sure.clock_ppm - al.clock_ppm:+.1f} ppm, more than those "
                        f"samples' information explains")
        # never wider than the documented clock range allows (the spread of a rate
        # anywhere in twice the range, as for a rate at its edge)
        cap = max(al.clock_std_ppm, 2 * CLOCK_LIMIT_PPM / math.sqrt(3.0))
        al = dataclasses.replace(wide, clock_std_ppm=min(wide.clock_std_ppm, cap))
    names = {f.effect for f in findings}
    if not partners:
        return al, jump, names
    # a finding one feed cannot tell from its partner (servo lag / contour smoothing) was
    # chosen at the first timing, which the one it is not may have bent (a lag read as a
    # smoothing leaves the start 17 ms late): the timing is searched with the partner in
    # its place too, and the better fit's timing kept; both then compete again
    for f in findings:
        # (a pulse and a stick-slip leave the start alike, and the other competing in
        # the pass after this one moved a pulse's start 5 ms: only the timing pairs)
        partner = next((next(iter(pair - {f.effect})) for pair in TIMING_ALIASED
                        if f.effect in pair), None)
        if partner is None or partner in names:
            continue
        Xa = model_columns(ctx, lib, expected, [g for g in findings if g is not f])
        other, jump_o = first_al, None
        for _ in range(3):  # its parameters and the timing depend on each other
            cols = partner_columns(ctx, next(e for e in lib if e.name == partner), expected,
                                    t_m, y, other)
            if cols is None:
                break
            prev = other
            other, jump_o = realign(ctx, expected, t_m, y,
                                     np.column_stack([*pose, Xa[:, 2:], cols]), prev)
            if abs(other.offset_s - prev.offset_s) < 1e-3:
                break
        if cols is None:
            continue
        log.debug("aliased %s -> %s: rms %.5f vs %.5f, offset %.4f vs %.4f", f.effect, partner,
                  other.rms_um, al.rms_um, other.offset_s, al.offset_s)
        worse, better = (al, other) if other.rms_um < al.rms_um else (other, al)
        if other.rms_um < al.rms_um:
            al, jump = other, jump_o
        # the pair one feed cannot tell apart puts the start in different places (a lag
        # carries its delay into the offset, a zero-phase smoothing does not: a smoothing
        # read as a lag left the start 11.8 ms early against a stated 1.1 ms): where the
        # other fits about as well, the timing is known no better than the two differ
        spread = alike_spread(worse, better, min(int(np.isfinite(y).sum()), REFINE_SAMPLES))
        if spread is not None:
            al = widened(al, spread,
                          f"{partner} in place of {f.effect} (which this recording cannot "
                          f"tell apart) fits about as well with the start "
                          f"{abs(worse.offset_s - better.offset_s) * 1e3:.2f} ms elsewhere")
        names.add(partner)
    return al, jump, names


#: a fit whose residual RMS is within this factor of the recording's own noise explains
#: it: its timing is not searched for globally again (a missing effect of 0.57 times the
#: noise, RMS, already exceeds it) - if the timing is sure, within these uncertainties
#: (a tenth of the documented clock range; a drift can hold a clock error: a trace fitted
#: to its noise at 282 ppm from the truth stated +- 306 ppm)
EXPLAINED = 1.15
SURE_CLOCK_PPM = 20.0
SURE_OFFSET_S = 0.01


def realign(ctx: Context, expected: np.ndarray, t_m: np.ndarray, y: np.ndarray,
             extra: np.ndarray, first: Alignment, rounds: int = 6, margin: float = 10.0
             ) -> tuple[Alignment, SetupStep | None]:
    """The timing searched afresh with the columns ``extra``, seeded with ``first``.
    A step of the set-up during the recording (a mount slip) is taken out of the
    reading first; its time and size depend on the timing and the timing on them, so
    both are searched in turn until the timing settles.  The step is looked for with
    the findings' model and, failing that, with the generic columns alone (findings
    such as lateral play can swallow a step at a wrong timing); it is kept only when
    the fit at its own timing needs it by the information criterion.

    The global search is skipped when the model polished from ``first`` already
    explains the recording down to its own noise (a residual within ``EXPLAINED`` of
    the noise read from sample-to-sample differences) with a sure timing: no other
    timing can then fit better by more than the noise, and the search cost a tenth of
    the diagnosis."""
    X = generic_columns(ctx, expected, extra)
    seed = ((first.offset_s, first.clock_ppm),)
    plain = align(ctx, expected, t_m, y, extra=extra, seeds=seed, model=X, search=False)
    ok = np.isfinite(y)
    noise = noise_estimate(y[ok], t_m[ok])
    log.debug("polished from the first timing: rms %.4f um, noise %.4f um (offset %.4f s "
              "+- %.2f ms, clock %.1f +- %.1f ppm)", plain.rms_um, noise, plain.offset_s,
              plain.offset_std_s * 1e3, plain.clock_ppm, plain.clock_std_ppm)
    if (plain.rms_um > EXPLAINED * noise or plain.clock_std_ppm > SURE_CLOCK_PPM
            or plain.offset_std_s > SURE_OFFSET_S):
        plain = align(ctx, expected, t_m, y, extra=extra, seeds=seed, model=X, noise_um=noise)
    else:
        # explained to the noise, but reversal-locked shapes leave minima a few ms apart
        # and the polish stops in the nearest: a 9.2 um play on the rotary-table
        # program stayed 6.1 ms late and 16.5 ppm slow, stated +- 0.74 ms, where the
        # truth's neighbourhood fit better by 2500 in chi-square; the neighbourhood is
        # scanned, and a better valley taken
        near = local_scan(ctx, X, t_m, y, plain, CLOCK_LIMIT_PPM, samples=10_000)
        if near is not plain:
            log.debug("a better valley near the polished timing: offset %.4f -> %.4f s, "
                      "clock %.1f -> %.1f ppm, rms %.5f -> %.5f um", plain.offset_s,
                      near.offset_s, plain.clock_ppm, near.clock_ppm, plain.rms_um, near.rms_um)
            plain = near
    finder = X
    jump = setup_step(ctx, X, t_m, y, first)
    if jump is None:
        finder = generic_columns(ctx, expected)
        jump = setup_step(ctx, finder, t_m, y, first)
    if jump is None:
        return plain, None
    al = first
    for _ in range(rounds):
        yc = y - jump.reading_um(ctx, al, t_m)
        new = align(ctx, expected, t_m, yc, extra=extra, seeds=seed + ((al.offset_s, al.clock_ppm),),
                    model=X)
        settled = abs(new.offset_s - al.offset_s) < 1e-3 and abs(new.clock_ppm - al.clock_ppm) < 2.0
        al = new
        if settled:
            break
        jump = setup_step(ctx, finder, t_m, y, al) or jump
    rss_p, n_p = _fit_stats(ctx, X, t_m, y, plain)
    rss_j, n_j = _fit_stats(ctx, X, t_m, y - jump.reading_um(ctx, al, t_m), al)
    n_eff = min(n_p, n_j)
    if n_eff * math.log(rss_p / max(rss_j, 1e-30)) - 4 * math.log(n_eff) < margin:
        return plain, None
    return al, jump


def profile_timing(ctx: Context, lib: list[Effect], expected: np.ndarray, t_m: np.ndarray,
                    y: np.ndarray, pose: list[np.ndarray], findings: list, al: Alignment,
                    jump: SetupStep | None) -> tuple[bool, tuple[float, float]]:
    """Lags trade with the recording's start: the alignment puts the reference lag into
    the offset, and a finding read through a lag (a servo mismatch reads the axis rates
    as late as the reference axis lags; an equal lag's shrink is read as late as the
    lag) then pulls the start to meet its own timing - microns of it against the
    tenths the geometry reads the start from (a mismatch moved it 12-13 ms, a lag found
    at the grid's end 25 ms).  Each such parameter is profiled with the timing: for
    every other value of the effect's grid (then around the best one) the timing is
    polished with every column, the lowest residual wins and the finding's parameter is
    set to it.

    The profile also says how far the timing is known once the parameter is free: a
    value whose fit is worse by ``dchi2`` (in units of the residual's variance over the
    samples polished) with its timing ``d`` away implies a standard uncertainty of
    ``d / sqrt(dchi2)`` on a quadratic profile (``d`` where the two fit alike).  True
    when a parameter changed, and the largest such offset (s) and clock (ppm)
    uncertainty over the values within 3 standard uncertainties."""
    changed = False
    widen = [0.0, 0.0]
    allg = Samples(np.arange(ctx.n), ctx.t_s)
    yc = y if jump is None else y - jump.reading_um(ctx, al, t_m)
    n_fit = min(int(np.isfinite(yc).sum()), PROFILE_SAMPLES)
    by = {e.name: e for e in lib}
    for f in findings:
        eff = by[f.effect]
        if eff.timing_parameter is None:
            continue
        key, grid = eff.timing_parameter
        rest = model_columns(ctx, lib, expected, [g for g in findings if g is not f])[:, 2:]
        fits: dict[float, Alignment] = {}
        model = TrialModel(ctx, expected, np.column_stack([*pose, rest]))

        def trial(c: float) -> float:
            c = float(c)
            if c not in fits:
                X = model.with_columns(eff.columns(ctx, allg, {**f.nonlinear, key: c})[0])
                fits[c] = refine(ctx, X, t_m, yc, al.offset_s, al.clock_ppm, iterations=4,
                                 max_samples=PROFILE_SAMPLES, check=False)
            return fits[c].rms_um

        coarse = list(grid[::2]) + ([grid[-1]] if len(grid) % 2 == 0 else [])
        k = grid.index(min(coarse, key=trial))
        near = list(grid[max(k - 2, 0):k + 3])
        k = grid.index(min(near, key=trial))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        for c in np.linspace(lo, hi, 7):
            trial(c)
        # then to the vertex of the parabola through the best value and its neighbours
        # (twice): a servo mismatch's columns move with the common lag by the lag
        # difference times the acceleration, and a common lag 0.7 ms off the fine
        # grid's step left that for a mode's deflection to take up
        for _ in range(2):
            vertex = _parabola_vertex({c: a.rms_um ** 2 for c, a in fits.items()})
            if vertex is None:
                break
            trial(round(vertex, 4))
        rms = {c: a.rms_um for c, a in fits.items()}
        best = min(rms, key=rms.get)  # a grid value may beat the finer ones
        log.debug("%s %s profiled with the timing: %.4g (%s)", f.effect, key, best,
                  ", ".join(f"{c:g}: {v:.5f} at {fits[c].offset_s:.4f} s" for c, v in sorted(rms.items())))
        if max(rms.values()) - rms[best] <= 1e-4 * rms[best]:
            # a flat profile (the finding explains next to nothing at this timing)
            # says nothing about the parameter: a tie must not move the start
            continue
        b = fits[best]
        for c, a in fits.items():
            spread = alike_spread(a, b, n_fit)
            if spread is not None:
                widen = [max(w, v) for w, v in zip(widen, spread)]
        if best != f.nonlinear.get(key):
            f.nonlinear[key] = best
            changed = True
    return changed, (widen[0], widen[1])


def _parabola_vertex(values: dict[float, float]) -> float | None:
    """The minimum of the parabola through the lowest of ``values`` (parameter ->
    value) and its two neighbours, within them; None at the ends or on no bowl."""
    cs = sorted(values)
    k = min(range(len(cs)), key=lambda i: values[cs[i]])
    if k == 0 or k == len(cs) - 1:
        return None
    (a, fa), (b, fb), (c, fc) = ((x, values[x]) for x in cs[k - 1:k + 2])
    den = (b - a) * (fb - fc) - (b - c) * (fb - fa)
    if den >= 0:  # no bowl (or a flat one)
        return None
    v = b - 0.5 * ((b - a) ** 2 * (fb - fc) - (b - c) ** 2 * (fb - fa)) / den
    return float(min(max(v, a), c)) if abs(v - b) > 1e-4 * max(abs(b), 1.0) else None


#: the shifts (s) of a finding's reading at which its shape is searched again, and the
#: samples the scan reads
SHAPE_SHIFTS_S = tuple(np.round(np.arange(-0.032, 0.0321, 0.002), 3))
SCAN_SAMPLES = 30_000


def shape_scan(ctx: Context, lib: list[Effect], expected: np.ndarray, t_m: np.ndarray,
                y: np.ndarray, pose: list[np.ndarray], findings: list, al: Alignment,
                jump: SetupStep | None, rounds: int = 3
                ) -> tuple[Alignment | None, tuple[float, float], str]:
    """A finding whose shape may hold the timing (``shape_holds_timing``: pulses after
    reversals) is searched again with its reading shifted in time by each of
    ``SHAPE_SHIFTS_S``, at the timing ``al`` and on what the rest of the model leaves.
    Its shape and the start trade with each other (a later rise with an earlier start,
    a later onset speed with a later start), so that the timing, polished with the
    shape found at it, and the shape, searched again at that timing, stop in the
    nearest valley: a 7.4 um pulse that rose over 4 ms was read rising over 10 ms (the
    end of its grid) with the start 12.4 ms early, stated +- 1.3 ms, while the pulses
    searched 12 ms later fit better by 1500 in chi-square.

    The best shift's shape, if it beats the shape held by more than 9 in chi-square, is
    polished with every column from the start moved by the shift and taken (the
    alignment returned, the finding's parameters set) only when it fits better than the
    timing held; then searched again from there (``rounds`` in all).  Where the two fit
    about as well (chi-square within 9), the timing is known no better than they
    differ: the amounts (offset s, clock ppm) to widen by, and why, are returned too."""
    by = {e.name: e for e in lib}
    span = ctx.t_s[-1] - ctx.t_s[0]
    n_fit = min(int(np.isfinite(y).sum()), REFINE_SAMPLES)
    taken, widen, why = None, (0.0, 0.0), ""
    for f in findings:
        eff = by[f.effect]
        if not eff.shape_holds_timing:
            continue
        rest = generic_columns(ctx, expected, np.column_stack(
            [*pose, model_columns(ctx, lib, expected, [g for g in findings if g is not f])[:, 2:]]))

        def model() -> np.ndarray:  # every column, with the findings as they are now
            return generic_columns(ctx, expected, np.column_stack([
                *pose, model_columns(ctx, lib, expected, findings)[:, 2:],
                shape_columns(ctx, lib, findings)]))

        cur = taken or al
        for _ in range(rounds):
            yc = y if jump is None else y - jump.reading_um(ctx, cur, t_m)
            tau_all = cur.program_time(t_m)
            ok = np.flatnonzero(np.isfinite(yc) & (tau_all >= ctx.t_s[0])
                                & (tau_all <= ctx.t_s[-1]))
            if len(ok) < 1000:
                break
            ok = ok[:: max(1, -(-len(ok) // SCAN_SAMPLES))]
            tau, yy = tau_all[ok], yc[ok]
            G = sample_at(ctx.t_s, rest, tau)
            r = yy - G @ lsq(G, yy)

            def gain(d: float, nl: dict | None) -> tuple[float, dict | None]:
                """The shape's reduction of ``r`` shifted by ``d`` (searched afresh
                unless ``nl`` is given)."""
                tt = tau - d
                idx = np.clip(np.rint((tt - ctx.t_s[0]) / span * (ctx.n - 1)).astype(int), 0,
                              ctx.n - 1)
                S = Samples(idx, tt)
                try:
                    nl = eff.search(ctx, S, r) if nl is None else nl
                    C = eff.columns(ctx, S, nl)[0] if nl is not None else None
                except (ValueError, np.linalg.LinAlgError):
                    return 0.0, None
                if C is None or not C.shape[1] or not np.isfinite(C).all():
                    return 0.0, None
                return projection_gain(C, r), nl

            held_gain = gain(0.0, f.nonlinear)[0]
            gains = {d: gain(d, None) for d in SHAPE_SHIFTS_S}
            d = max(gains, key=lambda k: gains[k][0])
            var = max(float(r @ r) - held_gain, 1e-30) / len(r)
            log.debug("%s searched shifted: best %+.1f ms (%s), chi-square %.1f better than "
                      "held", f.effect, d * 1e3, gains[d][1], (gains[d][0] - held_gain) / var)
            if gains[d][1] is None or gains[d][0] - held_gain <= 9.0 * var:
                break
            held = refine(ctx, model(), t_m, yc, cur.offset_s, cur.clock_ppm)
            before = dict(f.nonlinear)
            f.nonlinear = {**f.nonlinear, **gains[d][1]}
            moved = refine(ctx, model(), t_m, yc, cur.offset_s + d * (1 + cur.clock_ppm * 1e-6),
                           cur.clock_ppm)
            log.debug("%s shifted %+.1f ms: rms %.5f at %.4f s vs %.5f held at %.4f s",
                      f.effect, d * 1e3, moved.rms_um, moved.offset_s, held.rms_um,
                      held.offset_s)
            spread = alike_spread(moved, held, n_fit)
            if spread is not None:
                widen = (max(widen[0], spread[0]), max(widen[1], spread[1]))
                why = (f"{f.effect} with its shape searched {d * 1e3:+.0f} ms away fits about "
                       f"as well with the start "
                       f"{abs(moved.offset_s - held.offset_s) * 1e3:.2f} ms elsewhere")
            if moved.rms_um >= held.rms_um:
                f.nonlinear = before
                break
            taken = cur = moved
    return taken, widen, why


#: samples a profiled parameter's timing is polished on, and a full alignment (refine's)
PROFILE_SAMPLES = 30_000
REFINE_SAMPLES = 120_000


def alike_spread(a: Alignment, b: Alignment, n_fit: int) -> tuple[float, float] | None:
    """Two fits of the same reading at different timings: where the worse is worse by
    ``dchi2`` <= 9 (in units of the better's residual variance over ``n_fit`` samples),
    the standard uncertainty (offset s, clock ppm) their distance implies on a quadratic
    profile, ``d / sqrt(dchi2)`` (``d`` where the two fit alike); None when they do not
    fit alike."""
    better, worse = (a, b) if a.rms_um <= b.rms_um else (b, a)
    dchi2 = n_fit * (worse.rms_um ** 2 - better.rms_um ** 2) / max(better.rms_um ** 2, 1e-30)
    if dchi2 > 9.0:
        return None
    scale = math.sqrt(max(dchi2, 1.0))
    return (abs(worse.offset_s - better.offset_s) / scale,
            abs(worse.clock_ppm - better.clock_ppm) / scale)


def widened(al: Alignment, widen: tuple[float, float], why: str) -> Alignment:
    """``al`` with its uncertainties taking in ``widen`` (offset s, clock ppm) in
    quadrature, and ``why`` with the amounts among its reasons."""
    if widen[0] <= 0 and widen[1] <= 0:
        return al
    offset_std = float(math.hypot(al.offset_std_s, widen[0]))
    clock_std = float(math.hypot(al.clock_std_ppm, widen[1]))
    # A reason is printed only where it moves an uncertainty by 5 % or more: a
    # widening that small changes no figure a reader acts on.
    felt = (offset_std > 1.05 * al.offset_std_s or clock_std > 1.05 * al.clock_std_ppm)
    reasons = ((*al.widened_by, f"{why} (+- {widen[0] * 1e3:.2f} ms, "
                                f"+- {widen[1]:.1f} ppm in quadrature)")
               if felt else al.widened_by)
    return dataclasses.replace(al, offset_std_s=offset_std, clock_std_ppm=clock_std,
                               widened_by=reasons)


class TrialModel:
    """``generic_columns(ctx, expected, [fixed, cols])`` for one trial's ``cols`` after
    another (a parameter profiled on a grid): the same matrix, built once and its last
    columns overwritten while every new column varies as the last ones did (the generic
    columns drop a constant column, so the matrix's shape can depend on them)."""

    def __init__(self, ctx: Context, expected: np.ndarray, fixed: np.ndarray):
        self.ctx, self.expected, self.fixed = ctx, expected, fixed
        self.X: np.ndarray | None = None
        self.width = 0

    def with_columns(self, cols: np.ndarray) -> np.ndarray:
        cols = np.asarray(cols, float).reshape(self.ctx.n, -1)
        varies = bool((np.ptp(cols, axis=0) > 1e-9).all())
        if self.X is not None and varies and cols.shape[1] == self.width:
            self.X[:, -self.width:] = cols
            return self.X
        X = generic_columns(self.ctx, self.expected, np.column_stack([self.fixed, cols]))
        if varies:
            self.X, self.width = X, cols.shape[1]
        return X


def partner_columns(ctx: Context, eff: Effect, expected: np.ndarray, t_m: np.ndarray,
                     y: np.ndarray, al: Alignment, max_samples: int = 60_000):
    """``eff``'s columns on the trajectory grid, its nonlinear parameters searched on
    what the set-up leaves of the reading at the timing ``al``; None when it has nothing
    to offer."""
    tau = al.program_time(t_m)
    ok = np.flatnonzero(np.isfinite(y) & (tau >= ctx.t_s[0]) & (tau <= ctx.t_s[-1]))
    if len(ok) < 1000:
        return None
    ok = ok[:: max(1, len(ok) // max_samples)]
    tt = tau[ok]
    idx = np.clip(np.rint((tt - ctx.t_s[0]) / (ctx.t_s[-1] - ctx.t_s[0]) * (ctx.n - 1)).astype(int),
                  0, ctx.n - 1)
    # the set-up only: the generic columns' v^2 and acceleration terms are the lag's own
    # signature and would leave it nothing but its longest tail
    G = sample_at(ctx.t_s, np.column_stack([expected, np.ones(ctx.n), ctx.u]), tt)
    r = y[ok] - G @ lsq(G, y[ok])
    # judged as fitted together with the set-up (which shares a smoothing's or a lag's
    # shrink while moving)
    Q, sv, _ = np.linalg.svd(G, full_matrices=False)
    with fitted_beside(Q[:, sv > sv[0] * 1e-10]):
        cand = search_candidate(eff, ctx, Samples(idx, tt), r)
    if cand is None:
        return None
    log.debug("partner %s: %s", eff.name, cand[0])
    return eff.columns(ctx, Samples(np.arange(ctx.n), ctx.t_s), cand[0])[0]


def _fit_stats(ctx: Context, X: np.ndarray, t_m: np.ndarray, y: np.ndarray, al: Alignment,
               max_samples: int = 300_000) -> tuple[float, float]:
    """Residual sum of squares of the model ``X`` at the timing ``al`` and the samples
    it counts as (by the residual's correlation), over the same contiguous samples."""
    tau = al.program_time(t_m)
    idx = np.flatnonzero(np.isfinite(y))[:max_samples]
    tt = np.clip(tau[idx], ctx.t_s[0], ctx.t_s[-1])
    A = sample_at(ctx.t_s, X, tt)
    r = y[idx] - A @ lsq(A, y[idx])
    rho = serial_correlation(r, tt)
    return float(r @ r), max(len(idx) * (1 - rho) / (1 + rho), 10.0)


def pose_blocks(plan: PlanFiles, ctx: Context) -> list[np.ndarray]:
    """Geometry as functions of the pose, one block per kind (squareness, scale, the
    smooth geometry beyond the model), on the trajectory grid."""
    m, travel = plan.config.machine, plan.tested_travel()
    k = strided(ctx.n, ctx.ball_mm)
    sub = Samples(k, ctx.t_s[k])
    at = np.arange(ctx.n)
    out = []
    for E in (Squareness(m, travel), ScaleMismatch(m, travel), GeometryBeyond(m, travel)):
        G = E.columns(ctx, sub, {})[0]
        out.append(np.column_stack([np.interp(at, k, G[:, i]) for i in range(G.shape[1])])
                   if G.shape[1] else np.zeros((ctx.n, 0)))
    return out


def needed_blocks(ctx: Context, expected: np.ndarray, t_m: np.ndarray, y: np.ndarray,
                   al: Alignment, found: np.ndarray, blocks: list[np.ndarray],
                   margin: float, max_samples: int = 300_000) -> list[np.ndarray]:
    """The blocks the recording needs beyond the generic columns and what was found, each
    judged on its own by the information criterion (samples counted by the residual's
    correlation) at the first alignment.  Columns a trace does not need only blur its
    timing: on a slow 5-axis program two dozen unneeded geometry columns made the clock
    two to three times less certain than the recording allows."""
    tau = al.program_time(t_m)
    ok = np.flatnonzero(np.isfinite(y) & (tau >= ctx.t_s[0]) & (tau <= ctx.t_s[-1]))
    if len(ok) < 100:
        return blocks
    ok = ok[:max_samples]  # contiguous: the residual's correlation is read sample to sample
    yy = y[ok]
    base = sample_at(ctx.t_s, generic_columns(ctx, expected, found), tau[ok])
    r0 = yy - base @ lsq(base, yy)
    rss0 = float(r0 @ r0)
    rho = serial_correlation(r0, tau[ok])
    n_eff = max(len(ok) * (1 - rho) / (1 + rho), 10.0)
    keep = []
    for B in blocks:
        if B.shape[1] == 0:
            continue
        A = np.column_stack([base, sample_at(ctx.t_s, B, tau[ok])])
        r1 = yy - A @ lsq(A, yy)
        dbic = n_eff * math.log(rss0 / max(float(r1 @ r1), 1e-30)) - B.shape[1] * math.log(n_eff)
        if dbic >= margin:
            keep.append(B)
    return keep


def alignment_columns(plan: PlanFiles, ctx: Context, pose_only: bool = False) -> np.ndarray:
    """Columns the alignment fits besides its generic ones, so that what every trace
    may hold cannot pull the timing: geometry as functions of the pose (squareness,
    scale, and the smooth geometry beyond the model) and, unless ``pose_only``,
    different servo lags, a drift, and reversal-locked steps and pulses (backlash,
    lateral play, friction spikes)."""
    pose = np.column_stack(pose_blocks(plan, ctx))
    return pose if pose_only else np.column_stack([pose, dynamic_columns(ctx)])


def dynamic_columns(ctx: Context) -> np.ndarray:
    """What any recording may hold besides geometry, in generic shapes: different servo
    lags, a drift, and reversal-locked steps and pulses (backlash, lateral play,
    friction spikes)."""
    allg = Samples(np.arange(ctx.n), ctx.t_s)
    cols = [ServoMismatch().columns(ctx, allg, {})[0]]
    cols.append(ctx.u_bed * (ctx.t_s / 3600.0)[:, None])
    # each axis deflects with its own acceleration (its structure's compliance, a mode
    # of tens of Hz quasi-static below it): microns at each start and stop, which left
    # 17-20 ms and 100-120 ppm in the timing.  Not generic: on a trace without it the
    # same columns take the starts and stops the timing is read from
    cols.append(axis_acceleration_readings(ctx))
    widths = {f"width_{ctx.axis_names[j]}_um": 6.5 for j in linear_axes(ctx)
              if len(ctx.reversal_times[j])}
    if widths:
        cols.append(Backlash().columns(ctx, allg, widths)[0])
        # a pulse at the sign change and one at a breakaway speed (25 ms later on a
        # slow reversal inside a curve)
        for onset in (ReversalSpike.onsets_mm_s[0], 0.05):
            cols.append(ReversalSpike().columns(ctx, allg, {"tau_ms": 25.0, "onset_mm_s": onset})[0])
        cols.append(LateralPlay().columns(ctx, allg, {})[0])
    return np.column_stack(cols)


def shape_columns(ctx, lib, findings) -> np.ndarray:
    """The first-order change of each finding's columns with its continuous nonlinear
    parameters (a pulse's rise and decay, a play's width, a mode's frequency): fitted
    beside the timing, the shape is free within its linearisation, so that the timing's
    uncertainty takes in what the shape leaves open instead of holding the shape found
    at the first timing.  Parameters profiled with the timing and discrete ones are left
    out."""
    allg = Samples(np.arange(ctx.n), ctx.t_s)
    by = {e.name: e for e in lib}
    out = []
    for f in filter(timed, findings):
        eff = by[f.effect]
        skip = set(getattr(eff, "discrete", ())) | (
            {eff.timing_parameter[0]} if eff.timing_parameter else set())
        try:
            C = eff.columns(ctx, allg, f.nonlinear)[0]
        except (ValueError, np.linalg.LinAlgError):
            continue
        for key, value in f.nonlinear.items():
            if key in skip or isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            h = 0.01 * abs(value) if value else 0.01
            try:
                up = eff.columns(ctx, allg, {**f.nonlinear, key: value + h})[0]
                down = eff.columns(ctx, allg, {**f.nonlinear, key: value - h})[0]
            except (ValueError, np.linalg.LinAlgError):
                continue
            if up.shape != C.shape or not (np.isfinite(up).all() and np.isfinite(down).all()):
                continue
            Dk = (up - down) / (2 * h)
            keep = np.abs(Dk).max(axis=0) > 1e-9 * max(float(np.abs(C).max()), 1e-300)
            if keep.any():
                out.append(Dk[:, keep])
    return np.column_stack(out) if out else np.zeros((ctx.n, 0))


def timed(f) -> bool:
    """Is the finding's reading locked to the program, to be fitted beside the timing?  A
    steady ripple is locked to time instead: it would pull the clock rate."""
    return not (f.effect == "vibration" and f.nonlinear.get("steady"))


def model_columns(ctx, lib, expected, findings) -> np.ndarray:
    """The expected reading, a constant and the columns of every finding that is
    :func:`timed`, in that order."""
    allg = Samples(np.arange(ctx.n), ctx.t_s)
    by = {e.name: e for e in lib}
    return np.column_stack([expected[:, None], np.ones((ctx.n, 1))]
                           + [by[f.effect].columns(ctx, allg, f.nonlinear)[0]
                              for f in filter(timed, findings)])


def search_candidate(eff: Effect, ctx: Context, S: Samples, r: np.ndarray, pinned: dict | None = None):
    """An effect's nonlinear parameters searched on the residual ``r`` (those in
    ``pinned`` kept as given) and its columns there, or None when it has nothing to
    offer."""
    try:
        fixed = (pinned or {}).get(eff.name)
        # an effect whose search takes what is pinned searches the rest at that value
        nl = (eff.search(ctx, S, r, fixed=fixed) if fixed and eff.searches_with_fixed
              else eff.search(ctx, S, r))
    except (ValueError, np.linalg.LinAlgError):
        return None
    if nl is None:
        return None
    if pinned and eff.name in pinned:
        nl = {**nl, **pinned[eff.name]}
    C, labels = eff.columns(ctx, S, nl)
    if C.shape[1] == 0 or not np.isfinite(C).all():
        return None
    return nl, C, labels


#: the mounting's own parameters: the ball centres (seen as -u . shift) and the bar length
#: (a constant); on a layer whose bar direction varies little they are far from
#: orthogonal, so that either alone can fit the fitted stretches and miss the held-out ones
SETUP_PAIR = ("setup_offset", "bar_length")


def _joint_setup(trials, chosen, A_tr, A_ho, y_tr, y_ho, r_ho, rss0, n_eff, noise, opt, ctx,
                 S_ho, companions: int = 3):
    """When no single effect passes a forward step and neither of the mounting's two
    parts is in yet, both tried at once (a first geometry estimate that moved part of
    the centring into a constant - the two are not separable from geometry - left a
    gap neither part could take alone: each made the held-out stretches worse, and the
    servo mismatch behind them was never reached); if the pair fails, the pair with
    each of the ``companions`` best other candidates (a 1.3 ms servo mismatch at F2000
    with a 10 um centring: 12.4 um of gap that the set-up and the mismatch take to
    1.5 um together, while each alone left too much for the residual's correlation to
    let either in, and nothing was found).  ``([(effect, nl, labels, C_tr, C_ho,
    dbic)...], new_tr, new_ho)`` when the group passes the same tests a single effect
    must, else None."""
    if any(c[0].name in SETUP_PAIR for c in chosen):
        return None
    parts = [next((t for t in trials if t[1].name == name), None) for name in SETUP_PAIR]
    if any(t is None for t in parts):
        return None
    others = [t for t in trials if t[1].name not in SETUP_PAIR][:companions]
    for extra in (None, *others):
        group = parts if extra is None else [*parts, extra]
        out = _joint_group(group, A_tr, A_ho, y_tr, y_ho, r_ho, rss0, n_eff, noise, opt, ctx,
                           S_ho)
        if out is not None:
            return out
    return None


def _joint_group(group, A_tr, A_ho, y_tr, y_ho, r_ho, rss0, n_eff, noise, opt, ctx, S_ho):
    """The effects of ``group`` (trials) added at once, if together they pass the BIC
    margin, each is physical and plausible, and the held-out stretches improve as a
    single effect's must."""
    C_tr = np.column_stack([t[3] for t in group])
    A1 = np.column_stack([A_tr, C_tr])
    beta = solve(A1, y_tr)
    new_tr = y_tr - A1 @ beta
    p = C_tr.shape[1]
    dbic = n_eff * math.log(rss0 / max(float(new_tr @ new_tr), 1e-30)) - p * math.log(n_eff)
    if dbic < opt.bic_margin:
        return None
    out, k = [], A_tr.shape[1]
    for _gain, eff, nl, C, labels, _p in group:
        coef = beta[k:k + C.shape[1]]
        if not eff.physical(coef) or eff.implausible(eff.parameters(coef, labels, nl, ctx)):
            return None
        out.append((eff, nl, labels, C, eff.columns(ctx, S_ho, nl)[0], dbic / len(group)))
        k += C.shape[1]
    C_ho = np.column_stack([o[4] for o in out])
    new_ho = y_ho - np.column_stack([A_ho, C_ho]) @ beta
    mse_ho = float(np.mean(r_ho ** 2))
    if mse_ho - float(np.mean(new_ho ** 2)) < heldout_need(opt, mse_ho, noise, C_ho):
        return None
    log.debug("%s together: BIC %+.1f, held-out MSE %.4g -> %.4g",
              " and ".join(t[1].name for t in group), dbic, mse_ho, float(np.mean(new_ho ** 2)))
    return out, new_tr, new_ho


def _explain(ctx: Context, lib: list[Effect], expected: np.ndarray, t_m: np.ndarray,
             y: np.ndarray, al: Alignment, opt: Options, step, finalize: bool = True,
             mimic_library: list[Effect] | None = None, geometry=None,
             pinned: dict | None = None) -> Diagnosis:
    tau_all = al.program_time(t_m)
    T = ctx.t_s[-1]
    ok = np.isfinite(y) & (tau_all >= ctx.t_s[0]) & (tau_all <= T)
    sel = np.flatnonzero(ok)
    tau = tau_all[sel]
    idx = np.clip(np.rint((tau - ctx.t_s[0]) / (T - ctx.t_s[0]) * (ctx.n - 1)).astype(int),
                  0, ctx.n - 1)
    gap = y[sel] - np.interp(tau, ctx.t_s, expected)
    held = held_stretches(ctx, opt.heldout_every)[stretch_numbers(ctx)[idx]]
    rng = np.random.default_rng(0)
    tr = block_choice(np.flatnonzero(~held), opt.max_fit_samples, rng)
    ho = block_choice(np.flatnonzero(held), opt.max_fit_samples // 2, rng)
    S_tr, S_ho = Samples(idx[tr], tau[tr]), Samples(idx[ho], tau[ho])
    y_tr, y_ho = gap[tr], gap[ho]
    noise = noise_estimate(gap, tau)

    chosen: list[tuple[Effect, dict, tuple]] = []
    A_tr = np.zeros((len(tr), 0))
    A_ho = np.zeros((len(ho), 0))
    r_tr, r_ho = y_tr.copy(), y_ho.copy()
    findings: list[Finding] = []
    cols_tr: list[np.ndarray] = []
    cols_ho: list[np.ndarray] = []
    rms = lambda v: float(np.sqrt(np.mean(v * v))) if len(v) else 0.0  # noqa: E731
    # searches on the residual of a given set of columns are deterministic: the exchange
    # step below meets the forward steps' residuals again (a finding's place tried with
    # the findings chosen before it), so they are kept, keyed by those columns
    searched: dict[tuple, dict] = {}
    alive: list[np.ndarray] = []  # the keys are ids: keep their arrays

    def candidate(eff, rest_cols, r):
        key = tuple(id(c) for c in rest_cols)
        memo = searched.setdefault(key, {})
        if eff.name not in memo:
            memo[eff.name] = search_candidate(eff, ctx, S_tr, r, pinned)
        return memo[eff.name]

    def take(f, eff, nl, labels, C_tr, C_ho, A_tr, A_ho):
        """A finding added: its columns kept; the fitted and held-out designs grown."""
        findings.append(f)
        chosen.append((eff, nl, labels))
        cols_tr.append(C_tr)
        cols_ho.append(C_ho)
        alive.append(C_tr)
        return np.column_stack([A_tr, C_tr]), np.column_stack([A_ho, C_ho])

    while len(findings) < opt.max_effects:
        step(f"selection step {len(findings) + 1}")
        rho = serial_correlation(r_tr, S_tr.tau_s)
        n_eff = max(len(tr) * (1 - rho) / (1 + rho), 10.0)
        rss0 = float(r_tr @ r_tr)
        q, _ = np.linalg.qr(A_tr) if A_tr.shape[1] else (np.zeros((len(tr), 0)), None)
        trials = []
        for eff in lib:
            if any(eff.name == c[0].name for c in chosen):
                continue
            cand = candidate(eff, cols_tr, r_tr)
            if cand is None:
                continue
            nl, C_tr, labels = cand
            Cp = C_tr - q @ (q.T @ C_tr)
            keep = np.sqrt((Cp * Cp).sum(0)) > 1e-9 * max(1.0, float(np.sqrt((C_tr * C_tr).sum(0)).max()))
            if not keep.any():
                continue
            coef = solve(Cp[:, keep], r_tr)
            fit = Cp[:, keep] @ coef
            gain = float(r_tr @ r_tr - (r_tr - fit) @ (r_tr - fit))
            trials.append((gain, eff, nl, C_tr, labels, int(keep.sum())))
        if not trials:
            break
        dbics = {id(t): n_eff * math.log(rss0 / max(rss0 - t[0], 1e-30)) - t[5] * math.log(n_eff)
                 for t in trials}
        trials.sort(key=lambda t: -dbics[id(t)])
        # equal evidence (within the BIC margin): the more common effect first
        best = dbics[id(trials[0])]
        tied = sorted((t for t in trials if best - dbics[id(t)] < opt.bic_margin),
                      key=lambda t: PRIOR_ORDER.index(t[1].name))
        trials = tied + [t for t in trials if all(t is not u for u in tied)]
        if log.isEnabledFor(logging.DEBUG):
            log.debug("  candidates: %s", ", ".join(
                f"{t[1].name} {dbics[id(t)]:.1f}" for t in trials[:6]))
        accepted = None
        for rank, (gain, eff, nl, C_tr, labels, p) in enumerate(trials):
            dbic = dbics[id(trials[rank])]
            if dbic < opt.bic_margin:
                continue
            A1 = np.column_stack([A_tr, C_tr])
            beta = solve(A1, y_tr)
            C_ho, _ = eff.columns(ctx, S_ho, nl)
            B1 = np.column_stack([A_ho, C_ho])
            new_tr, new_ho = y_tr - A1 @ beta, y_ho - B1 @ beta
            if not eff.physical(beta[A_tr.shape[1]:]):
                log.debug("%s: not physical", eff.name)
                continue
            why = eff.implausible(eff.parameters(beta[A_tr.shape[1]:], labels, nl, ctx))
            if why:
                log.debug("%s: implausible (%s)", eff.name, why)
                continue
            mse_ho = float(np.mean(r_ho ** 2))
            need = heldout_need(opt, mse_ho, noise, C_ho)
            if mse_ho - float(np.mean(new_ho ** 2)) < need:
                log.debug("%s %s: held-out MSE %.4g -> %.4g, needs a drop of %.3g", eff.name, nl, mse_ho,
                          float(np.mean(new_ho ** 2)), need)
                continue
            accepted = (eff, nl, labels, C_tr, C_ho, beta, new_tr, new_ho, dbic, rank)
            break
        if accepted is None:
            joint = _joint_setup(trials, chosen, A_tr, A_ho, y_tr, y_ho, r_ho, rss0, n_eff,
                                 noise, opt, ctx, S_ho)
            if joint is None:
                break
            for eff, nl, labels, C_tr, C_ho, dbic in joint[0]:
                A_tr, A_ho = take(Finding(eff.name, eff.title, {}, nl, labels, rms(r_tr),
                                          rms(joint[1]), rms(r_ho), rms(joint[2]), dbic),
                                  eff, nl, labels, C_tr, C_ho, A_tr, A_ho)
            r_tr, r_ho = joint[1], joint[2]
            continue
        eff, nl, labels, C_tr, C_ho, beta, new_tr, new_ho, dbic, rank = accepted
        others = [t for t in trials if t[1] is not eff]
        ru = others[0] if others else None
        f = Finding(eff.name, eff.title, {}, nl, labels, rms(r_tr), rms(new_tr), rms(r_ho),
                    rms(new_ho), dbic)
        if ru is not None:
            f.runner_up = ru[1].name
            f.runner_up_ratio = trials[rank][0] / max(ru[0], 1e-30)
        A_tr, A_ho = take(f, eff, nl, labels, C_tr, C_ho, A_tr, A_ho)
        r_tr, r_ho = new_tr, new_ho

    # backward elimination: drop what the full model no longer needs, then rank by
    # importance (what the fit loses without it) and recount before/after in that order
    def fit(keep):
        if not keep:
            return y_tr.copy(), y_ho.copy()
        A = np.column_stack([cols_tr[i] for i in keep])
        B = np.column_stack([cols_ho[i] for i in keep])
        beta = solve(A, y_tr)
        return y_tr - A @ beta, y_ho - B @ beta

    def prune(keep):
        keep = list(keep)
        while len(keep) > 1:
            full_tr, full_ho = fit(keep)
            rho = serial_correlation(full_tr, S_tr.tau_s)
            n_eff = max(len(tr) * (1 - rho) / (1 + rho), 10.0)
            rss_full = float(full_tr @ full_tr)
            worst, worst_score = None, math.inf
            for i in keep:
                red_tr, red_ho = fit([k for k in keep if k != i])
                p = cols_tr[i].shape[1]
                dbic = n_eff * math.log(float(red_tr @ red_tr) / max(rss_full, 1e-30)) - p * math.log(n_eff)
                mse_ho = float(np.mean(red_ho ** 2))
                need = heldout_need(opt, mse_ho, noise, cols_ho[i])
                ok = dbic >= opt.bic_margin and mse_ho - float(np.mean(full_ho ** 2)) >= need
                if not ok and dbic < worst_score:
                    worst, worst_score = i, dbic
            if worst is None:
                break
            keep.remove(worst)
        return keep

    def exchange(keep):
        """Greedy forward selection can take a proxy early (a scale error standing in for
        a bar length plus part of a lag not yet in): with the others in, try each
        finding's place for every effect not chosen; take the best exchange that the
        information criterion prefers and held-out data do not refuse, until none."""
        for _ in range(len(keep) + 1):
            full_tr, full_ho = fit(keep)
            rho = serial_correlation(full_tr, S_tr.tau_s)
            n_eff = max(len(tr) * (1 - rho) / (1 + rho), 10.0)
            rss_full = float(full_tr @ full_tr)
            mse_full_ho = float(np.mean(full_ho ** 2))
            best = None
            names = {chosen[k][0].name for k in keep}
            for i in keep:
                rest = [k for k in keep if k != i]
                red_tr, _ = fit(rest)
                A_rest = np.column_stack([cols_tr[k] for k in rest]) if rest else np.zeros((len(tr), 0))
                B_rest = np.column_stack([cols_ho[k] for k in rest]) if rest else np.zeros((len(ho), 0))
                for eff in lib:
                    if eff.name in names:
                        continue
                    cand = candidate(eff, [cols_tr[k] for k in rest], red_tr)
                    if cand is None:
                        continue
                    nl, C_tr, labels = cand
                    A1 = np.column_stack([A_rest, C_tr])
                    beta = solve(A1, y_tr)
                    new_tr = y_tr - A1 @ beta
                    rss = float(new_tr @ new_tr)
                    dbic = (n_eff * math.log(rss_full / max(rss, 1e-30))
                            + (cols_tr[i].shape[1] - C_tr.shape[1]) * math.log(n_eff))
                    # fewer columns that lose less than a finding must bring (a bar
                    # length where a scale error of three columns held 0.006 um more
                    # of 0.25 um noise, on 300,000 samples): the simpler one, whatever
                    # such a sliver does to the information criterion
                    # (and, the other way, more columns must bring that much)
                    extra = C_tr.shape[1] - cols_tr[i].shape[1]
                    C_ho = eff.columns(ctx, S_ho, nl)[0] if extra > 0 else None
                    if extra < 0:
                        ok = dbic > 0 or (rss - rss_full) / len(tr) < heldout_need(
                            opt, rss / len(tr), noise, cols_ho[i])
                    elif extra > 0:
                        ok = dbic > 0 and (rss_full - rss) / len(tr) >= heldout_need(
                            opt, rss_full / len(tr), noise, C_ho)
                    else:
                        ok = dbic > 0
                    score = (ok, dbic)
                    if not ok or (best is not None and score <= best[0]):
                        continue
                    coef = beta[A_rest.shape[1]:]
                    if not eff.physical(coef) or eff.implausible(
                            eff.parameters(coef, labels, nl, ctx)):
                        continue
                    if C_ho is None:
                        C_ho = eff.columns(ctx, S_ho, nl)[0]
                    new_ho = y_ho - np.column_stack([B_rest, C_ho]) @ beta
                    # held-out data refuse the exchange when the finding it replaces,
                    # added back, would pass their test: an equal fit with fewer
                    # columns (a bar length where a scale error stood in for it) must
                    # not lose to the held-out samples' noise
                    mse_new_ho = float(np.mean(new_ho ** 2))
                    if mse_new_ho - mse_full_ho >= heldout_need(opt, mse_new_ho, noise,
                                                                 cols_ho[i]):
                        log.debug("exchange %s for %s: held-out MSE %.5g -> %.5g", eff.name,
                                  chosen[i][0].name, mse_full_ho, mse_new_ho)
                        continue
                    best = (score, i, eff, nl, labels, C_tr, C_ho)
            if best is None:
                return keep
            (_, dbic), i, eff, nl, labels, C_tr, C_ho = best
            log.debug("exchange: %s for %s (BIC %+.1f)", eff.name, chosen[i][0].name, dbic)
            old = findings[i]
            findings[i] = Finding(eff.name, eff.title, {}, nl, labels, old.rms_before_um,
                                  old.rms_after_um, old.heldout_rms_before_um,
                                  old.heldout_rms_after_um, old.delta_bic + dbic)
            if dbic < 0 and frozenset({eff.name, old.effect}) in ALIASED:
                # taken as the simpler of two the criterion ranks the other way: the one
                # it replaces fits at least as well (a pair one feed cannot tell apart)
                findings[i].runner_up, findings[i].runner_up_ratio = old.effect, 1.0
            chosen[i] = (eff, nl, labels)
            cols_tr[i], cols_ho[i] = C_tr, C_ho
            alive.append(C_tr)
            keep = prune(keep)
        return keep

    def polish(keep) -> bool:
        """The forward steps searched each finding's nonlinear parameters on what the
        findings before it left: with all the others in, each is searched again and
        its new parameters kept when the fit improves on the fitted and the held-out
        samples.  (A play operator's width was found before the bar length was in:
        8.5 um where the play fitted 9.6, and the ramp it missed after every reversal
        came back as a reversal spike.)  True when something moved."""
        moved = False
        for _ in range(2):
            changed = False
            full_tr, full_ho = fit(keep)
            for i in keep:
                eff, nl_old, _labels = chosen[i]
                rest = [k for k in keep if k != i]
                red_tr, _ = fit(rest)
                cand = candidate(eff, [cols_tr[k] for k in rest], red_tr)
                if cand is None or cand[0] == nl_old:
                    continue
                nl, C_tr, labels = cand
                A_rest = (np.column_stack([cols_tr[k] for k in rest]) if rest
                          else np.zeros((len(tr), 0)))
                A1 = np.column_stack([A_rest, C_tr])
                beta = solve(A1, y_tr)
                new_tr = y_tr - A1 @ beta
                if float(new_tr @ new_tr) >= float(full_tr @ full_tr):
                    continue
                coef = beta[A_rest.shape[1]:]
                if not eff.physical(coef) or eff.implausible(eff.parameters(coef, labels, nl, ctx)):
                    continue
                C_ho = eff.columns(ctx, S_ho, nl)[0]
                B_rest = (np.column_stack([cols_ho[k] for k in rest]) if rest
                          else np.zeros((len(ho), 0)))
                new_ho = y_ho - np.column_stack([B_rest, C_ho]) @ beta
                if float(np.mean(new_ho ** 2)) > float(np.mean(full_ho ** 2)):
                    continue
                log.debug("polish %s: %s -> %s", eff.name, nl_old, nl)
                chosen[i] = (eff, nl, labels)
                cols_tr[i], cols_ho[i] = C_tr, C_ho
                alive.append(C_tr)
                findings[i].nonlinear, findings[i].labels = nl, labels
                full_tr, full_ho = fit(keep)
                changed = moved = True
            if not changed:
                break
        return moved

    def settle(keep) -> bool:
        """Nonlinear parameters that the fitted coefficients fix (a servo mismatch's lag
        differences, which shape its own second order; a play's width and slack, which
        shape its columns) read back from the fit with every finding in, until they hold
        to 1 %: a search reads them on what the findings before it leave, without the
        others beside (1.86 ms where the fit gave 1.96, and a mode's deflection took up
        the 0.03 um left at the accelerations).  True when something moved."""
        moved = False
        beta = None  # the joint fit, made again only after a finding's columns changed
        for _ in range(4):
            changed = False
            for i in keep:
                eff, nl_old, labels = chosen[i]
                if beta is None:
                    beta = solve(np.column_stack([cols_tr[k] for k in keep]), y_tr)
                at = sum(cols_tr[k].shape[1] for k in keep[:keep.index(i)])
                nl = eff.from_fit(nl_old, beta[at:at + cols_tr[i].shape[1]], labels)
                if nl is None or all(
                        abs(nl[k] - nl_old.get(k, 0.0)) <= 0.01 * max(abs(nl[k]), 1e-3)
                        for k in nl if isinstance(nl[k], float)):
                    continue
                # taken whatever the fit says: a column shaped with one value and
                # scaled to another is no machine's (a slack ramp of 1.0 um holding 4.6
                # um: the axis would catch up faster than the command moved); the timing
                # polished with the model then moves to where the shape is right
                C_tr, labels_new = eff.columns(ctx, S_tr, nl)
                C_ho = eff.columns(ctx, S_ho, nl)[0]
                cols_tr[i], cols_ho[i] = C_tr, C_ho
                log.debug("settle %s: %s -> %s", eff.name, nl_old, nl)
                chosen[i] = (eff, nl, labels_new)
                alive.append(C_tr)
                findings[i].nonlinear, findings[i].labels = nl, labels_new
                changed = moved = True
                beta = None
            if not changed:
                break
        return moved

    keep = exchange(prune(range(len(chosen))))
    if polish(keep) | settle(keep):
        keep = prune(keep)
    if keep:
        full_tr, _ = fit(keep)
        loss = {i: float(fit([k for k in keep if k != i])[0] @ fit([k for k in keep if k != i])[0])
                - float(full_tr @ full_tr) for i in keep}
        keep.sort(key=lambda i: -loss[i])
    ranked = []
    before_tr, before_ho = y_tr, y_ho
    for n_in, i in enumerate(keep, start=1):
        after_tr, after_ho = fit(keep[:n_in])
        f = findings[i]
        f.rms_before_um, f.rms_after_um = rms(before_tr), rms(after_tr)
        f.heldout_rms_before_um, f.heldout_rms_after_um = rms(before_ho), rms(after_ho)
        before_tr, before_ho = after_tr, after_ho
        ranked.append(i)
    findings = [findings[i] for i in ranked]
    chosen = [chosen[i] for i in ranked]

    if not finalize:
        return Diagnosis("", al, {}, findings, {}, noise, {}, {})
    # final fit on all fitted + held-out samples: parameters and contributions
    allsel = np.sort(np.r_[tr, ho])
    S_all = Samples(idx[allsel], tau[allsel])
    blocks, slices = [], []
    for eff, nl, labels in chosen:
        C, _ = eff.columns(ctx, S_all, nl)
        slices.append(slice(sum(b.shape[1] for b in blocks), sum(b.shape[1] for b in blocks) + C.shape[1]))
        blocks.append(C)
    y_all = gap[allsel]
    if blocks:
        A = np.column_stack(blocks)
        beta = solve(A, y_all)
        fitted = A @ beta
    else:
        beta, fitted = np.zeros(0), np.zeros(len(allsel))
    resid = y_all - fitted
    noise = noise_estimate(resid, tau[allsel])
    cov = (covariance(A, resid, tau[allsel]) + GAIN_STD ** 2 * np.outer(beta, beta)
           if blocks else np.zeros((0, 0)))
    if blocks:
        at_rest_check(ctx, A, beta, cov, y_all, idx[allsel], tau[allsel],
                       [sl for (eff, _, _), sl in zip(chosen, slices)
                        if eff.name not in TIME_LOCKED])
    var_all = residual_variance(resid, tau[allsel])
    series_idx = idx[allsel]
    contribs = {}
    for f, (eff, nl, labels), sl in zip(findings, chosen, slices):
        contrib = blocks[slices.index(sl)] @ beta[sl]
        contribs[f.effect] = contrib
        f.parameters, f.unseen, f.uncertainty, f.undetermined = seen_parameters(
            eff, blocks[slices.index(sl)], beta[sl], labels, nl, ctx, cov[sl, sl])
        searched = [k for k, v in f.parameters.items() if isinstance(v, float)
                    and k not in f.uncertainty and isinstance(nl.get(k), float)]
        if searched:
            std, lost, spill = searched_std(eff, nl, searched, labels, ctx, S_all,
                                             np.delete(A, np.arange(A.shape[1])[sl], axis=1),
                                             y_all, var_all)
            for k, v in spill.items():
                if k in f.uncertainty:
                    f.uncertainty[k] = math.sqrt(f.uncertainty[k] ** 2 + v)
            f.uncertainty.update(std)
            f.undetermined += lost
            f.parameters = {k: v for k, v in f.parameters.items() if k not in lost}
        f.contribution_rms_um = rms(contrib)
        f.where = locate(ctx, series_idx, tau[allsel], contrib)
        # mimics: which other effects reproduce this finding's own signal
        sig = contrib[np.isin(allsel, tr)]
        tot = float(sig @ sig)
        for other in mimic_library or lib:
            if other.name == eff.name or tot <= 0:
                continue
            try:
                nl2 = other.search(ctx, S_tr, sig)
            except (ValueError, np.linalg.LinAlgError):
                nl2 = None
            if nl2 is None:
                continue
            C2, labels2 = other.columns(ctx, S_tr, nl2)
            if C2.shape[1] == 0:
                continue
            c2 = solve(C2, sig)
            if not other.physical(c2) or other.implausible(other.parameters(c2, labels2, nl2, ctx)):
                continue  # only with parameters no machine has: not a mimic
            r2 = 1.0 - float(((sig - C2 @ c2) ** 2).sum()) / tot
            if r2 >= opt.mimic_r2:
                f.mimics.append({"effect": other.name, "r2": round(r2, 4)})
        f.mimics.sort(key=lambda m: -m["r2"])
        for pair, how in ALIASED.items():
            if f.effect in pair:
                other = next(iter(pair - {f.effect}))
                if any(m["effect"] == other for m in f.mimics):
                    f.ambiguous_with = [other]
                    f.separate_by = how
        judge_confidence(f)
    findings = merge_aliased(findings, contribs, ctx, series_idx, tau[allsel])
    gap_rms = rms(gap)
    un_rms = rms(resid)
    unexplained = {"rms_um": un_rms, "noise_um": noise,
                   "significant": bool(un_rms > 1.25 * noise and un_rms - noise > 0.05),
                   "where": locate(ctx, series_idx, tau[allsel], resid, noise=noise)}
    # would smooth geometry outside the library fit the held-out data better than the
    # geometric findings do?  Then they may only stand in for it: say so.
    geo_doubt = None
    if geometry is not None and any(f.effect in GEOMETRIC for f in findings):
        G_tr, _ = geometry.columns(ctx, S_tr, {})
        G_ho, _ = geometry.columns(ctx, S_ho, {})
        A_tr = np.column_stack([cols_tr[j] for j in ranked] + [G_tr]) if G_tr.shape[1] else None
        if A_tr is not None:
            A_ho = np.column_stack([cols_ho[j] for j in ranked] + [G_ho])
            beta = solve(A_tr, y_tr)
            with_geo = float(np.mean((y_ho - A_ho @ beta) ** 2))
            base_ho = findings[-1].heldout_rms_after_um ** 2 if findings else float(np.mean(y_ho ** 2))
            gain = base_ho - with_geo
            if gain > max(0.1 * base_ho, (opt.min_effect_noise * noise) ** 2):
                geo_doubt = math.sqrt(gain)
                for f in findings:
                    if f.effect in GEOMETRIC:
                        f.geometry_doubt = True
                        judge_confidence(f)
    unexplained["geometry_beyond_library_um"] = geo_doubt
    if geo_doubt is not None:
        unexplained["significant"] = True
        unexplained["note"] = ("smooth position-locked geometry outside the library (straightness "
                               "or angular errors) explains held-out data better than the "
                               "geometric findings: identify it with sdit-path identify")
    gap_info = {"rms_um": gap_rms, "max_abs_um": float(np.max(np.abs(gap))) if len(gap) else 0.0,
                "where": locate(ctx, idx, tau, gap, noise=noise, detail=True)}
    return Diagnosis("", al, gap_info, findings, unexplained, noise,
                     {"in_program": int(len(sel)), "fitted": int(len(tr)), "heldout": int(len(ho)),
                      "dropouts": int((~np.isfinite(y)).sum())},
                     {"tau": tau[allsel], "gap": y_all, "fitted": fitted, "residual": resid,
                      "idx": series_idx, "held": held[allsel]})


#: Pairs of effects one recording at one feed cannot tell apart, and the experiment that
#: separates them.  Equal servo lag shrinks the path by (v tau)^2 / (2 R); a control's
#: smoothing set as a path tolerance shortcuts the same curves by an amount that does not
#: grow with the feed, one set as a time filter by (v sigma)^2 / (2 R) like the lag - then
#: only the static nodes tell them apart (a lag arrives late and one-sided, a zero-phase
#: filter leaves early and arrives late, symmetric about the stop).
#: a lag and a smoothing: the pair whose two readings put the start in different places
#: (a lag carries its delay into the offset, a zero-phase smoothing does not)
LAG_SMOOTHING = frozenset({"servo_lag", "contour_smoothing"})

ALIASED = {LAG_SMOOTHING:
           "run the layer again at a second feed (a path-tolerance smoothing does not grow "
           "with the feed, a lag's shrink grows as its square) and compare how the reading "
           "leaves and reaches the static nodes (a lag is one-sided, a zero-phase smoothing "
           "symmetric)",
           # both act for tens of ms after an axis reverses; at one feed a small stick-slip
           # and a pulse are a few hundredths of a micrometre apart (a 1.1 um stick-slip on
           # Z at F2000, named a pulse by the simpler-finding rule)
           frozenset({"reversal_spike", "stick_slip"}):
           "run the layer again at a second feed (a friction pulse grows with the feed; a "
           "stick-slip lives where an axis crawls, below about 200 mm/min, and lasts longer "
           "at a lower feed)"}

#: Pairs of position-locked errors a program tells apart only through the bar directions
#: and positions it covers.  Over the whole sphere a scale error of an axis reads the
#: square of the bar's direction cosine along it and a squareness the product of two
#: axes' cosines; a program whose poses couple the two (a 5-axis layer turning the table
#: under a bar of few directions, a 24 urad XZ squareness read as a scale of X and Z with
#: the squareness 2 % behind) cannot.  Never merged when both are selected: a machine
#: has both.
PROGRAM_ALIASED = {frozenset({"scale_mismatch", "squareness"}):
                   "measure a program whose bar directions cover each axis and the "
                   "diagonals between the two axes independently (another layer or "
                   "track, or the 3-axis sphere with the rotary axes still): a scale error "
                   "reads the square of the bar's direction cosine along its axis, a "
                   "squareness the product of the two axes' cosines"}

#: the aliased pairs whose timing is searched with either (a pulse and a stick-slip after
#: a reversal leave the start alike)
TIMING_ALIASED = (LAG_SMOOTHING,)


def merge_aliased(findings: list, contribs: dict, ctx: Context, idx: np.ndarray,
                   tau: np.ndarray) -> list:
    """Two effects this recording cannot tell apart, both selected, are one finding:
    the first named, the other in ``ambiguous_with``, their joint contribution and
    both parameter sets (the other's prefixed with its name).  One of them selected
    and the other its mimic or a close runner-up: the finding names both as well."""
    for pair, how in ALIASED.items():
        both = [f for f in findings if f.effect in pair]
        if len(both) != 2:
            continue
        keep, drop = both
        joint = contribs[keep.effect] + contribs[drop.effect]
        keep.contribution_rms_um = float(np.sqrt(np.mean(joint * joint)))
        keep.where = locate(ctx, idx, tau, joint)
        keep.parameters = {**keep.parameters,
                           **{f"{drop.effect}.{k}": v for k, v in drop.parameters.items()}}
        keep.unseen = keep.unseen + [f"{drop.effect}.{k}" for k in drop.unseen]
        keep.uncertainty = {**keep.uncertainty,
                            **{f"{drop.effect}.{k}": v for k, v in drop.uncertainty.items()}}
        keep.undetermined = keep.undetermined + [f"{drop.effect}.{k}" for k in drop.undetermined]
        keep.heldout_rms_after_um = min(keep.heldout_rms_after_um, drop.heldout_rms_after_um)
        keep.rms_after_um = min(keep.rms_after_um, drop.rms_after_um)
        keep.ambiguous_with, keep.separate_by = [drop.effect], how
        keep.mimics = [m for m in keep.mimics if m["effect"] != drop.effect] + [
            {"effect": drop.effect, "r2": 1.0}]
        judge_confidence(keep)
        findings = [f for f in findings if f is not drop]
    return pair_ambiguity(findings)


def pair_ambiguity(findings: list) -> list:
    """One of an aliased pair selected, the other reproducing it (a listed mimic, or a
    runner-up with nearly the same evidence): the recording cannot tell them apart
    either, and the finding names both.  One of a pair only some programs tell apart
    selected, the other its runner-up with nearly the same evidence: this program does
    not, and the finding names both (a mimic alone does not: the two share part of
    their signal on every program)."""
    for f in findings:
        if f.ambiguous_with:
            continue
        for pair, how in ALIASED.items():
            if f.effect not in pair:
                continue
            other = next(e for e in pair if e != f.effect)
            if any(m["effect"] == other for m in f.mimics) or (
                    f.runner_up == other and f.runner_up_ratio < AMBIGUOUS_RATIO):
                f.ambiguous_with, f.separate_by = [other], how
                judge_confidence(f)
        for pair, how in PROGRAM_ALIASED.items():
            if (not f.ambiguous_with and {f.effect, f.runner_up} == pair
                    and f.runner_up_ratio < AMBIGUOUS_RATIO):
                f.ambiguous_with, f.separate_by = [f.runner_up], how
                judge_confidence(f)
    return findings


#: a runner-up of an aliased pair within this evidence ratio makes the finding ambiguous
AMBIGUOUS_RATIO = 1.1


#: Effects whose signal is read through timing at the millisecond level.
TIME_LOCKED = ("servo_lag", "servo_mismatch", "contour_smoothing", "vibration",
               "reversal_spike", "stick_slip")


def timing_is_weak(al: Alignment, offset_s: float = 0.002, clock_ppm: float = 5.0) -> bool:
    """The recording's timing is known worse than ``offset_s`` or ``clock_ppm``."""
    return not (al.offset_std_s <= offset_s and al.clock_std_ppm <= clock_ppm)


def judge_confidence(f: Finding) -> None:
    """high: it holds on held-out segments and nothing else explains it as well;
    medium: a mimic or a close runner-up, or weaker on held-out data; low: barely
    generalises."""
    ex_tr = f.rms_before_um ** 2 - f.rms_after_um ** 2
    ex_ho = f.heldout_rms_before_um ** 2 - f.heldout_rms_after_um ** 2
    generalises = ex_ho / ex_tr if ex_tr > 0 else 0.0
    # the README's rule: no mimic, no close runner-up, not ambiguous
    close = bool(f.mimics) or f.runner_up_ratio < 1.1 or bool(f.ambiguous_with)
    f.confidence = ("high" if generalises >= 0.5 and not close and not f.geometry_doubt
                    and not _size_unsure(f) else
                    "medium" if generalises >= 0.25 else "low")


def _size_unsure(f: Finding) -> bool:
    """Every size the finding reports (its fitted parameters, not the searched ones)
    lies within 2 standard uncertainties of zero: a mode's compliance of 0.91 +- 0.91
    um per m/s^2 is not named with confidence, however much its columns took up."""
    sizes = [k for k, v in f.parameters.items() if isinstance(v, float)
             and k not in f.nonlinear and k in f.uncertainty]
    return bool(sizes) and all(abs(f.parameters[k]) < 2.0 * f.uncertainty[k] for k in sizes)


def _windows(tau: np.ndarray, flag: np.ndarray, min_gap_s: float = 0.5, limit: int = 12):
    if not flag.any():
        return []
    order = np.argsort(tau)
    t, f = tau[order], flag[order]
    on = t[f]
    splits = np.flatnonzero(np.diff(on) > min_gap_s)
    starts = np.r_[on[0], on[splits + 1]]
    ends = np.r_[on[splits], on[-1]]
    wins = sorted(zip(starts, ends), key=lambda w: -(w[1] - w[0]))[:limit]
    return [[round(float(a), 3), round(float(b), 3)] for a, b in sorted(wins)]


def locate(ctx: Context, idx: np.ndarray, tau: np.ndarray, signal: np.ndarray,
           noise: float | None = None, detail: bool = False) -> dict:
    """Where ``signal`` lives: segments (RMS per segment, the strongest), phases,
    near axis reversals or away from them, and time windows (program time)."""
    seg = ctx.segment[idx]
    names, inv = np.unique(seg.astype(str), return_inverse=True)
    ssum = np.bincount(inv, signal * signal, len(names))
    cnt = np.bincount(inv, None, len(names))
    seg_rms = np.sqrt(ssum / np.maximum(cnt, 1))
    peak = float(seg_rms.max()) if len(seg_rms) else 0.0
    floor = (noise or 0.0) * 1.5
    strong = [(str(names[i]), float(seg_rms[i])) for i in np.argsort(-seg_rms)
              if seg_rms[i] >= max(0.5 * peak, floor) and seg_rms[i] > 0]
    out = {"segments": [s for s, _ in strong[:20]],
           "segment_rms_um": {s: round(v, 4) for s, v in strong[:20]}}
    ph = ctx.phase[idx].astype(str)
    out["phase_rms_um"] = {p: round(float(np.sqrt(np.mean(signal[ph == p] ** 2))), 4)
                           for p in ("accelerate", "cruise", "decelerate", "dwell") if (ph == p).any()}
    near = np.zeros(len(idx), dtype=bool)
    for j in ctx.linear:
        near |= ctx.since_reversal_s[idx, j] < 0.1
    out["reversal_rms_um"] = {
        "within_100ms_after_reversal": round(float(np.sqrt(np.mean(signal[near] ** 2))), 4) if near.any() else 0.0,
        "elsewhere": round(float(np.sqrt(np.mean(signal[~near] ** 2))), 4) if (~near).any() else 0.0}
    # time windows where the (50 ms smoothed) signal is above half its peak (and noise)
    order = np.argsort(tau)
    sm = np.abs(signal[order])
    k = 50
    if len(sm) > k:
        sm = np.convolve(sm, np.ones(k) / k, mode="same")
    thr = max(0.5 * float(sm.max()) if len(sm) else 0.0, 3.0 * (noise or 0.0) / math.sqrt(k))
    flag = np.zeros(len(tau), dtype=bool)
    flag[order] = sm >= thr
    out["time_windows_s"] = _windows(tau, flag)
    if detail:
        kind = np.where(ph == "dwell", "static nodes (dwell)",
                        np.where(np.char.find(seg.astype(str), ">") >= 0, "meridian transits",
                                 "layer segments"))
        out["by_part_rms_um"] = {k: round(float(np.sqrt(np.mean(signal[kind == k] ** 2))), 4)
                                 for k in ("layer segments", "meridian transits",
                                           "static nodes (dwell)") if (kind == k).any()}
    return out
