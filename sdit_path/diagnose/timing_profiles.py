"""Parameters that trade with the recording's start, profiled with the timing: a
lag's value on its grid, a pulse's shape searched at shifted times; and how far two
fits at different timings that fit alike leave the timing open."""

from __future__ import annotations

import logging
import math

import numpy as np

from ..reading.context import Context, nearest_samples, sample_at
from .align import Alignment, SetupStep, coefficients_at, generic_columns, lsq, refine
from .columns import TrialModel, every_sample, model_columns, shape_columns
from .effects import Effect, Samples, projection_gain
from .results import ProfileOpen

log = logging.getLogger(__name__)


#: samples a profiled parameter's timing is polished on, and a full alignment (refine's)
PROFILE_SAMPLES = 30_000


REFINE_SAMPLES = 120_000


def alike_scale(a: Alignment, b: Alignment, n_fit: int) -> float | None:
    """Two fits of the same reading at different timings: where the worse is worse by
    ``dchi2`` <= 9 (in units of the better's residual variance over ``n_fit`` samples),
    ``sqrt(dchi2)`` (at least 1): a quantity that differs by ``d`` between them has the
    standard uncertainty ``d / scale`` on a quadratic profile (``d`` where the two fit
    alike); None when they do not fit alike."""
    better, worse = (a, b) if a.rms_um <= b.rms_um else (b, a)
    dchi2 = n_fit * (worse.rms_um ** 2 - better.rms_um ** 2) / max(better.rms_um ** 2, 1e-30)
    if dchi2 > 9.0:
        return None
    return math.sqrt(max(dchi2, 1.0))


def alike_spread(a: Alignment, b: Alignment, n_fit: int) -> tuple[float, float] | None:
    """The standard uncertainty (offset s, clock ppm) the distance between two fits
    that fit alike implies (:func:`alike_scale`); None when they do not."""
    scale = alike_scale(a, b, n_fit)
    if scale is None:
        return None
    return (abs(a.offset_s - b.offset_s) / scale, abs(a.clock_ppm - b.clock_ppm) / scale)


def profile_timing(ctx: Context, lib: list[Effect], expected: np.ndarray, t_m: np.ndarray,
                    y: np.ndarray, pose: list[np.ndarray], findings: list, al: Alignment,
                    jump: SetupStep | None) -> tuple[bool, tuple[float, float]]:
    """Lags trade with the recording's start: the alignment puts the reference lag into
    the offset, and a finding read through a lag (a servo mismatch reads the axis rates
    as late as the reference axis lags; an equal lag's shrink is read as late as the
    lag) then pulls the start to meet its own timing - microns of it against the
    tenths the geometry reads the start from - by ten milliseconds and more (hard cases:
    blind-bad-SDIT_C-s1-3, a mismatch; blind-bad-SDIT_B-s1-2, a lag).  Each such
    parameter is profiled with the timing: for every other value of the effect's grid
    (then around the best one) the timing is polished with every column, the lowest
    residual wins and the finding's parameter is set to it.

    The profile also says how far the timing is known once the parameter is free: a
    value whose fit is worse by ``dchi2`` (in units of the residual's variance over the
    samples polished) with its timing ``d`` away implies a standard uncertainty of
    ``d / sqrt(dchi2)`` on a quadratic profile (``d`` where the two fit alike).  So do
    the parameter itself and the finding's other parameters, fitted with it at each
    value: along a flat profile the common lag, the start and the lag differences move
    together (hard case: the memory benchmark's one-hour recording, whose runs that
    differed only in rounding put the common lag anywhere from 2.5 to 6 ms); the
    largest of those, and how each parameter moves along the profile, are kept on the
    finding (``profile``) for the read-out.  True when a parameter changed, and the
    largest offset (s) and clock (ppm) uncertainty over the values within 3 standard
    uncertainties."""
    changed = False
    widen = [0.0, 0.0]
    yc = y if jump is None else y - jump.reading_um(ctx, al, t_m)
    n_fit = min(int(np.isfinite(yc).sum()), PROFILE_SAMPLES)
    by = {e.name: e for e in lib}
    for f in findings:
        eff = by[f.effect]
        if eff.timing_parameter is None:
            continue
        key, grid = eff.timing_parameter
        f.profile = None
        rest = model_columns(ctx, lib, expected, [g for g in findings if g is not f])[:, 2:]
        fits: dict[float, Alignment] = {}
        found: dict[float, dict] = {}  # the finding's parameters fitted at each value
        model = TrialModel(ctx, expected, [*pose, rest])

        def trial(c: float) -> float:
            c = float(c)
            if c not in fits:
                nl = {**f.nonlinear, key: c}
                cols, labels = every_sample(eff, ctx, nl)
                X = model.with_columns(cols)
                fits[c] = refine(ctx, X, t_m, yc, al.offset_s, al.clock_ppm, iterations=4,
                                 max_samples=PROFILE_SAMPLES, check=False)
                if cols.shape[1] and (np.ptp(cols, axis=0) > 1e-9).all():
                    # (every column of the finding kept: they are the model's last)
                    beta = coefficients_at(ctx, X, t_m, yc, fits[c], PROFILE_SAMPLES)
                    with np.errstate(invalid="ignore", divide="ignore"):
                        found[c] = eff.parameters(beta[-cols.shape[1]:], labels, nl, ctx)
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
        # difference times the acceleration, and a common lag left on the fine grid's
        # step leaves that for a mode's deflection to take up
        # (hard case: blind-bad-SDIT_B-s1-37)
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
            # says nothing about the parameter: a tie must not move the start; what it
            # leaves open is read around the value kept
            kept = f.nonlinear.get(key)
            if isinstance(kept, float) and math.isfinite(kept):
                trial(kept)
                f.profile = _opened(key, float(kept), fits, found, n_fit)
            continue
        f.profile = _opened(key, best, fits, found, n_fit)
        b = fits[best]
        for c, a in fits.items():
            spread = alike_spread(a, b, n_fit)
            if spread is not None:
                widen = [max(w, v) for w, v in zip(widen, spread)]
        if best != f.nonlinear.get(key):
            f.nonlinear[key] = best
            changed = True
    return changed, (widen[0], widen[1])


def _opened(key: str, at: float, fits: dict[float, Alignment], found: dict[float, dict],
            n_fit: int) -> ProfileOpen:
    """What a profile of ``key`` leaves open around the value ``at``: per parameter
    (``key`` itself, or one of the finding's ``found`` at each value) the largest
    ``d / sqrt(dchi2)`` over the values that fit alike (:func:`alike_scale`), ``d`` how
    far it lies from its value at ``at``; and its slope along the profile, a straight
    line through its values at ``at``, at those that fit alike and at the nearest value
    on either side."""
    std = {key: 0.0}
    ref = found.get(at, {})
    near = {at}
    for c, a in fits.items():
        scale = alike_scale(a, fits[at], n_fit)
        if scale is None:
            continue
        near.add(c)
        std[key] = max(std[key], abs(c - at) / scale)
        for name, v in found.get(c, {}).items():
            w = ref.get(name)
            if name != key and isinstance(v, float) and isinstance(w, float) \
                    and math.isfinite(v - w):
                std[name] = max(std.get(name, 0.0), abs(v - w) / scale)
    below, above = [c for c in fits if c < at], [c for c in fits if c > at]
    near.update([max(below)] if below else [])
    near.update([min(above)] if above else [])
    slope = {}
    for name, w in ref.items():
        pts = [(c, found[c][name]) for c in sorted(near) if c in found
               and isinstance(found[c].get(name), float) and math.isfinite(found[c][name])]
        if name != key and isinstance(w, float) and len(pts) >= 2:
            cs, vs = np.array(pts).T
            slope[name] = float(np.polyfit(cs, vs, 1)[0])
    return ProfileOpen(std, slope)


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
    nearest valley: a pulse is read rising over the end of its grid, with the start
    milliseconds early and stated far tighter, while the pulses searched at the true
    start fit far better (hard case: blind-bad-SDIT_C-s2-39).

    The best shift's shape, if it beats the shape held by more than 9 in chi-square, is
    polished with every column from the start moved by the shift and taken (the
    alignment returned, the finding's parameters set) only when it fits better than the
    timing held; then searched again from there (``rounds`` in all).  Where the two fit
    about as well (chi-square within 9), the timing is known no better than they
    differ: the amounts (offset s, clock ppm) to widen by, and why, are returned too."""
    by = {e.name: e for e in lib}
    n_fit = min(int(np.isfinite(y).sum()), REFINE_SAMPLES)
    taken, widen, why = None, (0.0, 0.0), ""
    for f in findings:
        eff = by[f.effect]
        if not eff.shape_holds_timing:
            continue
        rest = generic_columns(ctx, expected, [
            *pose, model_columns(ctx, lib, expected, [g for g in findings if g is not f])[:, 2:]])

        def model() -> np.ndarray:  # every column, with the findings as they are now
            return generic_columns(ctx, expected, [
                *pose, model_columns(ctx, lib, expected, findings)[:, 2:],
                shape_columns(ctx, lib, findings)])

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
                S = Samples(nearest_samples(ctx, tt), tt)
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
