"""Feed-profile preview pictures (PNG bytes; no file IO here).

Per layer:
- ``speed``: path speed over time with the programmed feed, dwells shaded and labelled
  with their node, and the segment being run along the top;
- ``axes``: per machine axis the velocity, acceleration and jerk (finite differences of
  the sampled trajectory, exactly what the CSV says) with their limit lines and the
  dwells shaded;
- ``hemisphere``: the sphere with its tracks and static nodes, this layer's path
  coloured by path speed and the other layers' paths in grey.
"""

from __future__ import annotations

import io
import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: E402

from ..plan.preview import Preview  # noqa: E402
from ..timing.trajectory import Samples  # noqa: E402

_PNG = {"Software": None}


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, metadata=_PNG)
    plt.close(fig)
    return buf.getvalue()


def _envelope(t: np.ndarray, y: np.ndarray, bins: int = 2500) -> tuple[np.ndarray, np.ndarray]:
    """Min/max per time bin, so peaks survive decimation."""
    if len(t) <= 2 * bins:
        return t, y
    edges = np.linspace(0, len(t), bins + 1).astype(int)
    tt, yy = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        seg = y[a:b]
        i, j = int(np.argmin(seg)), int(np.argmax(seg))
        for k in sorted((i, j)):
            tt.append(t[a + k])
            yy.append(seg[k])
    return np.array(tt), np.array(yy)


def _dwell_spans(s: Samples) -> list[tuple[float, float, str]]:
    dwell = s.phase == "dwell"
    spans = []
    i = 0
    n = len(dwell)
    while i < n:
        if dwell[i]:
            j = i
            while j + 1 < n and dwell[j + 1] and s.segment[j + 1] == s.segment[i]:
                j += 1
            spans.append((s.t_s[i], s.t_s[j], str(s.segment[i])))
            i = j + 1
        else:
            i += 1
    return spans


def speed_figure(s: Samples, title: str, feed_mm_per_min: float) -> bytes:
    fig, ax = plt.subplots(figsize=(12, 4.2))
    t, v = _envelope(s.t_s, s.speed_mm_per_s)
    ax.plot(t, v, lw=0.8, color="tab:blue", label="path speed")
    ax.axhline(feed_mm_per_min / 60.0, color="tab:red", ls="--", lw=0.8,
               label=f"programmed feed F{feed_mm_per_min:g}")
    top = feed_mm_per_min / 60.0 * 1.15
    for a, b, node in _dwell_spans(s):
        ax.axvspan(a, b, color="0.85", lw=0)
        ax.text((a + b) / 2, top * 0.98, node, rotation=90, ha="center", va="top", fontsize=6,
                color="0.35")
    # segment names along the top, once per segment
    moving = s.phase != "dwell"
    seg = s.segment
    starts = np.flatnonzero(moving & np.concatenate([[True], seg[1:] != seg[:-1]]))
    for k in starts:
        if str(seg[k]).count("-") == 1 and ">" not in str(seg[k]) and str(seg[k]) != "remount":
            ax.text(s.t_s[k], top * 0.02, str(seg[k]), rotation=90, fontsize=5, color="tab:blue",
                    va="bottom")
    ax.set_ylim(0, top)
    ax.set_xlim(0, s.t_s[-1])
    ax.set_xlabel("time from program start (s)")
    ax.set_ylabel("path speed (mm/s)")
    ax.set_title(title + ": path speed (grey: dwells at static nodes)")
    # below the axes: inside, it would hide the last dwells' names
    ax.legend(loc="upper right", bbox_to_anchor=(1.0, -0.12), fontsize=8, ncol=2,
              frameon=False)
    fig.tight_layout()
    return _png(fig)


def axes_figure(s: Samples, title: str, limits: dict[str, tuple[float, float, float]],
                note: str = "") -> bytes:
    """``limits``: axis -> (velocity, acceleration, jerk) in the CSV's units per s^k;
    ``note``: a line under the pictures (what the limit lines mean for this timing)."""
    names = s.axis_names
    fig, grid = plt.subplots(len(names), 3, figsize=(14, 2.1 * len(names) + 0.8), sharex=True,
                             squeeze=False)
    dt = np.diff(s.t_s).mean() if len(s.t_s) > 1 else 1e-3
    spans = _dwell_spans(s)
    for r, (name, unit) in enumerate(zip(names, s.axis_units)):
        x = s.axes[:, r]
        v = np.diff(x) / dt
        a = np.diff(v) / dt
        j = np.diff(a) / dt
        for c, (label, y, lim) in enumerate((("velocity", v, limits[name][0]),
                                             ("acceleration", a, limits[name][1]),
                                             ("jerk", j, limits[name][2]))):
            ax = grid[r][c]
            for a0, b0, _ in spans:
                ax.axvspan(a0, b0, color="0.9", lw=0)
            t, yy = _envelope(s.t_s[: len(y)], y)
            ax.plot(t, yy, lw=0.6, color=f"C{r}")
            peak_abs = float(np.abs(y).max()) if len(y) else 0.0
            peak = peak_abs / lim if lim else 0.0
            power = {"velocity": "/s", "acceleration": "/s^2", "jerk": "/s^3"}[label]
            # scale to the signal; the limit lines show when they are in view
            span = max(1.2 * peak_abs, 1e-9)
            if peak >= 0.5:
                span = 1.15 * lim
            for sign in (1, -1):
                ax.axhline(sign * lim, color="tab:red", ls="--", lw=0.8)
            ax.set_ylim(-span, span)
            off = "" if span >= lim else f" (limit {lim:g} off scale)"
            ax.set_ylabel(f"{name} {label}\n({unit}{power})", fontsize=8)
            ax.set_title(f"{name} {label}: peak {peak:.1%} of limit{off}", fontsize=8)
            ax.tick_params(labelsize=7)
    for c in range(3):
        grid[-1][c].set_xlabel("time (s)", fontsize=8)
    fig.suptitle(title + ": per-axis motion vs limits (dashed), dwells grey", fontsize=10)
    if note:
        lines = textwrap.wrap(note, 150)
        fig.tight_layout(rect=(0, 0.02 * len(lines) + 0.01, 1, 1))
        fig.text(0.5, 0.005, "\n".join(lines), ha="center", va="bottom", fontsize=8)
    else:
        fig.tight_layout()
    return _png(fig)


def hemisphere_figure(s: Samples, others: list[np.ndarray], centre: np.ndarray, radius: float,
                      tracks: list[float], nodes: list[tuple[str, np.ndarray]], title: str,
                      feed_mm_per_min: float) -> bytes:
    fig = plt.figure(figsize=(15, 7))
    ax = fig.add_subplot(121, projection="3d")
    top = fig.add_subplot(122)
    c, r = centre, radius
    phi = np.linspace(0, 2 * np.pi, 181)
    for e in np.radians(tracks):
        ax.plot(c[0] + r * np.cos(e) * np.cos(phi), c[1] + r * np.cos(e) * np.sin(phi),
                c[2] + r * np.sin(e) + 0 * phi, color="0.6", lw=0.7)
        top.plot(c[0] + r * np.cos(e) * np.cos(phi), c[1] + r * np.cos(e) * np.sin(phi),
                 color="0.6", lw=0.7)
    for m in np.radians(np.arange(0, 360, 30)):
        el = np.linspace(0, np.pi / 2, 46)
        ax.plot(c[0] + r * np.cos(el) * np.cos(m), c[1] + r * np.cos(el) * np.sin(m),
                c[2] + r * np.sin(el), color="0.85", lw=0.5)
    for pts in others:
        ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], color="0.75", lw=0.5)
        top.plot(pts[:, 0], pts[:, 1], color="0.8", lw=0.5)
    moving = s.phase != "dwell"
    p = s.ball_mm[moving][::5]
    v = s.speed_mm_per_s[moving][::5]
    tt = s.t_s[moving][::5]
    by_speed = _speed_varies(s, feed_mm_per_min)
    if len(p) > 1:
        from matplotlib.collections import LineCollection

        seg = np.stack([p[:-1], p[1:]], axis=1)
        # where the speed holds the feed, colour by time: the order the path is run in
        values, cmap, clim, label = ((v[:-1], "viridis", (0, feed_mm_per_min / 60.0),
                                      "path speed (mm/s)") if by_speed else
                                     (tt[:-1], "plasma", (0, float(s.t_s[-1])),
                                      "time from program start (s); the speed holds the feed"))
        lc = Line3DCollection(seg, cmap=cmap, lw=2.0)
        lc.set_array(values)
        lc.set_clim(*clim)
        ax.add_collection(lc)
        lc2 = LineCollection(seg[:, :, :2], cmap=cmap, lw=2.0)
        lc2.set_array(values)
        lc2.set_clim(*clim)
        top.add_collection(lc2)
        fig.colorbar(lc2, ax=top, shrink=0.8, label=label)
        # the start (a star) and the direction (arrows along the first forward run)
        ax.scatter(*p[0], marker="*", s=160, color="black", zorder=5)
        top.plot(p[0, 0], p[0, 1], "*", ms=14, color="black", zorder=5, label="start")
        for frac in (0.03, 0.12, 0.25, 0.38):
            i = int(frac * len(p))
            j = min(i + max(len(p) // 200, 2), len(p) - 1)
            top.annotate("", (p[j, 0], p[j, 1]), (p[i, 0], p[i, 1]), zorder=6,
                         arrowprops={"arrowstyle": "-|>", "color": "black", "lw": 1.2,
                                     "mutation_scale": 12})
        top.legend(loc="upper right", bbox_to_anchor=(1.0, -0.08), fontsize=8, frameon=False)
    lowest = min(tracks) if tracks else 0.0
    for name, pos in nodes:
        ax.scatter(*pos, color="tab:red", s=10)
        top.scatter(pos[0], pos[1], color="tab:red", s=10, zorder=3)
        # names outside the lowest track, inside the others: the tracks lie close
        # together near the equator seen from above (A-4 beside B-4)
        d = pos[:2] - c[:2]
        n = float(np.hypot(*d))
        el = float(np.degrees(np.arcsin(np.clip((pos[2] - c[2]) / r, -1, 1))))
        out = 1.0 if abs(el - lowest) < 1e-6 else -1.0
        off = (d / n * 9.0 * out) if n > 1e-9 else np.array([0.0, 6.0])
        top.annotate(name, (pos[0], pos[1]), xytext=(off[0], off[1]), fontsize=6,
                     textcoords="offset points", ha="center", va="center")
    ax.scatter(*c, color="k", s=12)
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2], c[2] + r)
    ax.set_box_aspect((2, 2, 1))
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.view_init(elev=28, azim=-60)
    top.set_aspect("equal")
    top.set_xlabel("x (mm)")
    top.set_ylabel("y (mm)")
    top.set_title("seen from above (+Z)", fontsize=9)
    fig.suptitle(title + (": path coloured by speed" if by_speed else
                          ": path coloured by time") + ", static nodes red, start: the star",
                 fontsize=10)
    fig.tight_layout()
    return _png(fig)


def _speed_varies(s: Samples, feed_mm_per_min: float) -> bool:
    """Does the cruising speed differ from the feed by more than 2 % over more than 1 %
    of the cruise (a sample at a run's very start is not a speed that varies)?"""
    cruise = s.phase == "cruise"
    if not cruise.any():
        return True
    off = np.abs(s.speed_mm_per_s[cruise] - feed_mm_per_min / 60.0)
    return bool(np.percentile(off, 99) > 0.02 * feed_mm_per_min / 60.0)


def preview_files(pv: Preview, on_step=None) -> dict[str, bytes]:
    """``<program>_speed.png``, ``_axes.png`` and ``_hemisphere.png`` per planned layer."""
    layer_points = {lp.layer: lp.samples.ball_mm[lp.samples.phase != "dwell"][::10]
                    for lp in pv.layers}
    files = {}
    nodes = list(pv.nodes)
    tracks = list(pv.tracks_deg)
    feed = pv.feed_mm_per_min
    for lp in pv.layers:
        smp = lp.samples
        title = (f"{lp.program} (layer {lp.layer}, F{feed:g}, cycle {lp.cycle_s:.1f} s, "
                 f"timing: {pv.timing})")
        files[f"{lp.program}_speed.png"] = speed_figure(smp, title, feed)
        files[f"{lp.program}_axes.png"] = axes_figure(smp, title, pv.limits, pv.note)
        others = [v for k, v in layer_points.items() if k != lp.layer]
        files[f"{lp.program}_hemisphere.png"] = hemisphere_figure(
            smp, others, pv.centre_mm, pv.radius_mm, tracks, nodes, title, feed)
        if on_step:
            on_step(f"preview of layer {lp.layer} drawn")
    return files
