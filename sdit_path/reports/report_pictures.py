"""The test report's pictures (PNG bytes; no file IO here): the plan seen from above the
pivot, a polar plot of each layer's radial deviation, where a finding lives, and the
runs' timing against the plan.

The plan map is an azimuthal equidistant view from above the pivot: the distance from
the centre is the angle from the pole (90 deg at the equator), the angle is the
azimuth, as the plan's frame counts it (from +X, counter-clockwise seen from +Z)."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..analyse.sphere import LayerDeviation, pass_of  # noqa: E402
from ..geometry.hemisphere import TEST_SEGMENT  # noqa: E402
from ..timing.trajectory import Samples  # noqa: E402
from .views import above_pivot  # noqa: E402

_PNG = {"Software": None}
#: forward and reverse pass, as a ballbar report draws them
FORWARD, REVERSE = "#1f5fa8", "#d2691e"


def _png(fig, dpi: int = 130) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata=_PNG)
    plt.close(fig)
    return buf.getvalue()


def _frame(ax, rim: float = 90.0) -> None:
    t = np.linspace(0, 2 * np.pi, 361)
    for c in (30.0, 60.0, 90.0):
        ax.plot(c * np.cos(t), c * np.sin(t), color="0.85", lw=0.6, zorder=0)
    for a in range(0, 360, 30):
        ax.plot([0, rim * np.cos(np.radians(a))], [0, rim * np.sin(np.radians(a))],
                color="0.9", lw=0.5, zorder=0)
    ax.annotate("+X", (rim + 6, 0), ha="left", va="center", fontsize=7, color="0.4")
    ax.annotate("+Y", (0, rim + 6), ha="center", va="bottom", fontsize=7, color="0.4")
    ax.set_aspect("equal")
    ax.set_xlim(-rim - 14, rim + 16)
    ax.set_ylim(-rim - 14, rim + 14)
    ax.axis("off")


def _runs(seg: np.ndarray) -> list[tuple[int, int]]:
    starts = np.r_[0, np.flatnonzero(seg[1:] != seg[:-1]) + 1, len(seg)]
    return list(zip(starts[:-1], starts[1:]))


def plan_map(layers: list[tuple[str, Samples]], nodes: list[dict], pivot,
             start_nodes: dict[str, str]) -> bytes:
    """Every layer's forward pass in its colour (transits dashed grey), the static nodes
    with their names, each layer's start node (a star) and its direction (an arrow)."""
    fig, ax = plt.subplots(figsize=(6.8, 5.6))
    _frame(ax)
    colours = plt.get_cmap("tab10")
    handles = []
    for k, (name, s) in enumerate(layers):
        colour = colours(k % 10)
        x, y = above_pivot(s.ball_mm, pivot)
        first = pass_of(s) == 0
        test = np.array([bool(TEST_SEGMENT.match(v)) for v in s.segment])
        moving = s.phase != "dwell"
        for a, b in _runs(s.segment):
            if not moving[a] or s.phase[a] == "reposition":
                continue
            if test[a] and first[a]:
                ax.plot(x[a:b], y[a:b], color=colour, lw=1.3, zorder=2)
            elif not test[a]:
                ax.plot(x[a:b], y[a:b], color="0.55", lw=0.8, ls=(0, (3, 2)), zorder=1)
        handles.append(plt.Line2D([], [], color=colour, lw=1.6, label=f"layer {name}"))
        # the direction: an arrow a little way into the first test segment
        run = next(((a, b) for a, b in _runs(s.segment) if test[a] and moving[a]), None)
        if run is not None:
            a, b = run
            i = a + (b - a) // 3
            j = min(i + max((b - a) // 10, 2), b - 1)
            ax.annotate("", (x[j], y[j]), (x[i], y[i]), zorder=5,
                        arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 1.4,
                                    "mutation_scale": 12})
    by_id = {n["id"]: n for n in nodes}
    for n in nodes:
        px, py = above_pivot(np.array([n["position_mm"]]), pivot)
        ax.plot(px, py, "o", ms=3.2, color="black", zorder=4)
        # the name outside the node along its azimuth, small enough for the next track
        az = np.radians(n["azimuth_deg"])
        ax.annotate(n["id"], (px[0] + 5.5 * np.cos(az), py[0] + 5.5 * np.sin(az)),
                    fontsize=6, ha="center", va="center", color="0.15", zorder=6)
    starts = {v for v in start_nodes.values() if v in by_id}
    for sid in sorted(starts):
        px, py = above_pivot(np.array([by_id[sid]["position_mm"]]), pivot)
        ax.plot(px, py, "*", ms=13, color="#c00000", mec="white", mew=0.6, zorder=7)
    handles.append(plt.Line2D([], [], color="0.55", lw=0.8, ls=(0, (3, 2)),
                              label="transit"))
    handles.append(plt.Line2D([], [], marker="*", ls="", ms=10, color="#c00000",
                              label="start node"))
    handles.append(plt.Line2D([], [], marker="o", ls="", ms=4, color="black",
                              label="static node (dwell)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7,
              frameon=False)
    ax.set_title("The test seen from above the pivot (distance from the centre: angle "
                 "from the pole)", fontsize=8)
    fig.subplots_adjust(left=0.0, right=0.72, top=0.94, bottom=0.02)
    return _png(fig)


def polar(d: LayerDeviation, magnification_um: float | None = None) -> bytes:
    """The layer's radial deviation against the azimuth, forward and reverse pass in two
    colours, the zero circle (the sphere) bold; the radial scale reads in um."""
    span = magnification_um or max(1.0, float(np.ceil(max(abs(d.max_um), abs(d.min_um)))))
    fig = plt.figure(figsize=(3.5, 3.3))
    ax = fig.add_subplot(projection="polar")
    ax.set_rorigin(-2.0 * span)
    ax.set_ylim(-span, span)
    th = np.radians(d.azimuth_deg)
    for rev, colour, label in ((False, FORWARD, "forward"), (True, REVERSE, "reverse")):
        sel = d.reverse == rev
        if sel.any():
            order = np.argsort(th[sel], kind="stable")
            ax.plot(th[sel][order], d.deviation_um[sel][order], ".", ms=0.8, color=colour,
                    label=label, rasterized=True)
    t = np.linspace(0, 2 * np.pi, 361)
    ax.plot(t, np.zeros_like(t), color="black", lw=0.9)
    ax.set_rticks([-span, -span / 2, 0, span / 2, span])
    ax.tick_params(labelsize=6)
    ax.set_rlabel_position(100)
    ax.set_title(f"{d.program}: radial deviation (um)", fontsize=8)
    leg = ax.legend(loc="lower left", bbox_to_anchor=(-0.12, -0.14), fontsize=6, markerscale=8,
                    frameon=False, ncol=2)
    leg.set_in_layout(True)
    fig.subplots_adjust(left=0.08, right=0.92, top=0.86, bottom=0.1)
    return _png(fig)


def where_map(s: Samples, pivot, segments: list[str], title: str) -> bytes:
    """A layer's path from above the pivot with the segments a finding lives in marked."""
    fig, ax = plt.subplots(figsize=(2.6, 2.5))
    _frame(ax)
    x, y = above_pivot(s.ball_mm, pivot)
    marked = set(segments)
    for a, b in _runs(s.segment):
        if s.phase[a] in ("dwell", "reposition"):
            continue
        hot = s.segment[a] in marked
        ax.plot(x[a:b], y[a:b], color="#c00000" if hot else "0.7", lw=1.6 if hot else 0.7,
                zorder=2 if hot else 1)
    ax.set_title(title, fontsize=7)
    fig.subplots_adjust(left=0.0, right=1.0, top=0.9, bottom=0.0)
    return _png(fig, dpi=120)


def timing_chart(program: str, runs: list[dict], key: str) -> bytes:
    """Each run's measured (or the control's) duration against the planned one, in % of
    the planned, with its expanded uncertainty (k=2) where it has one."""
    fig, ax = plt.subplots(figsize=(6.4, 1.9))
    pos = np.arange(len(runs))
    ratio = np.array([(r[key] / r["planned_s"] - 1.0) * 100.0 for r in runs])
    err = np.array([2 * r.get("std_s", 0.0) / r["planned_s"] * 100.0 for r in runs])
    ax.axhline(0.0, color="black", lw=0.7)
    for lim in (-2.0, 2.0):
        ax.axhline(lim, color="0.6", lw=0.6, ls=":")
    ax.errorbar(pos, ratio, yerr=err, fmt="o", ms=3, color=FORWARD, ecolor="0.5", lw=0.8)
    ax.set_xticks(pos)
    ax.set_xticklabels([r["from"] if r["from"] == r["to"] else f"{r['from']}..{r['to']}"
                        for r in runs], rotation=90, fontsize=5)
    ax.tick_params(axis="y", labelsize=6)
    ax.set_ylabel("duration vs plan (%)", fontsize=7)
    ax.set_title(f"{program}: each run's duration against the plan (bars: k=2; dotted: "
                 f"+-2 %)", fontsize=8)
    fig.subplots_adjust(left=0.1, right=0.99, top=0.86, bottom=0.34)
    return _png(fig)


def _outline(part, rot: np.ndarray, pos: np.ndarray) -> np.ndarray | None:
    """Surface points of a posed primitive ``(k, 3)`` (bed frame); None for a mesh."""
    size = part.size_mm
    if part.shape == "box" and len(size) == 3:
        c = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                     float) * np.asarray(size) / 2.0
    elif part.shape in ("cylinder", "capsule") and len(size) == 2:
        r, h = size
        half = h / 2.0 + (r if part.shape == "capsule" else 0.0)
        a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        ring = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)])
        c = np.vstack([ring + [0, 0, -half], ring + [0, 0, half]])
    elif part.shape == "sphere" and len(size) >= 1:
        r = size[0]
        a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        c = np.vstack([np.column_stack([r * np.cos(a), r * np.sin(a), 0 * a]),
                       np.column_stack([r * np.cos(a), 0 * a, r * np.sin(a)]),
                       np.column_stack([0 * a, r * np.cos(a), r * np.sin(a)])])
    else:
        return None
    return c @ rot.T + pos


def machine_view(parts, poses, pivot_bed: np.ndarray, radius_mm: float, title: str) -> bytes:
    """The machine's parts, the balls and the bar at one pose, seen from the front (along
    +Y) and from the side (along -X): each part as the outline of its projection (table
    side blue, tool side grey, the bar orange), the sphere the ball runs on dashed."""
    from matplotlib.patches import Polygon
    from scipy.spatial import ConvexHull, QhullError

    colours = {"work": ("#c9d7ea", "#4a6d9c"), "tool": ("#dddddd", "#555555"),
               "bar": ("#f2b36b", "#b3671a")}
    fig, axes = plt.subplots(1, 2, figsize=(7.0, 3.6))
    t = np.linspace(0, np.pi, 91)
    for ax, (i, j, name) in zip(axes, ((0, 2, "front (X, Z)"), (1, 2, "side (Y, Z)"))):
        pts_all = []
        for part, (rot, pos) in zip(parts, poses):
            pts = _outline(part, rot[0], pos[0])
            if pts is None:
                continue
            p2 = pts[:, [i, j]]
            pts_all.append(p2)
            face, edge = colours.get(part.side, colours["tool"])
            if part.name in ("pivot_ball", "tool_ball"):
                face, edge = "#222222", "#000000"
            try:
                hull = p2[ConvexHull(p2).vertices]
            except (QhullError, ValueError):
                continue
            ax.add_patch(Polygon(hull, closed=True, facecolor=face, edgecolor=edge, lw=0.8,
                                 zorder=3 if part.side == "bar" or "ball" in part.name else 2))
        ax.plot(pivot_bed[i] + radius_mm * np.cos(t), pivot_bed[j] + radius_mm * np.sin(t),
                ls=(0, (4, 3)), color="0.5", lw=0.8, zorder=1)
        if pts_all:
            allp = np.vstack(pts_all)
            lo, hi = allp.min(axis=0), allp.max(axis=0)
            pad = 0.05 * float(max(hi - lo))
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=8)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("mm", fontsize=6)
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    return _png(fig)
