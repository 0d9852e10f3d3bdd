"""Vibration: a structural mode rung by the accelerations, or a steady ripple."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from ...reading.context import sample_at, sample_made
from ...reading.rows import BLOCK_ROWS
from .base import Effect, filtered_blocks, gain2, linear_axes, projection_gain


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


def _mode_response_rows(acc: np.ndarray, dt: float, f_hz: float, zeta: float,
                        rows: np.ndarray, block: int = BLOCK_ROWS) -> np.ndarray:
    """The rows ``rows`` (increasing) of ``_mode_response(acc, ...)`` for ``acc : (n,
    k)``, filtered a block of samples at a time with the filter's state carried from
    block to block (the same numbers; the response on every sample of an hour is 80 MB,
    and the filter's copies as much again)."""
    from scipy.signal import cont2discrete, lfilter_zi

    w = 2 * np.pi * f_hz
    b, a, _ = cont2discrete(([w * w], [1.0, 2 * zeta * w, w * w]), dt, method="zoh")
    b = np.ravel(b)
    out = np.empty((len(rows), acc.shape[1]))
    for start, stop, y in filtered_blocks(b, a, len(acc), lambda i, j: acc[i:j],
                                          np.outer(lfilter_zi(b, a), acc[0]), block):
        lo, hi = np.searchsorted(rows, (start, stop))
        out[lo:hi] = y[rows[lo:hi] - start]
    return out


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
    commonness, time_locked = 10, True
    limits = MappingProxyType({"amplitude_*": 10.0, "peak_*": 10.0})
    band_hz = (8.0, 250.0)
    dampings = (0.02, 0.05, 0.12)

    def _acc(self, ctx, j):
        key = ("axis_acceleration", j)
        if key not in ctx.cache:
            ctx.cache[key] = np.gradient(ctx.qdot[:, j], ctx.t_s) * 1e-3  # m/s^2
        return ctx.cache[key]

    def _mode_columns(self, ctx, s, f_hz, zeta, sub=None, axes=None):
        tau = s.tau_s if sub is None else s.tau_s[sub]
        idx = s.idx if sub is None else s.idx[sub]
        dt = float(ctx.t_s[1] - ctx.t_s[0])
        axes = linear_axes(ctx) if axes is None else list(axes)
        # every axis filtered at once and read at the samples with one interpolation
        # (the grid is uniform): np.interp per axis takes as long as the filter
        acc = self._accs(ctx, axes)
        if ctx.tall:  # (the response made at the rows read)
            return ctx.gain[idx][:, axes] * sample_made(
                ctx.t_s, tau, lambda rows: _mode_response_rows(acc, dt, f_hz, zeta, rows))
        x = _mode_response(acc, dt, f_hz, zeta)
        return ctx.gain[idx][:, axes] * sample_at(ctx.t_s, x, tau)

    def _accs(self, ctx, axes):
        key = ("axis_accelerations", tuple(axes))
        if key not in ctx.cache:
            ctx.cache[key] = np.column_stack([self._acc(ctx, j) for j in axes])
        return ctx.cache[key]

    def _ringing_samples(self, ctx, s, quota):
        """Indices into ``s`` where a mode can ring (from where any axis accelerates
        until a quarter second after), at most ``quota`` (a seeded choice): on a program
        that accelerates only where it starts and stops, a random choice over the whole
        trace keeps a handful of samples of each ring, and the search loses a mode of
        microns."""
        if "ringing" not in ctx.cache:  # the same for every search on this program
            dt = float(ctx.t_s[1] - ctx.t_s[0])
            acc = np.abs(np.column_stack([self._acc(ctx, j) for j in linear_axes(ctx)]))
            on = (acc > 0.01 * np.maximum(acc.max(axis=0), 1e-12)).any(axis=1)
            k = max(1, int(round(0.25 / dt)))
            ctx.cache["ringing"] = np.convolve(on.astype(float), np.ones(k), mode="full")[:ctx.n] > 0
        cand = np.flatnonzero(ctx.cache["ringing"][s.idx])
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
        if key not in ctx.cache:
            k_ax = len(linear_axes(ctx))
            P = np.empty((len(sub), len(freqs) * len(self.dampings) * k_ax))
            grams = []
            for f in freqs:
                for z in self.dampings:
                    C = self._mode_columns(ctx, s, f, z, sub)
                    C = C - q @ (q.T @ C)
                    P[:, len(grams) * k_ax:(len(grams) + 1) * k_ax] = C
                    grams.append(C.T @ C)
            ctx.cache[key] = (P, grams)
        P, grams = ctx.cache[key]
        B = (P.T @ rp).reshape(len(grams), -1)
        pairs = [(f, z) for f in freqs for z in self.dampings]
        # a structural mode belongs to one axis: the axes start and stop together on the
        # sphere, so a mode fitted to every axis at once spreads one axis' compliance
        # over all three, each larger than the mode's, and is refused as implausible
        ring = np.array([judge(G, b, f) for (f, _), G, b in zip(pairs, grams, B)])
        # The axis is the one whose mode explains most: its ringing and its deflection
        # that follows the acceleration (the base's column).  On a program whose
        # accelerations ramp slower than the mode rings, the deflection is nearly all of
        # it and its ringing is at the noise, and the axis chosen by its ringing alone
        # is one without a mode (hard case: blind-typical-SDIT_C-s1-10).
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
            grid *= win  # (in place: an hour's grid is 27 MB)
            spec = np.abs(np.fft.rfft(grid, nfft))
            i = int(np.flatnonzero(band)[np.argmax(spec[band])])
            df = rate / nfft
            cand = i * df + np.linspace(-1.5 * df, 1.5 * df, 31)
            ph = 2 * np.pi * cand[:, None] * s.tau_s[None, sub]
            gains = gain2(g[sub] * np.sin(ph), g[sub] * np.cos(ph), r[sub])
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

    def locked_to_program(self, nonlinear):
        return not nonlinear.get("steady")  # a steady ripple is locked to time

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
