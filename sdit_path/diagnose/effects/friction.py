"""Friction: a pulse after an axis reverses, and stick-slip where an axis crawls."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from ...reading.context import directions, reversals
from .base import Effect, beside_basis, grid_search, linear_axes, projection_gain


class ReversalSpike(Effect):
    """A decaying pulse after an axis reversal: friction changes sign with the axis'
    velocity and the velocity loop takes a few ms to answer.  Where the pulse starts is
    a parameter too: at the sign change, or once the axis has reached a breakaway
    speed (``onset_mm_s``); on a slow reversal inside a curve (2 mm/s^2 through zero)
    0.05 mm/s comes 25 ms after the sign change, and a pulse put at the sign change
    bends the timing by about as much."""

    name, title = "reversal_spike", "decaying pulse after an axis reversal (friction)"
    headline = 2
    parameter_notes = MappingProxyType({"tau_ms": "the time constant of the decay",
                                        "onset_mm_s": "the axis speed at which the pulse begins",
                                        "rise_ms": "the pulse's rise time"})
    commonness, time_locked = 5, True
    #: both act for tens of ms after an axis reverses; at one feed a small stick-slip and
    #: a pulse are a few hundredths of a micrometre apart, and the simpler-finding rule
    #: names the stick-slip a pulse (hard case: blind-bad-SDIT_B-s2-40).  They leave the
    #: start alike: no timing alias.
    aliases = MappingProxyType({
        "stick_slip":
            "run the layer again at a second feed (a friction pulse grows with the feed; a "
            "stick-slip lives where an axis crawls, below about 200 mm/min, and lasts "
            "longer at a lower feed)",
    })
    reverse, feed_power = -1, 0.0
    # the brief: tau 10-100 ms; the pulse rises over a few ms (friction breaking away
    # through the velocity loop), it does not jump
    limits = MappingProxyType({"height_*": 50.0, "tau_ms": 100.0})
    grid_ms = (5.0, 8.0, 12.0, 18.0, 25.0, 35.0, 50.0, 70.0, 100.0)
    #: the rise (ms) is searched too: a velocity loop answers in 1-10 ms, and a rise held
    #: fixed on a pulse that rises slower bends the timing by milliseconds while the fit
    #: stays at the noise, where the pulses are all the timing a trace holds
    #: (hard case: blind-bad-SDIT_B-s1-39)
    rise_grid_ms = (1.0, 1.5, 2.0, 3.0, 4.0, 5.5, 7.5, 10.0)
    rise_ms = 3.0
    #: speeds (mm/s) at which the pulse may start; the first is the sign change itself
    onsets_mm_s = (0.001, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
    discrete = ("onset_mm_s",)
    #: where every reversal is about as brisk, a later onset moves every pulse alike:
    #: the onset trades with the recording's start (the pulses may be all the timing a
    #: trace holds) and is profiled with it
    timing_parameter = ("onset_mm_s", onsets_mm_s)
    timing_end_implausible = False
    searches_with_fixed = True
    shape_holds_timing = True

    @staticmethod
    def _since(ctx, j, onset, idx):
        """At the samples ``idx``: the time since axis j last reversed, a reversal
        counted once the axis moves faster than ``onset`` (mm/s) the other way (inf
        before the first), and the direction since then: kept on every sample, or on a
        tall program as the reversals and the direction after each (the direction is
        constant between them; on every sample they are 50 MB an hour), the same
        numbers."""
        key = ("reversal_onset", j, onset)
        if key not in ctx.cache:
            d = directions(ctx.qdot[:, [j]], onset)[:, 0]
            flips, last = reversals(d)
            ctx.cache[key] = (flips, d[flips], d[:1].copy()) if ctx.tall else (
                np.where(last >= 0, ctx.t_s - ctx.t_s[np.maximum(last, 0)], np.inf), d)
        if not ctx.tall:
            since, d = ctx.cache[key]
            return since[idx], d[idx]
        flips, after, first = ctx.cache[key]
        k = np.searchsorted(flips, idx, side="right") - 1
        last = flips[np.maximum(k, 0)] if len(flips) else np.zeros(len(k), dtype=int)
        since = np.where(k >= 0, ctx.t_s[idx] - ctx.t_s[last], np.inf)
        d = after[np.maximum(k, 0)] if len(flips) else np.repeat(first, len(k))
        return since, np.where(k >= 0, d, first[0] if len(first) else 1.0)

    def _cols(self, ctx, s, tau_ms, onset=onsets_mm_s[0], rise_ms=rise_ms):
        cols = []
        g = ctx.gain[s.idx]  # (every axis' gain at once: a long program's are made per read)
        for j in linear_axes(ctx):
            since, d = self._since(ctx, j, onset, s.idx)
            since = np.minimum(since, 50.0)
            decay = (1.0 - np.exp(-since / (rise_ms * 1e-3))) * np.exp(-since / (tau_ms * 1e-3))
            cols.append(-g[:, j] * d * decay)
        return np.column_stack(cols)

    def _scorer(self, ctx, s, r, onset):
        """``score(tau_ms, rise_ms)``: :func:`projection_gain` of the pulses' columns, from
        the samples within a second of a reversal only (beyond it the longest pulse has
        decayed to e^-10) and the columns' 3 x 3 normal equations; None without them
        (or with :func:`fitted_beside`'s basis, which needs every sample)."""
        if beside_basis() is not None:
            return lambda t, q: projection_gain(self._cols(ctx, s, t, onset, q), r)
        since, weight = [], []
        for j in linear_axes(ctx):
            sj, d = self._since(ctx, j, onset, s.idx)
            since.append(sj)
            weight.append(-ctx.gain[s.idx, j] * d)
        since, weight = np.column_stack(since), np.column_stack(weight)
        near = np.flatnonzero((since < 1.0).any(axis=1))
        since, weight, rr = since[near], weight[near], r[near]

        def score(tau_ms, rise_ms):
            C = weight * ((1.0 - np.exp(-since / (rise_ms * 1e-3)))
                          * np.exp(-since / (tau_ms * 1e-3)))
            b = C.T @ rr
            coef = np.linalg.lstsq(C.T @ C, b, rcond=None)[0]
            return float(coef @ b)

        return score

    def search(self, ctx, s, r, fixed: dict | None = None):
        """Per onset speed (or at the one in ``fixed``, profiled with the timing) the
        time constant on its grid at the middle rise; for the best onset the rise and
        the time constant then in turn (they trade with each other: a longer rise with
        a shorter decay), twice, and together between the grids' points (a simplex in
        their logarithms)."""
        if not any(len(ctx.reversal_times[j]) for j in linear_axes(ctx)):
            return None
        onsets = ((fixed["onset_mm_s"],) if fixed and "onset_mm_s" in fixed
                  else self.onsets_mm_s)
        best: tuple | None = None
        for onset in onsets:
            score = self._scorer(ctx, s, r, onset)
            tau = grid_search(self.grid_ms, lambda t: score(t, self.rise_ms), np.geomspace)
            g = score(tau, self.rise_ms)
            if best is None or g > best[0]:
                best = (g, onset, tau, score)
        if best is None:
            return None
        g, onset, tau, score = best
        rise = self.rise_ms
        for _ in range(2):
            rise = grid_search(self.rise_grid_ms, lambda q: score(tau, q), np.geomspace)
            tau = grid_search(self.grid_ms, lambda t: score(t, rise), np.geomspace)
        g = score(tau, rise)
        from scipy.optimize import minimize

        lo = np.log([self.grid_ms[0], self.rise_grid_ms[0]])
        hi = np.log([self.grid_ms[-1], self.rise_grid_ms[-1]])

        def loss(z):
            return -score(*np.exp(np.clip(z, lo, hi)))

        res = minimize(loss, np.log([tau, rise]), method="Nelder-Mead",
                       options={"xatol": 0.01, "fatol": 1e-9 * max(g, 1e-30), "maxfev": 60,
                                "initial_simplex": np.log([[tau, rise], [tau * 1.1, rise],
                                                           [tau, rise * 1.15]])})
        if -res.fun > g:
            tau, rise = (float(v) for v in np.exp(np.clip(res.x, lo, hi)))
        return {"tau_ms": float(tau), "onset_mm_s": onset, "rise_ms": float(rise)}

    def implausible(self, params):
        why = super().implausible(params)
        tau = params.get("tau_ms")
        if why is None and isinstance(tau, float):
            # the data want a decay beyond the search, and friction decays over 10-100 ms
            # (the brief): shorter, it is a stick-slip's edge read as a companion pulse
            # (hard case: blind-bad-SDIT_C-s1-6); longer (as a lag at the end of its
            # grid), a slow ramp beside a play taken up over a 5-axis program's slow
            # reversals (hard case: blind-bad-SDIT5_C-s1-38)
            lo, hi = self.grid_ms[0], self.grid_ms[-1]
            if tau <= lo * (1 + 1e-9):
                return f"tau_ms = {tau:.4g} at the short end of its search ({lo:g})"
            if tau >= hi * (1 - 1e-9):
                return f"tau_ms = {tau:.4g} at the long end of its search ({hi:g})"
        return why

    def columns(self, ctx, s, nl):
        return self._cols(ctx, s, nl["tau_ms"], nl.get("onset_mm_s", self.onsets_mm_s[0]),
                          nl.get("rise_ms", self.rise_ms)), tuple(
            f"height_{ctx.axis_names[j]}_um" for j in linear_axes(ctx))


STICK_SLIP_SPEED_MM_PER_S = 200.0 / 60.0


class StickSlip(Effect):
    """An axis that crawls (slower than ~200 mm/min, near its reversals) sticks: its
    command runs on and the lag grows with the commanded travel until the spring force
    of the drive breaks the friction; it then slips forward, often past the command.
    The slip comes after a fixed travel (the stick distance: friction step over drive
    stiffness), not after a fixed time: a saw-tooth in the travel since the crawl
    began, its period in time growing as the axis slows.  Per axis: the mean lag while
    crawling (against the direction of motion) and the saw-tooth about it."""

    name, title = "stick_slip", "saw-tooth while an axis crawls near a reversal"
    trade_name = "stick-slip"
    commonness, time_locked = 12, True
    limits = MappingProxyType({"amplitude_*": 8.0, "mean_lag_*": 8.0})
    grid_um = (0.5, 0.8, 1.3, 2.0, 3.2, 5.0, 8.0, 12.0)

    def _cols(self, ctx, s, stick_um):
        cols = []
        for j in linear_axes(ctx):
            slow, _ = ctx.slow_state(j, STICK_SLIP_SPEED_MM_PER_S)
            travel, at_entry = ctx.crawl_travel(j, STICK_SLIP_SPEED_MM_PER_S)
            i = s.idx
            x = (np.interp(s.tau_s, ctx.t_s, travel) - at_entry[i]) / (stick_um * 1e-3)
            saw = 2.0 * (x - np.floor(x)) - 1.0
            against = -ctx.gain[i, j] * ctx.direction[i, j] * slow[i]
            cols += [against, against * saw]
        return np.column_stack(cols)

    def search(self, ctx, s, r):
        return {"stick_um": grid_search(
            self.grid_um, lambda p: projection_gain(self._cols(ctx, s, p), r), np.geomspace)}

    def columns(self, ctx, s, nl):
        return self._cols(ctx, s, nl["stick_um"]), tuple(
            f"{kind}_{ctx.axis_names[j]}_um" for j in linear_axes(ctx)
            for kind in ("mean_lag", "amplitude"))

    def unsure_in_time(self, ctx, params):
        """The crawls of the axes that stick.  Within them the saw-tooth's phase is the
        friction's, not the program's (sampled, a tooth of 3.5 um at 3 mm/s is shorter
        than a sample), and what the columns leave of it is not noise: read with the
        crawls, the start moves by milliseconds, several times what the timing states
        (hard case: blind-bad-SDIT_B-s1-40)."""
        size = {j: abs(params.get(f"mean_lag_{ctx.axis_names[j]}_um", 0.0))
                + abs(params.get(f"amplitude_{ctx.axis_names[j]}_um", 0.0))
                for j in linear_axes(ctx)}
        top = max(size.values(), default=0.0)
        if top <= 0.0:
            return None
        mask = np.zeros(ctx.n, bool)
        for j, s in size.items():
            if s >= 0.2 * top:
                mask |= ctx.slow_state(j, STICK_SLIP_SPEED_MM_PER_S)[0]
        return mask
