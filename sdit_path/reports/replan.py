"""The re-plan as text and pictures (PNG bytes; no file IO here); its JSON is
:meth:`sdit_path.replan.Replan.to_json`.
"""

from __future__ import annotations

import json

import numpy as np

from ..plan.files import sealed
from ..plan.manifest import plan_directory_files
from ..plan.pipeline import PlanResult
from ..replan import Replan
from ..replan.candidates import sector_of
from ..replan.evaluate import BIAS_NOISE_UM
from .views import above_pivot




def report_text(r: Replan) -> str:
    j = r.to_json()
    fmt = lambda v, f: "?" if v is None else format(v, f)  # noqa: E731
    lines = []
    nb = len(r.before.reasons)
    if r.asked:
        lines.append(f"Segments named: {', '.join(r.asked)}.")
    lines.append(f"Bad segments as planned: {nb}" + ("." if nb else " (none: nothing to re-plan)."))
    for sid, rs in r.before.reasons.items():
        lines.append(f"  {sid}: " + "; ".join(x.text for x in rs))
    for s in j["sectors"]:
        lines.append("")
        lines.append(f"SECTOR {s['sector']}: chosen {s['chosen']}")
        lines.append(f"  {'segment':8} {'reasons before':44} reasons after")
        for sid, ba in s["segments"].items():
            b = ", ".join(x["kind"] for x in ba["before"]["reasons"]) or "-"
            a = ", ".join(x["kind"] for x in ba["after"]["reasons"]) or "-"
            lines.append(f"  {sid:8} {b:44} {a}")
        lines.append("  candidates (best first): " + "; ".join(
            f"{c['curve']}: " + ("cannot be planned" if not c["feasible"] else
                                 f"cleared {'+'.join(c['cleared']) or 'nothing'}, "
                                 f"information {fmt(c['information_nats'], '.3f')} nats, lag "
                                 f"bias {fmt(c['lag_bias_std'], '.1f')} std, layer "
                                 f"{fmt(c['layer_cycle_s'], '.1f')} s")
            for c in s["candidates"][:6]) + (" ..." if len(s["candidates"]) > 6 else ""))
    for layer, tried in r.setup.items():
        lines.append("")
        works = [x for x in tried if x.get("feasible")]
        need = next((x["clearance_needed_mm"] for x in tried if "clearance_needed_mm" in x), None)
        what = ("makes its infeasible segments feasible" if need is None else
                f"changes the clearance at its nodes (needed: {need:.2f} mm)")
        lines.append(f"LAYER {layer}: no curve in the patch {what}; "
                     + ("these set-up changes would (each planned): " + "; ".join(
                         f"{x['change']} ({x['config']}, clearance {x['min_clearance_mm']:.2f} mm)"
                         if x.get("min_clearance_mm") is not None else
                         f"{x['change']} ({x['config']})" for x in works)
                        if works else "none of the set-up changes tried would: " + "; ".join(
                            f"{x['change']}: " + (_short_of(x) if x.get("planned")
                                                  else x.get("why", "")) for x in tried)))
    info = j["information_nats"]
    lines.append("")
    lines.append(f"WHOLE TEST: information of the {j['determined_combinations']} determined "
                 f"combinations {fmt(info['before'], '.3f')} -> {fmt(info['after'], '.3f')} nats "
                 f"(their geometric-mean standard uncertainty x "
                 f"{fmt(info['geometric_mean_std_factor'], '.3f')}); a 1 ms lag of one axis "
                 f"biases them by at most "
                 + ", ".join(f"{a} {fmt(j['lag_bias_std']['before'].get(a), '.1f')} -> "
                             f"{fmt(j['lag_bias_std']['after'].get(a), '.1f')}"
                             for a in j["lag_bias_std"]["before"])
                 + f" std (at {BIAS_NOISE_UM} um noise); cycle "
                 f"{j['cycle_s']['before']:.1f} -> {j['cycle_s']['after']:.1f} s; bad segments "
                 f"{len(j['bad_segments_before'])} -> {len(j['bad_segments_after'])}.")
    return "\n".join(lines) + "\n"


def _short_of(x: dict) -> str:
    """What a planned set-up change left short of."""
    if x.get("still_infeasible"):
        return ", ".join(x["still_infeasible"][:4]) + " still infeasible"
    low = x.get("min_clearance_mm")
    return "clearance " + ("unknown" if low is None else f"{low:.2f} mm")


def pictures(r: Replan) -> dict[str, bytes]:
    """Per re-planned layer, ``<layer>_replan.png``: the layer seen from above the pivot
    (azimuth around, elevation outwards from the pole), the curves as planned in grey and
    as re-planned in blue, each bad segment in red with its reasons."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    layers = sorted({s[0] for s in r.tried})
    for name in layers:
        b, a = r.before.layers[name], r.after.layers[name]
        fig, ax = plt.subplots(figsize=(7.5, 7.5))
        for ev, style in ((b, dict(color="0.6", lw=1.0, label="as planned")),
                          (a, dict(color="tab:blue", lw=1.2, label="re-planned"))):
            if ev.samples is None:
                continue
            x, y = above_pivot(ev.samples.ball_mm, r.config.ballbar.pivot_mm)
            moving = ev.samples.phase != "dwell"
            ax.plot(np.where(moving, x, np.nan), np.where(moving, y, np.nan), **style)
        if b.samples is not None:
            x, y = above_pivot(b.samples.ball_mm, r.config.ballbar.pivot_mm)
            for sid, rs in r.before.reasons.items():
                if sector_of(sid)[0] != name:
                    continue
                m = b.samples.segment == sid
                if not m.any():
                    continue
                ax.plot(np.where(m, x, np.nan), np.where(m, y, np.nan), color="tab:red", lw=2.0)
                k = np.flatnonzero(m)[len(np.flatnonzero(m)) // 2]
                ax.annotate(f"{sid}: " + ", ".join(x.kind for x in rs), (x[k], y[k]), fontsize=7,
                            color="tab:red", xytext=(4, 4), textcoords="offset points")
        # what was chosen per sector: a feed alone leaves the curve where it was
        chosen = [f"{sec}: {c.label}" for sec, c in sorted(r.chosen.items()) if sec[0] == name]
        if chosen:
            ax.text(0.01, 0.01, "chosen - " + "; ".join(chosen), transform=ax.transAxes,
                    fontsize=7, color="tab:blue", va="bottom")
        ax.set_aspect("equal")
        ax.set_title(f"layer {name}: curves as planned (grey) and re-planned (blue); bad "
                     f"segments in red", fontsize=9)
        ax.set_xlabel("90 deg - elevation, along the azimuth (deg)")
        ax.legend(loc="upper right", fontsize=8)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
        plt.close(fig)
        out[f"{name}_replan.png"] = buf.getvalue()
    return out


def replan_files(result: Replan, planned: PlanResult, source: str,
                 on_step=None) -> dict[str, str | bytes]:
    """Every file ``replan`` writes (relative path -> content): the re-planned plan's
    directory, its ``plan.json`` carrying the re-plan (``from``: the old plan's folder
    name ``source``), ``replan.json``, ``replan.txt`` and the pictures."""
    files = plan_directory_files(planned, on_step=on_step)
    report = result.to_json()
    manifest = json.loads(files["plan.json"])
    manifest["replan"] = {"from": source, **report}
    files["plan.json"] = json.dumps(sealed(manifest), indent=2, ensure_ascii=False) + "\n"
    files["replan.json"] = json.dumps(report, indent=2) + "\n"
    files["replan.txt"] = report_text(result)
    for name, png in pictures(result).items():
        files[f"pictures/{name}"] = png
    return files
