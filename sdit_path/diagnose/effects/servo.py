"""The servo loops: an equal lag of every axis, and lags that differ between axes."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from ...reading.context import Context
from ...reading.rows import blocks
from .base import Effect, filtered_blocks, grid_search, memo, projection_gain


class ServoLag(Effect):
    name, title = "servo_lag", "equal servo lag of all axes: radius shrink ~ v^2"
    trade_name = "servo lag (equal on all axes)"
    parameter_notes = MappingProxyType({"tau_ms": "the lag of every axis",
                                        "kv_per_s": "the position loop gain (1 / lag)"})
    commonness, time_locked = 2, True
    #: Equal servo lag shrinks the path by (v tau)^2 / (2 R); a control's smoothing set
    #: as a path tolerance shortcuts the same curves by an amount that does not grow with
    #: the feed, one set as a time filter by (v sigma)^2 / (2 R) like the lag - then only
    #: the static nodes tell them apart (a lag arrives late and one-sided, a zero-phase
    #: filter leaves early and arrives late, symmetric about the stop).
    aliases = MappingProxyType({
        "contour_smoothing":
            "run the layer again at a second feed (a path-tolerance smoothing does not grow "
            "with the feed, a lag's shrink grows as its square) and compare how the reading "
            "leaves and reaches the static nodes (a lag is one-sided, a zero-phase "
            "smoothing symmetric)",
    })
    #: the two readings put the start in different places (a lag carries its delay into
    #: the offset, a zero-phase smoothing does not)
    timing_alias = "contour_smoothing"
    reverse, feed_power = 1, 2.0
    limits = MappingProxyType({"tau_ms": 200.0})
    grid_ms = tuple(float(x) for x in np.round(np.geomspace(3.0, 150.0, 25), 3))
    timing_parameter = ("tau_ms", grid_ms)

    def __init__(self):
        self._cache: dict = {}

    def shrink_um(self, ctx: Context, idx: np.ndarray, tau_ms: float) -> np.ndarray:
        """Radial deviation (um) at trajectory samples ``idx`` when every axis follows
        its command through a first-order lag ``tau_ms`` (Kv = 1/tau)."""
        radial = memo(self._cache, ctx, tau_ms,
                       lambda: lagged_radial_um(ctx, tau_ms * 1e-3).astype(np.float32))
        # the lag also delays the machine along its path, and that delay cannot be told
        # from a later start: the alignment has put it into the offset, so program time
        # here is the commanded time of where the machine is - read the shrink tau later
        dt = (ctx.t_s[-1] - ctx.t_s[0]) / max(ctx.n - 1, 1)
        shifted = np.minimum(idx + int(round(tau_ms * 1e-3 / dt)), ctx.n - 1)
        return radial[shifted].astype(float)

    def search(self, ctx, s, r):
        # a fixed grid (cached across steps): every third value, then the neighbours
        g = self.grid_ms
        coarse = list(range(0, len(g), 3))
        gains = {i: projection_gain(self.shrink_um(ctx, s.idx, g[i])[:, None], r) for i in coarse}
        best = max(gains, key=gains.get)
        for i in range(max(best - 2, 0), min(best + 3, len(g))):
            if i not in gains:
                gains[i] = projection_gain(self.shrink_um(ctx, s.idx, g[i])[:, None], r)
        return {"tau_ms": g[max(gains, key=gains.get)]}

    def columns(self, ctx, s, nl):
        return self.shrink_um(ctx, s.idx, nl["tau_ms"])[:, None], ("scale",)

    def physical(self, coef):
        return coef[0] > 0

    def parameters(self, coef, labels, nl, ctx):
        # the shrink grows as tau^2: an amplitude factor c means tau * sqrt(c)
        tau = nl["tau_ms"] * float(np.sqrt(max(coef[0], 0.0)))
        return {"tau_ms": tau, "kv_per_s": (1e3 / tau) if tau > 0 else float("inf")}


def lagged_radial_um(ctx: Context, tau_s: float) -> np.ndarray:
    """First-order lag (Tustin) of the ball path in the table frame by ``tau_s``, as
    radial deviation in um on the whole trajectory grid."""
    from scipy.signal import lfilter

    dt = float(np.median(np.diff(ctx.t_s)))
    k = 2.0 * tau_s / dt
    p0 = ctx.ball_mm[0]
    if ctx.tall:  # (a block of samples at a time, the same numbers)
        out = np.empty(ctx.n)
        for a, b, y in filtered_blocks([1.0, 1.0], [1.0 + k, 1.0 - k], ctx.n,
                                       lambda a, b: ctx.ball_mm[a:b] - p0, np.zeros((1, 3))):
            out[a:b] = (np.linalg.norm(y + p0 - ctx.pivot_mm, axis=1) - ctx.length_mm[a:b]) * 1e3
        return out
    lagged = lfilter([1.0, 1.0], [1.0 + k, 1.0 - k], ctx.ball_mm - p0, axis=0) + p0
    return (np.linalg.norm(lagged - ctx.pivot_mm, axis=1) - ctx.length_mm) * 1e3


#: a servo mismatch's nonlinear parameters: the lag differences its second-order
#: columns are built with (found by its search; not reported, the fitted lags are)
SECOND_ORDER = "second_order_lag_"


class ServoMismatch(Effect):
    name, title = "servo_mismatch", "different servo lags per axis: ~v, flips with direction"
    trade_name, headline = "servo mismatch", 0
    parameter_notes = MappingProxyType({
        "common_lag_ms": "the servo lag all axes share; it moves the whole reading in time as "
                         "the recording's start does, so the two are read together"})
    commonness, time_locked = 6, True
    reverse, feed_power = -1, 1.0
    limits = MappingProxyType({"lag_*": 8.0, "common_lag_ms": 200.0})
    grid_ms = (0.0, 3.0, 6.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 65.0, 80.0, 100.0)
    timing_parameter = ("common_lag_ms", grid_ms)

    def __init__(self):
        self._cache: dict = {}
        self._secant_cache: dict = {}

    def _axes(self, ctx):
        """The axes that move (the first is the reference), read once per context (a
        long program's columns are made a block of rows at a time)."""
        key = ("servo axes",)
        if key not in ctx.cache:
            moving = [j for j in ctx.observable
                      if np.ptp(ctx.q[:, j]) > (1e-6 if j not in ctx.linear else 1e-3)]
            ctx.cache[key] = (moving[1:], (moving[0] if moving else 0))
        return ctx.cache[key]

    def rates(self, ctx: Context, common_ms: float) -> np.ndarray:
        """``(n, m)`` axis rates of the other axes as a lag difference reads them when
        the reference axis lags ``common_ms``.

        Axis j following its command through a first-order lag tau + d instead of tau
        is off by L(tau + d) q - L(tau) q = -d * s L(tau) L(tau + d) q: the rate through
        two lags, about 2 tau late.  The alignment has put the reference lag tau into the
        offset, so in program time the rate is read about tau late; read without that
        lag, the mismatch (microns where the geometry reads tenths) drags the start late
        to meet it (hard case: blind-bad-SDIT_C-s1-3)."""
        return memo(self._cache, ctx, common_ms, lambda: self._lagged_rates(ctx, common_ms),
                     digits=6)

    def _lagged_rates(self, ctx, common_ms):
        others, _ = self._axes(ctx)
        if ctx.tall and common_ms > 0:
            return self._lagged_rates_in_blocks(ctx, common_ms, others)
        v = ctx.qdot[:, others].astype(float)
        if common_ms > 0 and len(v):
            from scipy.signal import lfilter

            dt = (ctx.t_s[-1] - ctx.t_s[0]) / max(ctx.n - 1, 1)
            k = 2.0 * common_ms * 1e-3 / dt
            for _ in range(2):  # Tustin, from rest at the first rate
                v = lfilter([1.0, 1.0], [1.0 + k, 1.0 - k], v - v[0], axis=0) + v[0]
            shift = int(round(common_ms * 1e-3 / dt))
            v = np.concatenate([v[shift:], np.repeat(v[-1:], min(shift, len(v)), axis=0)])
        return v

    @staticmethod
    def _lagged_rates_in_blocks(ctx, common_ms, others):
        """:meth:`_lagged_rates` of a tall program: both lags a block of samples at a
        time, each from rest at its first input (the same numbers; whole, the rates and
        the filters' copies are 0.3 GB an hour), shifted in place."""
        from scipy.signal import lfilter

        dt = (ctx.t_s[-1] - ctx.t_s[0]) / max(ctx.n - 1, 1)
        k = 2.0 * common_ms * 1e-3 / dt
        b, a = [1.0, 1.0], [1.0 + k, 1.0 - k]
        out = np.empty((ctx.n, len(others)))
        v0 = ctx.qdot[0][others]
        w0, zi = None, np.zeros((1, len(others)))
        for start, stop, y in filtered_blocks(b, a, ctx.n,
                                              lambda i, j: ctx.qdot[i:j][:, others] - v0,
                                              np.zeros((1, len(others)))):
            w = y + v0
            w0 = w[0].copy() if w0 is None else w0
            y, zi = lfilter(b, a, w - w0, axis=0, zi=zi)
            out[start:stop] = y + w0
        return _read_later(out, int(round(common_ms * 1e-3 / dt)))

    def search(self, ctx, s, r):
        if not self._axes(ctx)[0]:
            return None
        nl = {"common_lag_ms": grid_search(
            self.grid_ms, lambda c: projection_gain(self.columns(ctx, s, {"common_lag_ms": c})[0], r),
            np.linspace)}
        # the lag differences' second order (d^2 times the axis' acceleration) needs the
        # differences themselves: iterated to them, like a play's width
        others, _ = self._axes(ctx)
        for _ in range(2):
            C, _labels = self.columns(ctx, s, nl)
            d = np.linalg.lstsq(C, r, rcond=None)[0]
            nl.update({f"{SECOND_ORDER}{ctx.axis_names[j]}": float(x) for j, x in zip(others, d)})
        return nl

    def columns(self, ctx, s, nl):
        others, ref = self._axes(ctx)
        common = float(nl.get("common_lag_ms", 0.0))
        # without a common lag the rates are the axes' own: a tall program's read at the
        # rows asked for (held whole, two axes' are 54 MB an hour)
        v = ctx.qdot[s.idx][:, others] if common == 0 and ctx.tall else self.rates(ctx, common)[s.idx]
        # axis error -qdot * lag to first order; um of reading per ms of lag.  Where the
        # search has found a lag difference h, the column is the exact error of that
        # difference divided by it (a secant: fitted h gives the error itself), because
        # its second order (h^2 times the axis' acceleration, through the common lag as
        # well) reaches microns at the accelerations: left out, a linear axis takes it
        # up as a mode's deflection (hard case: test-five-axis-rotary-mismatch), and
        # built without the common lag it pulls the start and brings a mode beside it
        # (hard case: blind-bad-SDIT_B-s1-37)
        hints = tuple(round(float(nl.get(f"{SECOND_ORDER}{ctx.axis_names[j]}", 0.0)), 6)
                      for j in others)
        exact = self._secants(ctx, common, hints) if any(hints) else None
        cols = []
        g = ctx.gain[s.idx]  # (every axis' gain at once: a long program's are made per read)
        for i, j in enumerate(others):
            rate = -v[:, i] if exact is None or not hints[i] else exact[s.idx, i]
            cols.append(g[:, j] * rate)
        labels = tuple(f"lag_{ctx.axis_names[j]}_minus_{ctx.axis_names[ref]}_ms" for j in others)
        return np.column_stack(cols) if cols else np.zeros((len(s.idx), 0)), labels

    def _secants(self, ctx, common_ms, hints):
        """``(n, m)`` exact axis errors ``(L(tau + h) - L(tau)) q / h`` (axis units per
        s, read in program time like :meth:`rates`) of lag differences ``hints`` (ms)
        beside the common lag ``tau``; a zero hint gives a zero column (unused)."""
        return memo(self._secant_cache, ctx, (round(common_ms, 6), hints),
                     lambda: self._lag_differences(ctx, common_ms, hints))

    def _lag_differences(self, ctx, common_ms, hints):
        from scipy.signal import lfilter

        others, _ = self._axes(ctx)
        dt = (ctx.t_s[-1] - ctx.t_s[0]) / max(ctx.n - 1, 1)
        if ctx.tall:
            return self._lag_differences_in_blocks(ctx, common_ms, hints, others, dt)
        q = ctx.q[:, others].astype(float)
        q = q - q[0]

        def lag(x, tau_ms):
            if tau_ms <= 0:
                return x
            k = 2.0 * tau_ms * 1e-3 / dt
            return lfilter([1.0, 1.0], [1.0 + k, 1.0 - k], x)

        out = np.zeros_like(q)
        for i, h in enumerate(hints):
            if h:
                base = lag(q[:, i], common_ms)
                out[:, i] = (lag(q[:, i], common_ms + h) - base) / (h * 1e-3)
        shift = int(round(common_ms * 1e-3 / dt))
        if shift:
            out = np.concatenate([out[shift:], np.repeat(out[-1:], min(shift, len(out)), axis=0)])
        return out

    @staticmethod
    def _lag_differences_in_blocks(ctx, common_ms, hints, others, dt):
        """:meth:`_lag_differences` of a tall program: each lag a block of samples at a
        time from rest (the same numbers), shifted in place."""
        from scipy.signal import lfilter

        out = np.zeros((ctx.n, len(others)))
        q0 = ctx.q[0, others]
        for i, h in enumerate(hints):
            if not h:
                continue
            lags = (common_ms, common_ms + h)
            coef = [([1.0, 1.0], [1.0 + 2.0 * tau * 1e-3 / dt, 1.0 - 2.0 * tau * 1e-3 / dt])
                    for tau in lags]
            zi = [np.zeros(1), np.zeros(1)]
            for start, stop in blocks(ctx.n):
                x = ctx.q[start:stop, others[i]] - q0[i]
                ys = []
                for m, tau in enumerate(lags):
                    if tau <= 0:
                        ys.append(x)
                        continue
                    y, zi[m] = lfilter(*coef[m], x, zi=zi[m])
                    ys.append(y)
                out[start:stop, i] = (ys[1] - ys[0]) / (h * 1e-3)
        return _read_later(out, int(round(common_ms * 1e-3 / dt)))

    def from_fit(self, nl, coef, labels):
        # label lag_<axis>_minus_<ref>_ms -> that axis' difference, within the limits
        lim = self.limits["lag_*"]
        out = dict(nl)
        for lab, c in zip(labels, coef):
            h = float(np.clip(c, -lim, lim))
            axis = lab[len("lag_"):lab.index("_minus_")]
            out[f"{SECOND_ORDER}{axis}"] = round(h, 4) if abs(h) >= 1e-4 else 0.0
        return out

    def shape_parameters(self, nonlinear):
        # the second-order hints follow from the fitted lags (``from_fit``)
        return {k: v for k, v in nonlinear.items() if not k.startswith(SECOND_ORDER)}

    def parameters(self, coef, labels, nl, ctx):
        out = {k: float(v) for k, v in nl.items() if not k.startswith(SECOND_ORDER)}
        out.update({lab: float(c) for lab, c in zip(labels, coef)})
        return out


def _read_later(out: np.ndarray, shift: int) -> np.ndarray:
    """``out`` read ``shift`` samples later, its last row held at the end (in place:
    ``np.concatenate([out[shift:], np.repeat(out[-1:], shift, axis=0)])``)."""
    if shift:
        last = out[-1].copy()
        out[:-shift] = out[shift:]
        out[-min(shift, len(out)):] = last
    return out
