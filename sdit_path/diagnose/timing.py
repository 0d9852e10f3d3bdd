"""The recording's timing settled with what was found: searched afresh with the
findings' columns, a set-up step taken out, lags and shapes profiled with it, read
again without what a finding leaves open, and widened by what a partner the recording
cannot tell apart would say."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from ..reading.context import Context, sample_at
from .align import CLOCK_LIMIT_PPM, Alignment, SetupStep, align, generic_columns, local_scan, lsq, \
    setup_step
from .columns import locked_findings, model_columns, partner_columns, shape_columns
from .effects import TIMING_ALIASED, Effect
from .fitting import noise_estimate, serial_correlation, solve
from .timing_profiles import REFINE_SAMPLES, alike_spread, profile_timing, shape_scan

log = logging.getLogger(__name__)


#: how far (s, ppm) the timing polished again with a finding's new shapes may move: the
#: neighbourhood of valleys a few ms apart, not a new search
RESHAPED_S = 0.05


RESHAPED_PPM = 100.0


#: a nonlinear parameter that moved by this share (or appeared or went) reshapes a finding
RESHAPED_SHARE = 0.2


def reshaped(lib: list[Effect], before: list, after: list) -> list[str]:
    """The effects found in both ``before`` and ``after`` whose nonlinear parameters
    that shape them (``shape_parameters``: not a servo mismatch's second-order hints)
    differ by more than :data:`RESHAPED_SHARE`, or of which one holds a parameter the
    other does not."""
    by = {e.name: e for e in lib}
    old = {f.effect: f.nonlinear for f in before}
    out = []
    for f in after:
        if f.effect not in old:
            continue
        a = by[f.effect].shape_parameters(old[f.effect])
        b = by[f.effect].shape_parameters(f.nonlinear)
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
    for f in locked_findings(lib, findings):
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
    al, jump = realign(ctx, expected, t_m, y, [*pose, X[:, 2:], D], first_al)
    shifted, widen_s, why_s = shape_scan(ctx, lib, expected, t_m, y, pose, findings, al, jump)
    seed = first_al
    if shifted is not None:
        # a shape that held the timing in the wrong valley: the timing polished from the
        # new one, and from there after the profile too (from the first timing it goes
        # back to the neighbouring valley; hard case: blind-bad-SDIT_C-s2-39)
        X = model_columns(ctx, lib, expected, findings)
        D = shape_columns(ctx, lib, findings)
        al, jump = realign(ctx, expected, t_m, y, [*pose, X[:, 2:], D],
                            shifted)
        seed = al
    changed, widen = profile_timing(ctx, lib, expected, t_m, y, pose, findings, al, jump)
    if changed:
        # the lagged findings' columns changed with it: the timing searched again
        X = model_columns(ctx, lib, expected, findings)
        D = shape_columns(ctx, lib, findings)
        al, jump = realign(ctx, expected, t_m, y, [*pose, X[:, 2:], D], seed)
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
        # from every sample is kept (on a slow program the crawls carry most of the
        # timing: without them the start moves by about what the information lost
        # explains; hard case: blind-bad-SDIT_C-s1-6)
        sure, _ = realign(ctx, expected, t_m, y_sure,
                           [*pose, X[:, 2:], D], first_al)
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
    # smoothing leaves the start late by a good part of the lag; hard case:
    # blind-bad-SDIT_C-s1-2): the timing is searched with the partner in its place too,
    # and the better fit's timing kept; both then compete again
    for f in findings:
        # (a pulse and a stick-slip leave the start alike, and the other competing in
        # the pass after this one moves a pulse's start by milliseconds: only the timing
        # pairs; hard case: blind-bad-SDIT_B-s1-5)
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
                                     [*pose, Xa[:, 2:], cols], prev)
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
        # read as a lag leaves the start milliseconds early, far beyond what the lag's
        # timing states; hard case: blind-bad-SDIT_B-s1-46): where the other fits about
        # as well, the timing is known no better than the two differ
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
#: (a tenth of the documented clock range; a drift can hold a clock error: a trace is
#: fitted to its noise hundreds of ppm from the truth, and stated about as uncertain;
#: hard case: blind-bad-SDIT_C-s1-28)
EXPLAINED = 1.15


SURE_CLOCK_PPM = 20.0


SURE_OFFSET_S = 0.01


def realign(ctx: Context, expected: np.ndarray, t_m: np.ndarray, y: np.ndarray,
             extra: np.ndarray | list[np.ndarray], first: Alignment, rounds: int = 6,
             margin: float = 10.0
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
    timing can then fit better by more than the noise, and the search costs about a
    tenth of the diagnosis."""
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
        # and the polish stops in the nearest, milliseconds off and sure of it, while the
        # truth's neighbourhood fits far better (hard case: blind-bad-SDIT5_C-s1-38): the
        # neighbourhood is scanned, and a better valley taken
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
