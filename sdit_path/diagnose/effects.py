"""The library of candidate effects: compact physical models of what a real ballbar
trace contains beyond the simulated geometry (domain brief, section 3).

Each effect gives regressor columns (um of bar reading per unit of a parameter) on a
set of samples; effects with a nonlinear parameter (a time constant, a pitch, a
frequency, a window) first search it on the current residual.  Axis effects act on a
machine axis and reach the bar through ``Context.gain`` (the bar reading change per
unit axis error), so they hold for 3- and 5-axis machines alike.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib

from dataclasses import dataclass, field

import numpy as np

from ..errormodel.chain import sensitivities
from ..errormodel.model import ModelOptions, build_model
from ..machine.kinematics import Kinematics
from .align import sample_at
from ..reading.context import Context, directions, reversals

STICK_SLIP_SPEED_MM_PER_S = 200.0 / 60.0


@dataclass(frozen=True, slots=True)
class Samples:
    """A set of trace samples: ``idx : (n,)`` nearest trajectory sample, ``tau_s : (n,)``
    exact program time."""

    idx: np.ndarray
    tau_s: np.ndarray

    def take(self, keep: np.ndarray) -> "Samples":
        return Samples(self.idx[keep], self.tau_s[keep])


@dataclass(frozen=True, slots=True)
class Design:
    effect: str
    labels: tuple[str, ...]
    nonlinear: dict = field(default_factory=dict)


#: an orthonormal basis (n, k) of columns fitted beside a searched effect's, or None:
#: set by :func:`fitted_beside` while a search runs
_BESIDE: contextvars.ContextVar = contextvars.ContextVar("beside", default=None)


@contextlib.contextmanager
def fitted_beside(basis: np.ndarray | None):
    """Within this block, every search judges its columns as fitted together with the
    columns ``basis`` spans (``r`` orthogonal to them): the reduction a joint fit would
    give.  A raw projection lets the earlier fit keep what the new columns share with it
    (a set-up fitted alone takes part of a smoothing's shrink while moving, and the
    smoothing's search then preferred its shortest filter)."""
    token = _BESIDE.set(basis)
    try:
        yield
    finally:
        _BESIDE.reset(token)


def _memo(cache: dict, ctx: Context, value: float, make, digits: int = 9):
    """``make()`` for one context and parameter value, kept in ``cache`` (at most 24
    entries: the grid and the profiled values of one diagnosis).  The context rides
    along with its result so that its id cannot be reused while cached."""
    key = (id(ctx), round(value, digits) if isinstance(value, float) else value)
    if key not in cache:
        if len(cache) >= 24:
            cache.pop(next(iter(cache)))
        cache[key] = (ctx, make())
    return cache[key][1]


def projection_gain(cols: np.ndarray, r: np.ndarray) -> float:
    """Reduction of ``|r|^2`` by least squares on ``cols`` (fitted beside
    :func:`fitted_beside`'s columns, if any)."""
    if cols.size == 0:
        return 0.0
    Q = _BESIDE.get()
    if Q is not None and Q.shape[0] == cols.shape[0]:
        cols = cols - Q @ (Q.T @ cols)
    coef, *_ = np.linalg.lstsq(cols, r, rcond=None)
    fit = cols @ coef
    return float(r @ r - (r - fit) @ (r - fit))


#: a column whose best projection takes less than this share of the residual's energy
#: explains nothing (an axis the bar does not see at these poses)
NEGLIGIBLE = 1e-6


def _grid_search(grid, score, spacing) -> float:
    """The best value of a one-dimensional parameter: ``score`` on ``grid``, then on 9
    points (``np.geomspace`` or ``np.linspace``) between the best one's neighbours."""
    k = int(np.argmax([score(v) for v in grid]))
    fine = spacing(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 9)
    return float(fine[int(np.argmax([score(v) for v in fine]))])


def _gain2(s: np.ndarray, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Projection gains of ``r (n,)`` on many column pairs ``s, c : (m, n)`` at once."""
    ss, cc, sc = (s * s).sum(1), (c * c).sum(1), (s * c).sum(1)
    sr, cr = s @ r, c @ r
    det = ss * cc - sc * sc
    det = np.where(det > 1e-300, det, np.inf)
    a = (cc * sr - sc * cr) / det
    b = (ss * cr - sc * sr) / det
    return a * sr + b * cr


def _ripple_gains(x: np.ndarray, g: np.ndarray, r: np.ndarray, inv: np.ndarray,
                  block: int = 64) -> np.ndarray:
    """:func:`_gain2` of ``r`` on the pairs ``g sin(2 pi x f), g cos(2 pi x f)`` for the
    evenly spaced spatial frequencies ``inv``, from the sums the pairs' products reduce
    to: with ``z = exp(i 2 pi x f)``, ``sum g^2 sin^2 = (sum g^2 - Re sum g^2 z^2) / 2``,
    ``sum g^2 cos^2 = (sum g^2 + Re sum g^2 z^2) / 2``, ``sum g^2 sin cos = Im sum g^2 z^2
    / 2``, ``sum g r sin = Im sum g r z`` and ``sum g r cos = Re sum g r z``.  Within a
    block of frequencies ``z`` steps by multiplication (64 steps: a phase error of
    ~1e-14 rad), each block starting from ``exp`` again."""
    g2, gr = g * g, g * r
    total = float(g2.sum())
    out = np.zeros(len(inv))
    step = np.exp(2j * np.pi * x * (inv[1] - inv[0])) if len(inv) > 1 else None
    for b in range(0, len(inv), block):
        m = min(block, len(inv) - b)
        Z = np.empty((m, len(x)), complex)
        Z[0] = np.exp(2j * np.pi * x * inv[b])
        for k in range(1, m):
            np.multiply(Z[k - 1], step, out=Z[k])
        s1 = Z @ gr
        Z *= Z
        s2 = Z @ g2
        ss, cc, sc = 0.5 * (total - s2.real), 0.5 * (total + s2.real), 0.5 * s2.imag
        sr, cr = s1.imag, s1.real
        det = ss * cc - sc * sc
        det = np.where(det > 1e-300, det, np.inf)
        a = (cc * sr - sc * cr) / det
        bb = (ss * cr - sc * sr) / det
        out[b:b + m] = a * sr + bb * cr
    return out


class Effect:
    name = ""
    title = ""
    unit_note = ""

    def search(self, ctx: Context, s: Samples, r: np.ndarray) -> dict | None:
        return {}

    def columns(self, ctx: Context, s: Samples, nl: dict) -> tuple[np.ndarray, tuple[str, ...]]:
        raise NotImplementedError

    def parameters(self, coef: np.ndarray, labels, nl: dict, ctx: Context) -> dict:
        out = {k: float(v) for k, v in nl.items()}
        out.update({lab: float(c) for lab, c in zip(labels, coef)})
        return out

    def physical(self, coef: np.ndarray) -> bool:
        return True

    def from_fit(self, nl: dict, coef: np.ndarray, labels) -> dict | None:
        """Nonlinear parameters read back from the coefficients fitted with every other
        finding in (a lag difference that shapes its own second order), or None when
        none are."""
        return None

    #: a nonlinear parameter that trades with the recording's start (a lag: the alignment
    #: puts it into the offset) and the grid it is profiled on with the timing, or None
    timing_parameter: tuple[str, tuple[float, ...]] | None = None
    #: a lag at the far end of its grid is not this effect; other timing parameters (a
    #: pulse's onset speed) may lie at either end
    timing_end_implausible: bool = True
    #: ``search`` takes ``fixed=`` (parameters pinned by a profile with the timing)
    searches_with_fixed: bool = False
    #: the effect's shape may hold the recording's timing (pulses after reversals on a
    #: trace with little else), and its shape and the start trade with each other: its
    #: search is repeated with the effect shifted in time (``diagnose.shape_scan``)
    shape_holds_timing: bool = False

    #: how the effect's reading changes when the same path is run again: in the reverse
    #: direction it is multiplied by ``reverse`` (-1: odd in the velocity, +1: even;
    #: None: not that simple), at half the feed by 0.5 ** ``feed_power`` (None: not a
    #: power of the feed).  Used to name the run that separates it from the geometry.
    reverse: int | None = None
    feed_power: float | None = None

    #: parameter -> largest plausible magnitude on a machining centre (about twice the
    #: "bad" end of the domain brief's table); a fit beyond it is not this effect
    limits: dict = {}

    def unsure_in_time(self, ctx: Context, params: dict) -> np.ndarray | None:
        """Grid samples where the effect's model, as found (``params``: its sizes by
        label), leaves the reading open - a fine structure not locked to the program -
        or None.  The timing is read again without them and the two readings compared
        (``diagnose.settle``)."""
        return None

    def implausible(self, params: dict) -> str | None:
        for key, value in params.items():
            for pattern, lim in self.limits.items():
                if isinstance(value, float) and _match(key, pattern) and abs(value) > lim:
                    return f"{key} = {value:.4g} exceeds the plausible {lim:g}"
        if self.timing_parameter and self.timing_end_implausible:
            # a lag at the far end of its search: the data want a longer one, which is not
            # this effect (a backlash on the equator layer, its play taken up over a slow
            # reversal, read as a mismatch with a 100 ms common lag beside a stick-slip)
            key, grid = self.timing_parameter
            value = params.get(key)
            if isinstance(value, float) and grid[-1] > 0 and value >= grid[-1] * (1 - 1e-9):
                return f"{key} = {value:.4g} at the end of its search ({grid[-1]:g})"
        return None


def _match(key: str, pattern: str) -> bool:
    if pattern.endswith("*"):
        return key.startswith(pattern[:-1])
    if pattern.startswith("*"):
        return key.endswith(pattern[1:])
    return key == pattern


def linear_axes(ctx: Context):
    """Linear axes the bar can see."""
    return [j for j in ctx.linear if j in ctx.observable]



class SetupOffset(Effect):
    name, title = "setup_offset", "ball centring / set-up offset of the pivot"
    limits = {"d*": 2000.0}

    def columns(self, ctx, s, nl):
        u = ctx.u[s.idx]
        return -u, ("dx_um", "dy_um", "dz_um")


class BarLength(Effect):
    name, title = "bar_length", "bar length offset (calibration, constant thermal growth)"
    limits = {"dL_um": 1000.0}

    def columns(self, ctx, s, nl):
        return np.ones((len(s.idx), 1)), ("dL_um",)


class ThermalDrift(Effect):
    name, title = "thermal_drift", "slow drift in time: radial growth and pivot-to-spindle drift"
    limits = {"*_um_per_h": 60.0}  # the brief: up to 40 um/h in a Z warm-up

    def columns(self, ctx, s, nl):
        th = s.tau_s / 3600.0
        # the spindle drifts in the machine's frame (a Z warm-up stays along Z while a
        # rotary table turns the bar); on a machine without a rotary table the same as u
        u = ctx.u_bed[s.idx]
        cols = np.column_stack([th, th * th, u[:, 0] * th, u[:, 1] * th, u[:, 2] * th])
        return cols, ("radial_um_per_h", "radial_um_per_h2", "x_um_per_h", "y_um_per_h",
                      "z_um_per_h")

    def parameters(self, coef, labels, nl, ctx):
        out = {lab: float(c) for lab, c in zip(labels, coef)}
        # the radial rate at the end of the program (the quadratic bends it)
        out["radial_end_um_per_h"] = out["radial_um_per_h"] + 2 * out.pop("radial_um_per_h2") * (
            ctx.duration_s / 3600.0)
        return out


class ServoLag(Effect):
    name, title = "servo_lag", "equal servo lag of all axes: radius shrink ~ v^2"
    reverse, feed_power = 1, 2.0
    limits = {"tau_ms": 200.0}
    grid_ms = tuple(float(x) for x in np.round(np.geomspace(3.0, 150.0, 25), 3))
    timing_parameter = ("tau_ms", grid_ms)

    def __init__(self):
        self._cache: dict = {}

    def shrink_um(self, ctx: Context, idx: np.ndarray, tau_ms: float) -> np.ndarray:
        """Radial deviation (um) at trajectory samples ``idx`` when every axis follows
        its command through a first-order lag ``tau_ms`` (Kv = 1/tau)."""
        radial = _memo(self._cache, ctx, tau_ms,
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
    lagged = lfilter([1.0, 1.0], [1.0 + k, 1.0 - k], ctx.ball_mm - p0, axis=0) + p0
    return (np.linalg.norm(lagged - ctx.pivot_mm, axis=1) - ctx.length_mm) * 1e3


#: a servo mismatch's nonlinear parameters: the lag differences its second-order
#: columns are built with (found by its search; not reported, the fitted lags are)
SECOND_ORDER = "second_order_lag_"


class ServoMismatch(Effect):
    name, title = "servo_mismatch", "different servo lags per axis: ~v, flips with direction"
    reverse, feed_power = -1, 1.0
    limits = {"lag_*": 8.0, "common_lag_ms": 200.0}
    grid_ms = (0.0, 3.0, 6.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 65.0, 80.0, 100.0)
    timing_parameter = ("common_lag_ms", grid_ms)

    def __init__(self):
        self._cache: dict = {}
        self._secant_cache: dict = {}

    def _axes(self, ctx):
        moving = [j for j in ctx.observable
                  if np.ptp(ctx.q[:, j]) > (1e-6 if j not in ctx.linear else 1e-3)]
        return moving[1:], (moving[0] if moving else 0)

    def rates(self, ctx: Context, common_ms: float) -> np.ndarray:
        """``(n, m)`` axis rates of the other axes as a lag difference reads them when
        the reference axis lags ``common_ms``.

        Axis j following its command through a first-order lag tau + d instead of tau
        is off by L(tau + d) q - L(tau) q = -d * s L(tau) L(tau + d) q: the rate through
        two lags, about 2 tau late.  The alignment has put the reference lag tau into the
        offset, so in program time the rate is read about tau late; read without that
        lag, the mismatch (microns where the geometry reads tenths) drags the start
        12-13 ms late to meet it."""
        return _memo(self._cache, ctx, common_ms, lambda: self._lagged_rates(ctx, common_ms),
                     digits=6)

    def _lagged_rates(self, ctx, common_ms):
        others, _ = self._axes(ctx)
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

    def search(self, ctx, s, r):
        if not self._axes(ctx)[0]:
            return None
        nl = {"common_lag_ms": _grid_search(
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
        v = self.rates(ctx, common)
        # axis error -qdot * lag to first order; um of reading per ms of lag.  Where the
        # search has found a lag difference h, the column is the exact error of that
        # difference divided by it (a secant: fitted h gives the error itself), because
        # its second order (h^2 times the axis' acceleration, through the common lag as
        # well) reaches microns at the accelerations: a 1 ms mismatch of a rotary axis
        # left it for a linear axis to take up as a mode's deflection, and a 2 ms one
        # at F2000 without its common lag pulled the start 4 ms late
        hints = tuple(round(float(nl.get(f"{SECOND_ORDER}{ctx.axis_names[j]}", 0.0)), 6)
                      for j in others)
        exact = self._secants(ctx, common, hints) if any(hints) else None
        cols = []
        for i, j in enumerate(others):
            rate = -v[s.idx, i] if exact is None or not hints[i] else exact[s.idx, i]
            cols.append(ctx.gain[s.idx, j] * rate)
        labels = tuple(f"lag_{ctx.axis_names[j]}_minus_{ctx.axis_names[ref]}_ms" for j in others)
        return np.column_stack(cols) if cols else np.zeros((len(s.idx), 0)), labels

    def _secants(self, ctx, common_ms, hints):
        """``(n, m)`` exact axis errors ``(L(tau + h) - L(tau)) q / h`` (axis units per
        s, read in program time like :meth:`rates`) of lag differences ``hints`` (ms)
        beside the common lag ``tau``; a zero hint gives a zero column (unused)."""
        return _memo(self._secant_cache, ctx, (round(common_ms, 6), hints),
                     lambda: self._lag_differences(ctx, common_ms, hints))

    def _lag_differences(self, ctx, common_ms, hints):
        from scipy.signal import lfilter

        others, _ = self._axes(ctx)
        dt = (ctx.t_s[-1] - ctx.t_s[0]) / max(ctx.n - 1, 1)
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

    def from_fit(self, nl, coef, labels):
        # label lag_<axis>_minus_<ref>_ms -> that axis' difference, within the limits
        lim = self.limits["lag_*"]
        out = dict(nl)
        for lab, c in zip(labels, coef):
            h = float(np.clip(c, -lim, lim))
            axis = lab[len("lag_"):lab.index("_minus_")]
            out[f"{SECOND_ORDER}{axis}"] = round(h, 4) if abs(h) >= 1e-4 else 0.0
        return out

    def parameters(self, coef, labels, nl, ctx):
        out = {k: float(v) for k, v in nl.items() if not k.startswith(SECOND_ORDER)}
        out.update({lab: float(c) for lab, c in zip(labels, coef)})
        return out


#: rest at the start (s) before an axis' first move long enough to read the play's
#: unknown state there (shorter, its few samples are left to the residual)
START_REST_S = 0.2
#: least bar sensitivity to an axis (um per um) at the start for its play's state there
#: to be read (below it, a column of a few hundredths fits noise with an absurd size)
START_GAIN = 0.1


def _start_rest_s(ctx: Context, j: int) -> float:
    """How long (s) axis j stands at the start before it has moved 0.5 um."""
    moved = np.flatnonzero(np.abs(ctx.q[:, j] - ctx.q[0, j]) > 0.5e-3)
    return float(ctx.t_s[moved[0]] - ctx.t_s[0]) if moved.size else 0.0


class Backlash(Effect):
    name, title = "backlash", "lost motion: a step at each reversal of an axis (play operator)"
    reverse, feed_power = -1, 0.0
    limits = {"play_*": 80.0, "slack_at_start_*": 80.0}
    grid_um = (0.5, 1.0, 2.0, 3.0, 4.5, 6.5, 9.0, 13.0, 18.0, 25.0, 35.0, 50.0)

    def search(self, ctx, s, r):
        out = {}
        for j in linear_axes(ctx):
            if not len(ctx.reversal_times[j]):
                continue
            g = [projection_gain(self._col(ctx, s, j, b)[:, None], r) for b in self.grid_um]
            if max(g) <= NEGLIGIBLE * float(r @ r):
                # an axis the bar barely sees here (Z on a level bar): its play column,
                # fitted on noise, takes an absurd size and wrecks the held-out stretches
                continue
            b = float(self.grid_um[int(np.argmax(g))])
            for _ in range(3):  # the column's shape depends on the play: iterate to it
                c = self._col(ctx, s, j, b)
                den = float(c @ c)
                fitted = abs(float(c @ r) / den) if den > 0 else b
                if not 0.2 <= fitted <= 100.0 or abs(fitted - b) < 0.02 * b:
                    break
                b = fitted
            out[f"width_{ctx.axis_names[j]}_um"] = b
            if (_start_rest_s(ctx, j) >= START_REST_S
                    and abs(float(ctx.gain[0, j])) >= START_GAIN):
                out[f"slack_{ctx.axis_names[j]}_um"] = self._slack(ctx, s, j, b, r)
        return out or None

    def _slack(self, ctx, s, j, width_um, r) -> float:
        """How far (um, 0 to the play) the command moves axis j at the start before the
        axis follows, iterated like the play: the start column's shape depends on it."""
        sig = width_um / 2.0  # the middle of the play, with nothing known
        for _ in range(3):
            C = np.column_stack([self._col(ctx, s, j, width_um),
                                 self._start_col(ctx, s, j, sig)])
            coef = np.linalg.lstsq(C, r, rcond=None)[0]
            fitted = float(min(max(coef[1], 0.05), width_um))
            if abs(fitted - sig) < 0.02 * sig:
                break
            sig = fitted
        return sig

    def _start_col(self, ctx, s, j, slack_um):
        """Bar reading (um per um of slack) of where the play stood at the start, beyond
        the taken-up state :meth:`_col` assumes there: the axis stands until the command
        has moved ``slack_um`` from where it began, then follows."""
        i = s.idx
        sig = max(slack_um, 0.05) * 1e-3
        far = np.flatnonzero(np.abs(ctx.q[:, j] - ctx.q[0, j]) >= sig)
        end = int(far[0]) if far.size else ctx.n
        moved = np.abs(ctx.q[i, j] - ctx.q[0, j])
        ramp = np.where(i < end, 1.0 - moved / sig, 0.0)
        return ctx.gain[i, j] * ctx.direction[0, j] * ramp

    def _col(self, ctx, s, j, width_um):
        """Bar reading (um per um of play) of a play operator of ``width_um`` on axis j:
        after a reversal the axis stands until the command has moved the play."""
        i = s.idx
        x = ctx.q[i, j]
        d = ctx.direction[i, j]
        x_rev = ctx.position_at_reversal[i, j]
        b = width_um * 1e-3
        moved = np.abs(x - x_rev)
        dev = np.where(np.isfinite(x_rev) & (moved < b), x_rev - x + d * b / 2.0, -d * b / 2.0)
        return ctx.gain[i, j] * dev / b

    def columns(self, ctx, s, nl):
        axes = [j for j in linear_axes(ctx) if f"width_{ctx.axis_names[j]}_um" in nl]
        cols = [self._col(ctx, s, j, nl[f"width_{ctx.axis_names[j]}_um"]) for j in axes]
        labels = [f"play_{ctx.axis_names[j]}_um" for j in axes]
        # Where the play stood when the recording began is not known: the last move
        # before the program left it anywhere across its width.  :meth:`_col` takes it
        # up in the first direction; the slack left at the start (how far the command
        # moves before the axis follows) is a column of its own, read from the rest
        # before the first move.  (An independent generator starting in the middle of
        # the play left 3.9 um over the first 2 s, and a reversal spike was invented.)
        for j in axes:
            key = f"slack_{ctx.axis_names[j]}_um"
            if key in nl:
                cols.append(self._start_col(ctx, s, j, nl[key]))
                labels.append(f"slack_at_start_{ctx.axis_names[j]}_um")
        return np.column_stack(cols), tuple(labels)

    def parameters(self, coef, labels, nl, ctx):
        return {lab: float(c) for lab, c in zip(labels, coef)}

    def from_fit(self, nl, coef, labels):
        # the plays and slacks the columns are shaped with, as fitted with the others in
        # (a slack searched at 1.0 um fitted 4.6, and the start column's shape held the
        # timing 6 ms late); a play the fit puts outside the search's range keeps its own
        fitted = {lab: float(c) for lab, c in zip(labels, coef)}
        out = dict(nl)
        def axis(key, prefix):  # width_<axis>_um -> <axis>
            return key[len(prefix):-len("_um")]

        for key in nl:
            if key.startswith("width_"):
                c = abs(fitted.get(f"play_{axis(key, 'width_')}_um", 0.0))
                if 0.2 <= c <= 100.0:
                    out[key] = round(c, 4)
        for key in nl:
            if key.startswith("slack_"):
                a = axis(key, "slack_")
                top = out.get(f"width_{a}_um", nl[key])
                c = fitted.get(f"slack_at_start_{a}_um", nl[key])
                out[key] = round(float(min(max(c, 0.05), top)), 4)
        return out


class ReversalSpike(Effect):
    """A decaying pulse after an axis reversal: friction changes sign with the axis'
    velocity and the velocity loop takes a few ms to answer.  Where the pulse starts is
    a parameter too: at the sign change, or once the axis has reached a breakaway
    speed (``onset_mm_s``); on a slow reversal inside a curve (2 mm/s^2 through zero)
    0.05 mm/s comes 25 ms after the sign change, and a pulse put at the sign change
    then bent the timing by 40 ms."""

    name, title = "reversal_spike", "decaying pulse after an axis reversal (friction)"
    reverse, feed_power = -1, 0.0
    # the brief: tau 10-100 ms; the pulse rises over a few ms (friction breaking away
    # through the velocity loop), it does not jump
    limits = {"height_*": 50.0, "tau_ms": 100.0}
    grid_ms = (5.0, 8.0, 12.0, 18.0, 25.0, 35.0, 50.0, 70.0, 100.0)
    #: the rise (ms) is searched too: a velocity loop answers in 1-10 ms, and a rise
    #: held at 3 ms on a pulse that rose over 3.9 ms bent the timing 2.8 ms while the
    #: fit stayed at the noise (the pulses were the only timing in that trace)
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
    def _since(ctx, j, onset):
        """Time since axis j last reversed, a reversal counted once the axis moves
        faster than ``onset`` (mm/s) the other way, and the direction since then."""
        key = ("reversal_onset", j, onset)
        if key not in ctx._slow:
            d = directions(ctx.qdot[:, [j]], onset)[:, 0]
            _, last = reversals(d)
            since = np.where(last >= 0, ctx.t_s - ctx.t_s[np.maximum(last, 0)], np.inf)
            ctx._slow[key] = (since, d)
        return ctx._slow[key]

    def _cols(self, ctx, s, tau_ms, onset=onsets_mm_s[0], rise_ms=rise_ms):
        cols = []
        for j in linear_axes(ctx):
            since, d = self._since(ctx, j, onset)
            since = np.minimum(since[s.idx], 50.0)
            decay = (1.0 - np.exp(-since / (rise_ms * 1e-3))) * np.exp(-since / (tau_ms * 1e-3))
            cols.append(-ctx.gain[s.idx, j] * d[s.idx] * decay)
        return np.column_stack(cols)

    def _scorer(self, ctx, s, r, onset):
        """``score(tau_ms, rise_ms)``: :func:`projection_gain` of the pulses' columns, from
        the samples within a second of a reversal only (beyond it the longest pulse has
        decayed to e^-10) and the columns' 3 x 3 normal equations; None without them
        (or with :func:`fitted_beside`'s basis, which needs every sample)."""
        if _BESIDE.get() is not None:
            return lambda t, q: projection_gain(self._cols(ctx, s, t, onset, q), r)
        since, weight = [], []
        for j in linear_axes(ctx):
            sj, d = self._since(ctx, j, onset)
            since.append(sj[s.idx])
            weight.append(-ctx.gain[s.idx, j] * d[s.idx])
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
        best = None
        for onset in onsets:
            score = self._scorer(ctx, s, r, onset)
            tau = _grid_search(self.grid_ms, lambda t: score(t, self.rise_ms), np.geomspace)
            g = score(tau, self.rise_ms)
            if best is None or g > best[0]:
                best = (g, onset, tau, score)
        g, onset, tau, score = best
        rise = self.rise_ms
        for _ in range(2):
            rise = _grid_search(self.rise_grid_ms, lambda q: score(tau, q), np.geomspace)
            tau = _grid_search(self.grid_ms, lambda t: score(t, rise), np.geomspace)
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
            # (the brief): shorter, it was a stick-slip's edge read as a companion pulse;
            # longer (as a lag at the end of its grid), a slow ramp beside a play taken
            # up over a 5-axis program's slow reversals
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


class LateralPlay(Effect):
    name, title = "lateral_play", "a step across the reversing axis (guide play)"
    reverse, feed_power = -1, 0.0
    limits = {"play_*": 15.0}

    def columns(self, ctx, s, nl):
        cols, labels = [], []
        for j in linear_axes(ctx):
            if not len(ctx.reversal_times[j]):
                continue
            for k in linear_axes(ctx):
                if k != j:
                    cols.append(ctx.gain[s.idx, k] * ctx.direction[s.idx, j] / 2.0)
                    labels.append(f"play_{ctx.axis_names[k]}_on_{ctx.axis_names[j]}_reversal_um")
        return (np.column_stack(cols) if cols else np.zeros((len(s.idx), 0))), tuple(labels)


class CyclicError(Effect):
    name, title = "cyclic_error", "ripple locked to an axis position (scale / screw pitch)"
    limits = {"amplitude_um": 5.0}
    pitch_range_mm = (4.0, 25.0)

    def search(self, ctx, s, r):
        best = (0.0, None, None, None)
        n = len(s.idx)
        sub = np.sort(np.random.default_rng(1).choice(n, min(n, 8000), replace=False))
        for j in linear_axes(ctx):
            x = ctx.q[s.idx, j]
            span = float(np.ptp(x))
            if span < 2 * self.pitch_range_mm[0]:
                continue
            g = ctx.gain[s.idx, j]
            lo, hi = self.pitch_range_mm
            step = 1.0 / (8.0 * span)  # phase error <= pi/4 across the span
            inv = np.arange(1.0 / hi, 1.0 / lo, step)
            gains = _ripple_gains(x[sub], g[sub], r[sub], inv)
            k = int(np.argmax(gains))
            if gains[k] > best[0]:
                best = (float(gains[k]), j, float(inv[k]), step)
        if best[1] is None:
            return None
        # refine the best pitch on all samples
        j, step = best[1], best[3]
        x, g = ctx.q[s.idx, j], ctx.gain[s.idx, j]
        fine = np.linspace(best[2] - step, best[2] + step, 9)
        ph = 2 * np.pi * x[None, :] * fine[:, None]
        gf = _gain2(g * np.sin(ph), g * np.cos(ph), r)
        return {"axis": ctx.axis_names[j], "pitch_mm": float(1.0 / fine[int(np.argmax(gf))])}

    def columns(self, ctx, s, nl):
        j = ctx.axis_names.index(nl["axis"])
        ph = 2 * np.pi * ctx.q[s.idx, j] / nl["pitch_mm"]
        g = ctx.gain[s.idx, j]
        return np.column_stack([g * np.sin(ph), g * np.cos(ph)]), ("sin_um", "cos_um")

    def parameters(self, coef, labels, nl, ctx):
        return {"axis": nl["axis"], "pitch_mm": nl["pitch_mm"],
                "amplitude_um": float(np.hypot(*coef)),
                "phase_deg": float(np.degrees(np.arctan2(coef[1], coef[0])))}


def _mode_response(acc: np.ndarray, dt: float, f_hz: float, zeta: float) -> np.ndarray:
    """Deflection of a structural mode (natural frequency ``f_hz``, damping ratio
    ``zeta``, unit static compliance) driven by ``acc`` sampled every ``dt``: the exact
    discretisation of x'' + 2 zeta w x' + w^2 x = w^2 a for an acceleration held over each
    step (zero-order hold), so the frequency is not warped.  ``acc``: (n,) or (n, k),
    k signals filtered at once."""
    from scipy.signal import cont2discrete, lfilter, lfilter_zi

    w = 2 * np.pi * f_hz
    b, a, _ = cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), dt, method="zoh")
    b = np.ravel(b)
    # at rest in its static deflection under the first acceleration
    zi = lfilter_zi(b, a)
    zi = zi * acc[0] if acc.ndim == 1 else np.outer(zi, acc[0])
    y, _ = lfilter(b, a, acc, axis=0, zi=zi)
    return y


#: a mode's ringing is read when its best fit beyond the deflection gains this many
#: times the residual's variance (the most of about 150 frequency-damping trials on
#: noise reaches about 12)
RINGING_READ = 25.0


class Vibration(Effect):
    """A structural mode of a linear axis, rung by that axis' commanded acceleration: the
    axis deflects with it (static compliance, um per m/s^2) and rings at the mode's
    frequency after every change of acceleration, seen along the bar through the axis'
    gain.  Its static compliance cannot exceed what the whole axis mass on the mode's
    stiffness gives, 1 / (2 pi f)^2 (4 um per m/s^2 at 80 Hz); beyond twice that it is
    not a mode (a stiff, high mode with a large compliance is a servo lag's v^2 / R in
    disguise).  A steady ripple from outside the motion (a pump, the floor) is the other
    form: a sinusoid locked to time.  The search takes whichever explains more."""

    name, title = "vibration", "vibration: an axis' structural mode rung by its acceleration, or a steady ripple"
    limits = {"amplitude_*": 10.0, "peak_*": 10.0}
    band_hz = (8.0, 250.0)
    dampings = (0.02, 0.05, 0.12)

    def _acc(self, ctx, j):
        key = ("axis_acceleration", j)
        if key not in ctx._slow:
            ctx._slow[key] = np.gradient(ctx.qdot[:, j], ctx.t_s) * 1e-3  # m/s^2
        return ctx._slow[key]

    def _mode_columns(self, ctx, s, f_hz, zeta, sub=None, axes=None):
        tau = s.tau_s if sub is None else s.tau_s[sub]
        idx = s.idx if sub is None else s.idx[sub]
        dt = float(ctx.t_s[1] - ctx.t_s[0])
        axes = linear_axes(ctx) if axes is None else list(axes)
        # every axis filtered at once and read at the samples with one interpolation
        # (the grid is uniform): np.interp per axis took as long as the filter
        x = _mode_response(self._accs(ctx, axes), dt, f_hz, zeta)
        return ctx.gain[idx][:, axes] * sample_at(ctx.t_s, x, tau)

    def _accs(self, ctx, axes):
        key = ("axis_accelerations", tuple(axes))
        if key not in ctx._slow:
            ctx._slow[key] = np.column_stack([self._acc(ctx, j) for j in axes])
        return ctx._slow[key]

    def _ringing_samples(self, ctx, s, quota):
        """Indices into ``s`` where a mode can ring (from where any axis accelerates
        until a quarter second after), at most ``quota`` (a seeded choice): on a program
        that accelerates only where it starts and stops, a random choice over the whole
        trace kept a handful of samples of each ring and the search lost a 2 um mode."""
        if "ringing" not in ctx._slow:  # the same for every search on this program
            dt = float(ctx.t_s[1] - ctx.t_s[0])
            acc = np.abs(np.column_stack([self._acc(ctx, j) for j in linear_axes(ctx)]))
            on = (acc > 0.01 * np.maximum(acc.max(axis=0), 1e-12)).any(axis=1)
            k = max(1, int(round(0.25 / dt)))
            ctx._slow["ringing"] = np.convolve(on.astype(float), np.ones(k), mode="full")[:ctx.n] > 0
        cand = np.flatnonzero(ctx._slow["ringing"][s.idx])
        if len(cand) < min(quota, 5000):  # hardly any acceleration: the whole trace
            cand = np.arange(len(s.idx))
        rng = np.random.default_rng(3)
        return cand if len(cand) <= quota else np.sort(rng.choice(cand, quota, replace=False))

    def _mode_search(self, ctx, s, r):
        """Frequency and damping on a grid (log-spaced frequencies over the band, three
        dampings), refined on finer grids around the best.  The ringing is read at the
        aligned timing: an alignment a few ms off (weak timing) loses a mode of tens of
        Hz, which the report's timing warning covers."""
        if ctx.n < 10 or not linear_axes(ctx) or len(r) < 1000:
            return None
        sub = self._ringing_samples(ctx, s, 40000)
        rs = r[sub]

        # a candidate is judged by its ringing: the deflection that follows the acceleration
        # and that deflection's timing derivative are in every candidate's fit (they read
        # as a lag would, and as an alignment a few ms off)
        dt = float(ctx.t_s[1] - ctx.t_s[0])
        idx, tau = s.idx[sub], s.tau_s[sub]
        base = []
        for j in linear_axes(ctx):
            a = self._acc(ctx, j)
            base += [ctx.gain[idx, j] * np.interp(tau, ctx.t_s, a),
                     ctx.gain[idx, j] * np.interp(tau, ctx.t_s, np.gradient(a, dt)) * 1e-2]
        base = np.column_stack(base)

        q, _ = np.linalg.qr(base)
        rp = rs - q @ (q.T @ rs)
        bound = lambda f: 2.0e6 / (2 * np.pi * f) ** 2  # noqa: E731  (see implausible)

        axes = linear_axes(ctx)

        def judge(G, b, f):
            # what the mode of each axis adds beyond the base (Frisch-Waugh: its
            # coefficient in the joint fit is that of the fit of the base's residual on
            # its own residual): the gain per axis
            g = np.diag(G)
            coef = b / np.maximum(g, 1e-300)
            return np.where((g > 0) & (np.abs(coef) <= bound(f)), coef * b, 0.0)

        def gain(f, z, k):
            C = self._mode_columns(ctx, s, f, z, sub, [axes[k]])
            C = C - q @ (q.T @ C)
            return float(judge(C.T @ C, C.T @ rp, f)[0])

        # the coarse grid's columns beyond the base on this sample set depend on the
        # samples only: kept with the context (every selection step and exchange
        # searches the same samples again), all judged with one product
        freqs = np.geomspace(*self.band_hz, 48)
        key = ("mode_grid", len(tau), float(tau[0]), float(tau[-1]), float(tau.sum()))
        if key not in ctx._slow:
            k_ax = len(linear_axes(ctx))
            P = np.empty((len(sub), len(freqs) * len(self.dampings) * k_ax))
            grams = []
            for f in freqs:
                for z in self.dampings:
                    C = self._mode_columns(ctx, s, f, z, sub)
                    C = C - q @ (q.T @ C)
                    P[:, len(grams) * k_ax:(len(grams) + 1) * k_ax] = C
                    grams.append(C.T @ C)
            ctx._slow[key] = (P, grams)
        P, grams = ctx._slow[key]
        B = (P.T @ rp).reshape(len(grams), -1)
        pairs = [(f, z) for f in freqs for z in self.dampings]
        # a structural mode belongs to one axis: the axes start and stop together on the
        # sphere, so a mode fitted to every axis at once spread one axis' compliance over
        # all three (8, 5 and 5 um per m/s^2 for a mode of X of 3.7) and was refused
        ring = np.array([judge(G, b, f) for (f, _), G, b in zip(pairs, grams, B)])
        # The axis is the one whose mode explains most: its ringing and its deflection
        # that follows the acceleration (the base's column).  On a program whose
        # accelerations ramp slower than the mode rings, the deflection is nearly all of
        # it (a 0.85 um per m/s^2 mode at 79 Hz: 366 in chi-square, the ringing noise),
        # and the axis chosen by its ringing alone was one without a mode.
        static = np.array([projection_gain(base[:, 2 * n][:, None], rs) for n in range(len(axes))])
        k = int(np.argmax(static + ring.max(axis=0)))
        if ring[:, k].max() < RINGING_READ * float(rp @ rp) / len(rp):
            # its ringing is below the noise: the mode's frequency and damping are not
            # read.  The deflection is a mode's well below its frequency, at any
            # frequency the axis' mass allows for the compliance found
            c = abs(float(base[:, 2 * k] @ rs) / max(float(base[:, 2 * k] @ base[:, 2 * k]), 1e-300))
            f = self.band_hz[1] if c <= 0 else min(self.band_hz[1],
                                                   0.8 * np.sqrt(2.0e6 / c) / (2 * np.pi))
            return {"frequency_hz": float(f), "damping": 0.05, "axis": ctx.axis_names[axes[k]],
                    "ringing": False}
        i = int(np.argmax(ring[:, k]))
        f, z = pairs[i]
        best = (float(ring[i, k]), f, z)
        step = freqs[1] / freqs[0]
        for _ in range(2):  # refine: frequency, then damping, on finer grids
            best = max([best] + [(gain(f * step ** e, z, k), f * step ** e, z)
                                 for e in np.linspace(-0.6, 0.6, 7)
                                 if self.band_hz[0] <= f * step ** e <= self.band_hz[1]])
            _, f, z = best
            best = max([best] + [(gain(f, z * m, k), f, z * m) for m in (0.6, 0.8, 1.25, 1.6)
                                 if 0.005 <= z * m <= 0.3])
            _, f, z = best
            step = step ** 0.25
        return {"frequency_hz": float(f), "damping": float(z), "axis": ctx.axis_names[axes[k]]}

    def _steady_search(self, ctx, s, r):
        if len(s.tau_s) < 1000:
            return None
        order = np.argsort(s.tau_s)
        t = s.tau_s[order]
        rate = 1000.0
        n = int((t[-1] - t[0]) * rate) + 1
        k = np.clip(np.round((t - t[0]) * rate).astype(int), 0, n - 1)
        nfft = 1 << int(np.ceil(np.log2(n)))
        freqs = np.fft.rfftfreq(nfft, 1.0 / rate)
        band = (freqs >= self.band_hz[0]) & (freqs <= self.band_hz[1])
        if not band.any():
            return None
        win = np.hanning(n)
        sub = np.sort(np.random.default_rng(2).choice(len(r), min(len(r), 60000), replace=False))
        best = (0.0, None)
        for j in linear_axes(ctx):
            g = ctx.gain[s.idx, j]
            grid = np.zeros(n)
            grid[k] = (r * g)[order]
            spec = np.abs(np.fft.rfft(grid * win, nfft))
            i = int(np.flatnonzero(band)[np.argmax(spec[band])])
            df = rate / nfft
            cand = i * df + np.linspace(-1.5 * df, 1.5 * df, 31)
            ph = 2 * np.pi * cand[:, None] * s.tau_s[None, sub]
            gains = _gain2(g[sub] * np.sin(ph), g[sub] * np.cos(ph), r[sub])
            m = int(np.argmax(gains))
            if gains[m] > best[0]:
                best = (float(gains[m]), float(cand[m]))
        if best[1] is None:
            return None
        return {"frequency_hz": best[1], "steady": True}

    def search(self, ctx, s, r):
        """Both forms, each fitted to the residual; the one that explains more (its
        gain per sample, the steady form judged with a full fit over every axis)."""
        nl_mode = self._mode_search(ctx, s, r)
        nl_steady = self._steady_search(ctx, s, r)
        g_mode = g_steady = 0.0
        for nl in (nl_mode, nl_steady):
            if nl is None:
                continue
            C, _ = self.columns(ctx, s, nl)
            coef, *_ = np.linalg.lstsq(C, r, rcond=1e-8)
            fit = C @ coef
            g = float(r @ r - (r - fit) @ (r - fit))
            if nl is nl_mode:
                g_mode = g
            else:
                g_steady = g
        if nl_mode is None and nl_steady is None:
            return None
        return nl_mode if nl_steady is None or (nl_mode is not None and g_mode >= g_steady) \
            else nl_steady

    def columns(self, ctx, s, nl):
        if not nl.get("steady"):
            axes = self._axes(ctx, nl)
            labels = tuple(f"compliance_{ctx.axis_names[j]}_um_per_m_s2" for j in axes)
            return self._mode_columns(ctx, s, nl["frequency_hz"], nl["damping"], None, axes), labels
        ph = 2 * np.pi * nl["frequency_hz"] * s.tau_s
        sn, cs = np.sin(ph), np.cos(ph)
        cols, labels = [], []
        for j in linear_axes(ctx):
            g = ctx.gain[s.idx, j]
            cols += [g * sn, g * cs]
            labels += [f"{ctx.axis_names[j]}_sin_um", f"{ctx.axis_names[j]}_cos_um"]
        return np.column_stack(cols), tuple(labels)

    @staticmethod
    def _axes(ctx, nl):
        """The mode's axis (every linear axis for a mode found without one)."""
        return [j for j in linear_axes(ctx) if "axis" not in nl or ctx.axis_names[j] == nl["axis"]]

    def implausible(self, params):
        why = super().implausible(params)
        if why or params.get("form") != "structural mode":
            return why
        bound = 2.0e6 / (2 * np.pi * params["frequency_hz"]) ** 2  # um per m/s^2
        for key, value in params.items():
            if key.startswith("compliance_") and abs(value) > bound:
                return (f"{key} = {value:.4g} exceeds {bound:.3g}, twice the whole axis mass "
                        f"on a mode at {params['frequency_hz']:.0f} Hz")
        return None

    def parameters(self, coef, labels, nl, ctx):
        out = {"frequency_hz": nl["frequency_hz"]}
        if not nl.get("steady"):
            if nl.get("ringing", True):
                out["form"] = "structural mode"
                out["damping"] = nl["damping"]
            else:  # frequency and damping not read: not printed as numbers
                out = {"form": "structural mode, its ringing below the noise: the "
                               "deflection with the acceleration read, not the frequency"}
            for c, j in zip(coef, self._axes(ctx, nl)):
                name = ctx.axis_names[j]
                out[f"compliance_{name}_um_per_m_s2"] = float(c)
                # the largest deflection it brings on this program
                x = _mode_response(self._acc(ctx, j), float(ctx.t_s[1] - ctx.t_s[0]),
                                   nl["frequency_hz"], nl["damping"])
                out[f"peak_{name}_um"] = float(abs(c) * np.max(np.abs(x)))
            return out
        out["form"] = "steady ripple"
        for n, j in enumerate(linear_axes(ctx)):
            out[f"amplitude_{ctx.axis_names[j]}_um"] = float(np.hypot(coef[2 * n], coef[2 * n + 1]))
        return out


class StickSlip(Effect):
    """An axis that crawls (slower than ~200 mm/min, near its reversals) sticks: its
    command runs on and the lag grows with the commanded travel until the spring force
    of the drive breaks the friction; it then slips forward, often past the command.
    The slip comes after a fixed travel (the stick distance: friction step over drive
    stiffness), not after a fixed time: a saw-tooth in the travel since the crawl
    began, its period in time growing as the axis slows.  Per axis: the mean lag while
    crawling (against the direction of motion) and the saw-tooth about it."""

    name, title = "stick_slip", "saw-tooth while an axis crawls near a reversal"
    limits = {"amplitude_*": 8.0, "mean_lag_*": 8.0}
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
        return {"stick_um": _grid_search(
            self.grid_um, lambda p: projection_gain(self._cols(ctx, s, p), r), np.geomspace)}

    def columns(self, ctx, s, nl):
        return self._cols(ctx, s, nl["stick_um"]), tuple(
            f"{kind}_{ctx.axis_names[j]}_um" for j in linear_axes(ctx)
            for kind in ("mean_lag", "amplitude"))

    def unsure_in_time(self, ctx, params):
        """The crawls of the axes that stick.  Within them the saw-tooth's phase is the
        friction's, not the program's (sampled, a tooth of 3.5 um at 3 mm/s is shorter
        than a sample), and what the columns leave of it is not noise: fitted with the
        crawls, the start came 3.3 ms late against a stated 0.8 ms (blind case SDIT_B 40),
        without them 0.7 ms."""
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


class _ModelColumns(Effect):
    """Columns from the geometric error model's first-order sensitivities."""

    wanted: tuple[str, ...] = ()

    order = 1

    def __init__(self, machine, travel):
        self._kin = Kinematics(machine)
        self._model = build_model(machine, travel, ModelOptions(linear_order=self.order,
                                                                squareness=True, location=False))
        self._names = [n for n in self._wanted() if n in self._model.names]
        self._travel = {a: (lo, hi) for a, lo, hi in self._model.travel}

    def _wanted(self):
        return self.wanted

    def columns(self, ctx, s, nl):
        if not self._names:
            return np.zeros((len(s.idx), 0)), ()
        from ..errormodel.model import ErrorModel

        # the same samples come back for every candidate of a pass: the sensitivities at
        # the nominal poses are kept with the context (a few per kind)
        kept = ctx._slow.setdefault(("pose columns", type(self).__name__), {})
        key = hashlib.blake2b(np.ascontiguousarray(s.idx).tobytes(), digest_size=16).digest()
        if key not in kept:
            sub = ErrorModel(self._model.axes, self._model.rotary,
                             tuple(self._model.parameters[self._model.index(n)]
                                   for n in self._names),
                             self._model.travel, self._model.options)
            if len(kept) >= 4:
                kept.pop(next(iter(kept)))
            kept[key] = sensitivities(self._kin, sub, ctx.q[s.idx], ctx.pivot_mm)
        return kept[key].copy(), tuple(self._names)


class Squareness(_ModelColumns):
    name, title = "squareness", "out-of-squareness of the linear axes (shear)"
    limits = {"*_urad": 200.0}  # the brief: 50-100 um/m on a bad machine
    wanted = ("EC0Y", "EB0Z", "EA0Z")

    def parameters(self, coef, labels, nl, ctx):
        return {f"{n}_urad": float(c) for n, c in zip(labels, coef)}


class ScaleMismatch(_ModelColumns):
    name, title = "scale_mismatch", "linear positioning (scale) error per axis"
    limits = {"*_um_per_m": 100.0}  # the brief: 30-60 um/m on a bad machine
    wanted = ("EXX.P1", "EYY.P1", "EZZ.P1")

    def parameters(self, coef, labels, nl, ctx):
        out = {}
        for n, c in zip(labels, coef):
            axis = n[2]
            lo, hi = self._travel.get(axis, (0.0, 1.0))
            out[f"{axis}_um_per_m"] = float(c / max((hi - lo) / 2.0, 1e-9) * 1e3)
        return out


class GeometryBeyond(_ModelColumns):
    """Not an effect to name: smooth position-locked geometry the library lacks
    (straightness and angular errors of the linear axes, Legendre degree 2-3), used to
    tell whether geometric findings are only standing in for it."""

    name, title = "geometry_beyond_library", "straightness / angular errors (Legendre 2-3)"
    order = 3

    def _wanted(self):
        return [p.name for p in self._model.parameters
                if p.kind == "component" and p.axis not in self._model.rotary
                and p.basis in ("P2", "P3")]


#: findings that a more general geometric error could be standing in for
GEOMETRIC = ("setup_offset", "bar_length", "squareness", "scale_mismatch", "cyclic_error",
             "thermal_drift")


class ContourSmoothing(Effect):
    """The control rounds the path, in one of two ways.  A path-tolerance smoothing
    (G642, COMPCAD) averages the path in space within each run and stops exactly at the
    nodes (``window_mm``).  A set-point filter (an axial jerk filter, a cascade of moving
    averages: about a Gaussian) acts in time on every axis and passes through the stops
    - the axes leave a node early and reach it late, symmetric about the stop
    (``sigma_ms``); its delay, if the control does not compensate it, is the start's.
    Both are searched; the one whose column takes more of the residual is kept."""

    name, title = "contour_smoothing", "the control shortcuts the path (spatial low-pass)"
    reverse, feed_power = 1, 2.0
    limits = {"shortcut_um": 40.0}
    grid_mm = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0)
    sigma_grid_ms = (2.0, 3.0, 5.0, 8.0, 12.0, 18.0, 25.0, 35.0, 50.0)

    def __init__(self):
        self._cache: dict = {}

    def shortcut_um(self, ctx: Context, idx: np.ndarray, window_mm: float) -> np.ndarray:
        """Radial deviation (um) at samples ``idx`` of the path averaged over
        ``window_mm`` of arc length within its run (zero while standing)."""
        return smoothed_radial_um(ctx, idx, window_mm)

    def filtered_um(self, ctx: Context, idx: np.ndarray, sigma_ms: float) -> np.ndarray:
        """Radial deviation (um) at samples ``idx`` of the ball path filtered in time by
        a zero-phase Gaussian of ``sigma_ms``, through the stops."""
        return _memo(self._cache, ctx, sigma_ms, lambda: time_filtered_radial_um(
            ctx, sigma_ms * 1e-3).astype(np.float32))[idx].astype(float)

    def search(self, ctx, s, r):
        space = lambda w: projection_gain(self.shortcut_um(ctx, s.idx, w)[:, None], r)  # noqa: E731
        time = lambda q: projection_gain(self.filtered_um(ctx, s.idx, q)[:, None], r)  # noqa: E731
        w = _grid_search(self.grid_mm, space, np.linspace)
        q = _grid_search(self.sigma_grid_ms, time, np.geomspace)
        return {"window_mm": w} if space(w) >= time(q) else {"sigma_ms": q}

    def columns(self, ctx, s, nl):
        if "sigma_ms" in nl:
            return self.filtered_um(ctx, s.idx, nl["sigma_ms"])[:, None], ("scale",)
        return self.shortcut_um(ctx, s.idx, nl["window_mm"])[:, None], ("scale",)

    def physical(self, coef):
        return coef[0] > 0

    def parameters(self, coef, labels, nl, ctx):
        c = float(np.sqrt(max(coef[0], 0.0)))
        radius = float(np.median(ctx.length_mm))
        if "sigma_ms" in nl:
            # the shortcut grows as (v sigma)^2 / (2 R): at the layer's typical feed
            sigma = nl["sigma_ms"] * c
            moving = ctx.speed_mm_per_s[ctx.moving]
            v = float(np.median(moving)) if moving.size else 0.0
            return {"sigma_ms": sigma,
                    "shortcut_um": float((v * sigma * 1e-3) ** 2 / (2.0 * radius) * 1e3)}
        w = nl["window_mm"] * c
        return {"window_mm": w, "shortcut_um": float(w * w / (24.0 * radius) * 1e3)}


def time_filtered_radial_um(ctx: Context, sigma_s: float) -> np.ndarray:
    """The ball path in the table frame filtered by a zero-phase Gaussian of ``sigma_s``
    in time (the ends held), as radial deviation in um on the whole trajectory grid."""
    from scipy.ndimage import gaussian_filter1d

    dt = float(np.median(np.diff(ctx.t_s)))
    p0 = ctx.ball_mm[0]
    smooth = gaussian_filter1d(ctx.ball_mm - p0, sigma_s / dt, axis=0, mode="nearest",
                               truncate=6.0) + p0
    return (np.linalg.norm(smooth - ctx.pivot_mm, axis=1) - ctx.length_mm) * 1e3


def smoothed_radial_um(ctx: Context, idx: np.ndarray, window_mm: float) -> np.ndarray:
    s = ctx.arc_mm[idx]
    lo = np.maximum(s - window_mm / 2.0, ctx.run_start_mm[idx])
    hi = np.minimum(s + window_mm / 2.0, ctx.run_end_mm[idx])
    width = np.maximum(hi - lo, 1e-12)
    avg = np.column_stack([(np.interp(hi, ctx.arc_mm, ctx.arc_integral[:, k])
                            - np.interp(lo, ctx.arc_mm, ctx.arc_integral[:, k])) / width
                           for k in range(3)])
    out = (np.linalg.norm(avg - ctx.pivot_mm, axis=1) - ctx.length_mm[idx]) * 1e3
    return np.where(ctx.moving[idx] & (hi - lo > 1e-9), out, 0.0)


def library(machine, travel) -> list[Effect]:
    return [SetupOffset(), BarLength(), ThermalDrift(), ServoLag(), ServoMismatch(), Backlash(),
            ReversalSpike(), LateralPlay(), CyclicError(), Vibration(), StickSlip(),
            Squareness(machine, travel), ScaleMismatch(machine, travel), ContourSmoothing()]


#: how common each effect is on a healthy machining centre, most common first: the
#: order that decides between effects the data cannot tell apart (equal evidence)
PRIOR_ORDER = ("setup_offset", "bar_length", "servo_lag", "thermal_drift", "backlash",
               "reversal_spike", "servo_mismatch", "squareness", "scale_mismatch",
               "cyclic_error", "vibration", "lateral_play", "stick_slip", "contour_smoothing")

EFFECT_NAMES = ("setup_offset", "bar_length", "thermal_drift", "servo_lag", "servo_mismatch",
                "backlash", "reversal_spike", "lateral_play", "cyclic_error", "vibration",
                "stick_slip", "squareness", "scale_mismatch", "contour_smoothing")
