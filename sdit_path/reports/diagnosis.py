"""The diagnosis as text and as pictures (PNG bytes; no file IO here); its JSON is
:meth:`sdit_path.diagnose.Diagnosis.to_json`."""

from __future__ import annotations

import io

import numpy as np

from ..diagnose import Diagnosis
from ..diagnose.align import timing_is_weak
from ..reading.context import Context
from .views import above_pivot


def parameters_text(params: dict, std: dict) -> str:
    """``name value +- standard uncertainty`` for each parameter; a float without one
    was found by a search on a grid and says so."""
    out = []
    for k, v in params.items():
        if not isinstance(v, float):
            out.append(f"{k} {v}")
        elif std.get(k) is None:
            out.append(f"{k} {v:.4g} (on the search grid, no uncertainty)")
        else:
            out.append(f"{k} {v:.4g} +- {std[k]:.2g}")
    return ", ".join(out)


def summary_text(d: Diagnosis) -> str:
    al = d.alignment
    lines = [f"Program {d.program}: {d.samples['in_program']} samples in the program "
             f"({d.samples['dropouts']} dropouts); fitted on {d.samples['fitted']}, "
             f"{d.samples['heldout']} held out (a third of the stretches of each kind).",
             f"Alignment: program starts at {al.offset_s:.4f} s of the recording "
             f"(+- {al.offset_std_s * 1e3:.2f} ms), instrument clock {al.clock_ppm:+.1f} ppm "
             f"(+- {al.clock_std_ppm:.1f})." + (
                 " The recording holds little timing information: effects read through "
                 "their timing (lag, smoothing, vibration, spikes) are named with at most "
                 "medium confidence." if timing_is_weak(al) else ""),
             *([f"  Its uncertainty takes in: {'; '.join(al.widened_by)}."]
               if al.widened_by else []),
             f"Gap (measured - simulated): RMS {d.gap['rms_um']:.3f} um, max |gap| "
             f"{d.gap['max_abs_um']:.3f} um; sensor noise about {d.noise_um:.3f} um."]
    jump = d.gap.get("setup_step")
    if jump:
        lines.append(f"  the set-up offset stepped by {jump['size_um']:.2f} um (dx, dy, dz "
                     + ", ".join(f"{v:+.2f}" for v in jump["shift_um"])
                     + f") at {jump['at_s']:.2f} s of the recording: a mount slip or a knock? "
                     f"No effect of the library holds it: taken out before the timing and the effects "
                     f"were fitted, it counts as unexplained")
    w = d.gap["where"]
    if w.get("by_part_rms_um"):
        lines.append(f"  layer {w.get('layer', '?')}, RMS by part (um): " + ", ".join(
            f"{k} {v:.3f}" for k, v in w["by_part_rms_um"].items()))
    if w.get("segments"):
        lines.append("  strongest in: " + ", ".join(
            f"{s} ({w['segment_rms_um'][s]:.2f})" for s in w["segments"][:8]))
    if w.get("phase_rms_um"):
        lines.append("  by phase (RMS um): " + ", ".join(f"{k} {v:.3f}" for k, v in w["phase_rms_um"].items()))
    rv = w.get("reversal_rms_um", {})
    if rv:
        lines.append(f"  within 100 ms after an axis reversal {rv['within_100ms_after_reversal']:.3f} um, "
                     f"elsewhere {rv['elsewhere']:.3f} um")
    if not d.findings:
        lines.append("Findings: none - no effect of the library is supported by the data.")
    for k, f in enumerate(d.findings, start=1):
        name = " or ".join([f.effect, *f.ambiguous_with])
        lines.append(f"{k}. {name} ({f.confidence} confidence): "
                     f"{parameters_text(f.parameters, f.uncertainty)}")
        if f.unseen:
            lines.append(f"   not seen by the bar in this program (not estimated): "
                         f"{', '.join(f.unseen)}")
        if f.undetermined:
            lines.append(f"   not determined apart from the other parameters by this "
                         f"recording (not reported): {', '.join(f.undetermined)}")
        lines.append(f"   RMS {f.rms_before_um:.3f} -> {f.rms_after_um:.3f} um fitted, "
                     f"held-out {f.heldout_rms_before_um:.3f} -> {f.heldout_rms_after_um:.3f} um")
        mimics = [m for m in f.mimics if m["effect"] not in f.ambiguous_with]
        if mimics:
            lines.append("   mimicked by: " + ", ".join(f"{m['effect']} (R2 {m['r2']:.2f})" for m in mimics)
                         + " - the same signature; separate them by a second feed, direction or set-up")
        if f.ambiguous_with:
            lines.append(f"   AMBIGUOUS: {f.effect} or {' or '.join(f.ambiguous_with)} - this "
                         f"recording cannot tell them apart; to separate them, {f.separate_by}")
        if f.where.get("segments"):
            lines.append("   where: " + ", ".join(f.where["segments"][:8]))
    u = d.unexplained
    verdict = "NOT explained by the library" if u["significant"] else "at the noise level"
    lines.append(f"Unexplained: RMS {u['rms_um']:.3f} um ({verdict}).")
    if u.get("note"):
        lines.append(f"  {u['note']}")
    if u["significant"] and u["where"].get("segments"):
        lines.append("  strongest in: " + ", ".join(u["where"]["segments"][:8]))
        if u["where"].get("time_windows_s"):
            lines.append("  time windows (s): " + ", ".join(
                f"{a:.1f}-{b:.1f}" for a, b in u["where"]["time_windows_s"][:8]))
    return "\n".join(lines) + "\n"


def pictures(d: Diagnosis, ctx: Context) -> dict[str, bytes]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = d.series
    order = np.argsort(s["tau"])
    t, gap, fit, res = s["tau"][order], s["gap"][order], s["fitted"][order], s["residual"][order]
    step = max(1, len(t) // 40000)
    out = {}
    fig, ax = plt.subplots(2, 1, figsize=(12, 6.5), sharex=True)
    ax[0].plot(t[::step], gap[::step], lw=0.4, color="0.4", label="gap (measured - simulated)")
    ax[0].plot(t[::step], fit[::step], lw=0.6, color="C1", label="findings fitted")
    ax[0].set_ylabel("um")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t[::step], res[::step], lw=0.4, color="C0", label="unexplained residual")
    ax[1].set_ylabel("um")
    ax[1].set_xlabel("program time (s)")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, f in enumerate(d.findings):
        for a, b in f.where.get("time_windows_s", [])[:12]:
            ax[0].axvspan(a, b, color=colors[(k + 2) % len(colors)], alpha=0.15, lw=0)
        ax[0].plot([], [], color=colors[(k + 2) % len(colors)], lw=6, alpha=0.3,
                   label=f"{k + 1}. {f.effect}")
    ax[0].legend(loc="upper right", fontsize=8)
    dwell = ctx.phase == "dwell"
    edges = np.flatnonzero(np.diff(np.r_[0, dwell.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        ax[1].axvspan(ctx.t_s[a], ctx.t_s[min(b, ctx.n - 1)], color="0.85", lw=0)
    ax[1].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{d.program}: gap RMS {d.gap['rms_um']:.3f} um -> unexplained "
                 f"{d.unexplained['rms_um']:.3f} um (grey bands: dwells)")
    out["residual_time"] = _png(fig, plt)
    # seen from above the pivot (distance from the centre: the angle from the pole), the
    # whole path in grey under the samples the diagnosis read, coloured by their value
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.2))
    whole = ctx.phase != "dwell"
    wx, wy = above_pivot(ctx.ball_mm[whole][::20], ctx.pivot_mm)
    px, py = above_pivot(ctx.ball_mm[s["idx"]], ctx.pivot_mm)
    lim = float(np.percentile(np.abs(s["residual"]), 99)) or 1.0
    ring = np.linspace(0, 2 * np.pi, 361)
    for ax, (vals, title) in zip(axes, ((s["gap"], "gap"), (s["residual"], "unexplained"))):
        vl = float(np.percentile(np.abs(vals), 99)) or lim
        for c in (30.0, 60.0, 90.0):
            ax.plot(c * np.cos(ring), c * np.sin(ring), color="0.88", lw=0.6, zorder=0)
        ax.plot(wx, wy, ".", ms=0.6, color="0.8", zorder=1)
        sc = ax.scatter(px, py, c=vals, s=4, cmap="coolwarm", vmin=-vl, vmax=vl, zorder=2,
                        rasterized=True)
        ax.set_aspect("equal")
        ax.set_xlim(-100, 100)
        ax.set_ylim(-100, 100)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.annotate("+X", (93, 0), fontsize=8, color="0.4", va="center")
        ax.annotate("+Y", (0, 93), fontsize=8, color="0.4", ha="center")
        ax.set_title(f"{title} (um) seen from above the pivot", fontsize=10)
        fig.colorbar(sc, ax=ax, shrink=0.8)
    fig.suptitle(f"{d.program}: where the reading differs (coloured: the samples the "
                 f"diagnosis read; grey: the rest of the path; rings every 30 deg from the "
                 f"pole)", fontsize=10)
    fig.tight_layout()
    out["residual_hemisphere"] = _png(fig, plt)
    return out


def _png(fig, plt) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()
