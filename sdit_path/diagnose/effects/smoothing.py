"""The control rounds the path: a path-tolerance smoothing or a set-point filter."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from ...reading.context import Context
from ...reading.rows import blocks
from .base import Effect, grid_search, memo, projection_gain


class ContourSmoothing(Effect):
    """The control rounds the path, in one of two ways.  A path-tolerance smoothing
    (G642, COMPCAD) averages the path in space within each run and stops exactly at the
    nodes (``window_mm``).  A set-point filter (an axial jerk filter, a cascade of moving
    averages: about a Gaussian) acts in time on every axis and passes through the stops
    - the axes leave a node early and reach it late, symmetric about the stop
    (``sigma_ms``); its delay, if the control does not compensate it, is the start's.
    Both are searched; the one whose column takes more of the residual is kept."""

    name, title = "contour_smoothing", "the control shortcuts the path (spatial low-pass)"
    commonness, time_locked = 13, True
    reverse, feed_power = 1, 2.0
    limits = MappingProxyType({"shortcut_um": 40.0})
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
        return memo(self._cache, ctx, sigma_ms, lambda: time_filtered_radial_um(
            ctx, sigma_ms * 1e-3).astype(np.float32))[idx].astype(float)

    def search(self, ctx, s, r):
        space = lambda w: projection_gain(self.shortcut_um(ctx, s.idx, w)[:, None], r)  # noqa: E731
        time = lambda q: projection_gain(self.filtered_um(ctx, s.idx, q)[:, None], r)  # noqa: E731
        w = grid_search(self.grid_mm, space, np.linspace)
        q = grid_search(self.sigma_grid_ms, time, np.geomspace)
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
    if ctx.tall:
        # a block of samples at a time, each with the filter's reach on either side (so
        # every output sample sums the same inputs as the whole: the same numbers)
        reach = int(6.0 * sigma_s / dt + 0.5) + 1
        out = np.empty(ctx.n)
        for a, b in blocks(ctx.n):
            lo, hi = max(a - reach, 0), min(b + reach, ctx.n)
            smooth = gaussian_filter1d(ctx.ball_mm[lo:hi] - p0, sigma_s / dt, axis=0,
                                       mode="nearest", truncate=6.0)[a - lo:b - lo] + p0
            out[a:b] = (np.linalg.norm(smooth - ctx.pivot_mm, axis=1) - ctx.length_mm[a:b]) * 1e3
        return out
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
