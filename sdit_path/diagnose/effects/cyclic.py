"""A ripple locked to an axis position: a scale's or a screw's cyclic error."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from .base import Effect, gain2, ripple_gains, linear_axes


class CyclicError(Effect):
    name, title = "cyclic_error", "ripple locked to an axis position (scale / screw pitch)"
    headline = 3
    commonness, geometric = 9, True
    limits = MappingProxyType({"amplitude_um": 5.0})
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
            gains = ripple_gains(x[sub], g[sub], r[sub], inv)
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
        gf = gain2(g * np.sin(ph), g * np.cos(ph), r)
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
