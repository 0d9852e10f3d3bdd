"""The analysis of a test's recordings as text, and the files ``analyse`` writes (the
report, each recording on its program's time, the pictures); its JSON is
:meth:`sdit_path.analyse.AnalysisResult.to_json`."""

from __future__ import annotations

import json
import math

import numpy as np

from ..analyse import Analysed, AnalysisResult
from ..analyse.sphere import deviations
from ..analyse.stored import aligned_name
from ..plan.files import PlanFiles
from .html import report_html
from .vocabulary import effect_name, is_setup, parameter_rows, pooled, row_text
from .identification import summary_text as geometry_text


def summary_text(report: dict) -> str:
    """The analysis as the metrologist reads it, from its JSON (``to_json()``)."""
    lines = [f"Analysis of {len(report['recordings'])} recording(s). Alignment figures are "
             f"+- one standard uncertainty (k=1); the results in the trade's terms and the "
             f"effects' parameters +- the expanded uncertainty (k=2)."]
    for r in report["recordings"]:
        al = r["diagnosis"]["alignment"]
        own = (r.get("timing") or {}).get("model") == "recording"
        clock = ("clock rate within each run's measured time" if own else
                 f"clock {al['clock_ppm']:+.1f} ppm (+- {_num(al['clock_std_ppm'])})")
        lines.append(f"  {r['file']}: {r['program']} ({r['matched']}); program starts at "
                     f"{al['offset_s']:.4f} s of the recording (+- {_ms(al['offset_std_s'])} ms), "
                     f"{clock}, noise {r['diagnosis']['noise_um']:.2f} um")
        n = r.get("nuisances")
        if n:
            c = n["centring_um"]
            lines.append(f"    set-up: ball centring ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) um, bar "
                         f"length offset {n['bar_length_um']:.2f} um (with the machine's "
                         f"constant translations, which read exactly like a centring)")
        lines.extend(_timing_lines(r.get("timing") or {"model": "plan"}))
    for w in report["warnings"]:
        lines.append(f"WARNING: {w}")
    lines.append("")
    lines.append("GEOMETRY (estimated together with the effects below; each effect found in a "
                 "recording is a nuisance of that recording):")
    g = dict(report["geometry"])
    g.pop("recordings", None)
    g["warnings"] = report["warnings"] and ["see the warnings above"]
    lines.append(geometry_text(g, setup=False))
    alias = report["aliasing"]
    lines.append("")
    if alias:
        lines.append("Dynamics and geometry aliased in these recordings (an effect estimated "
                     "with the geometry takes certainty from it):")
        for x in alias:
            runs = "; ".join(f"{s['run']}: +- {s['std']:.3g}" for s in x["second_run"])
            lines.append(f"  {x['effect']} in {x['program']} makes {x['combination']} "
                         f"{x['factor']:.1f} times less certain (+- {x['std_without_effect']:.3g} "
                         f"without it). One more run of {x['program']}, computed on the same poses "
                         f"with the effect shared: {runs}.")
    else:
        lines.append("No effect found takes more than a third of the certainty of a determined "
                     "combination: dynamics and geometry are separated by these recordings.")
    lines.append("")
    lines.append("EFFECTS across the recordings (where found; an effect found in several "
                 "recordings as their weighted mean, +- k=2):")
    across = {k: v for k, v in report["across_recordings"].items() if not is_setup(k)}
    if not across:
        lines.append("  none found beyond the set-up.")
    for eff, hits in across.items():
        lines.append(f"  {effect_name(eff)}: " + "; ".join(
            f"{h['program']} ({h['confidence']} confidence, {h['contribution_rms_um']:.2f} um RMS)"
            for h in hits))
        for p in pooled(hits, eff):
            if p["value"] is not None:
                spread = (f", the recordings scatter {p['birge']:.1f} times their uncertainty"
                          if p["birge"] and p["birge"] > 1.05 else "")
                lines.append(f"    {p['label']} {p['value']:.4g} +- {2 * p['std']:.2g} "
                             f"{p['unit']}{spread}")
            else:
                rng = (f"{p['low']:.4g}" if p["low"] == p["high"]
                       else f"{p['low']:.4g} to {p['high']:.4g}")
                lines.append(f"    {p['label']} {rng} {p['unit']} (on the search grid, no "
                             f"uncertainty" + (f"; {p['note']}" if p["note"] else "") + ")")
    for r in report["recordings"]:
        lines.append("")
        lines.append(f"RECORDING {r['file']} ({r['program']}):")
        lines.append(_diagnosis_text(r["diagnosis"]))
    return "\n".join(lines).rstrip() + "\n"


def _timing_lines(timing: dict, within: float = 0.02) -> list[str]:
    """How the recording's program was timed, and the runs whose measured (or the
    control's) time is more than ``within`` off the plan's (and, measured, by more than
    three standard uncertainties)."""
    if timing["model"] == "plan":
        return []
    runs = timing["runs"]
    key = "measured_s" if timing["model"] == "recording" else "control_s"
    off = [r for r in runs if abs(r[key] / r["planned_s"] - 1.0) > within
           and abs(r[key] - r["planned_s"]) > 3 * r.get("std_s", 0.0)]
    if timing["model"] == "recording":
        law = ("the plan's time law" if timing.get("from", "plan") == "plan"
               else f"{timing['from']}'s motion of the program as written")
        head = (f"    timing: the recording's own, run by run (each run's start and end where "
                f"the reading places them, {law} inside each run; durations +- one standard "
                f"uncertainty, k=1); {len(runs) - len(off)} of {len(runs)} runs within "
                f"{within * 100:.0f} % of the planned time or their uncertainty")
    else:
        head = (f"    timing: the control's own (LinuxCNC 2.9's planner on the program as "
                f"written), not the plan's; {len(runs) - len(off)} of {len(runs)} runs within "
                f"{within * 100:.0f} % of the planned time")
    out = [head + (":" if off else ".")]
    for r in off:
        name = r["from"] if r["from"] == r["to"] else f"{r['from']}..{r['to']}"
        std = f" +- {r['std_s']:.2f}" if "std_s" in r else ""
        model = (f" ({timing['from']}'s planner: {r['model_s']:.2f} s)" if "model_s" in r
                 else "")
        out.append(f"      run {name}: {r[key]:.2f}{std} s, planned {r['planned_s']:.2f} s{model}")
    if timing["model"] == "recording" and timing.get("placed_std_s"):
        out.append(_placed_line(timing["placed_std_s"]))
    return out


def _placed_line(std_s: float) -> str:
    """What the run-by-run timing's precision leaves readable: a ringing at f is blurred
    by a timing error of std sigma by exp(-(2 pi f sigma)^2 / 2), 0.6 at f = 1/(2 pi sigma)."""
    f = 1.0 / (2 * math.pi * max(std_s, 1e-6))
    return (f"    the reading places the runs' starts and ends to +- {std_s * 1e3:.1f} ms "
            f"(median, k=1): what changes faster than that is blurred, a structural mode "
            f"ringing above {f:.0f} Hz is read only as its deflection, not its ringing")


def _ms(v) -> str:
    return "?" if v is None else f"{v * 1e3:.2f}"


def _num(v) -> str:
    return "?" if v is None else f"{v:.1f}"


def _diagnosis_text(d: dict) -> str:
    lines = [f"  gap RMS {d['gap']['rms_um']:.3f} um (the reading against the ideal one, set-up "
             f"included), noise {d['noise_um']:.3f} um"]
    found = [f for f in d["findings"] if not is_setup(f["effect"])]
    if not found:
        lines.append("  findings: none beyond the set-up")
    for k, f in enumerate(found, start=1):
        par = "; ".join(row_text(r) for r in parameter_rows(
            f["parameters"], f.get("parameter_std", {}), f["effect"]))
        name = " or ".join(effect_name(e) for e in [f["effect"], *f.get("ambiguous_with", [])])
        lines.append(f"  {k}. {name} ({f['confidence']} confidence, {f['contribution_rms_um']:.2f} "
                     f"um RMS): {par}")
        lines.append(f"     held-out RMS (on samples the fit never saw) "
                     f"{f['heldout_rms_before_um']:.3f} -> {f['heldout_rms_after_um']:.3f} um")
        if f.get("ambiguous_with"):
            lines.append(f"     AMBIGUOUS: to separate them, {f['separate_by']}")
    u = d["unexplained"]
    verdict = "NOT explained by the library" if u["significant"] else "at the noise level"
    lines.append(f"  unexplained: RMS {u['rms_um']:.3f} um ({verdict})"
                 + (": strongest in " + ", ".join(u["where"]["segments"][:6])
                    if u["significant"] and u.get("where", {}).get("segments") else ""))
    return "\n".join(lines)


def _columns(text: str) -> tuple[np.ndarray, np.ndarray]:
    """``t_s, delta_l_um`` of an aligned CSV as :func:`aligned_csv` writes it."""
    rows = [ln.split(",") for ln in text.splitlines()
            if ln and not ln.startswith("#") and not ln.startswith("t_s")]
    data = np.array(rows, dtype=float).reshape(-1, 2)
    return data[:, 0], data[:, 1]


def aligned_csv(a: Analysed) -> str:
    """The recording on its program's time, for other tools."""
    al = a.diagnosis.alignment
    head = [f"# program: {a.program}", f"# source: {a.label}",
            f"# offset_s: {al.offset_s:.6f}", f"# clock_ppm: {al.clock_ppm:.3f}",
            "# t_s is program time: measured t = offset_s + t_s * (1 + clock_ppm 1e-6)",
            "t_s,delta_l_um"]
    rows = [f"{t:.6f},{y:.4f}" for t, y in zip(a.trace.t_s, a.trace.delta_l_um)
            if math.isfinite(y)]  # a dropout stays out
    return "\n".join(head + rows) + "\n"


def analysis_files(result: AnalysisResult, plan: PlanFiles | None = None,
                   plan_sha256: str = "", conditions: list[tuple[str, str]] | None = None,
                   html: bool = True) -> dict[str, str | bytes]:
    """Every file ``analyse`` writes (relative path -> content): the analysis as JSON and
    text, the test report (``report.html``, with ``plan``), each recording on its
    program's time, and the pictures drawn.  ``plan_sha256`` (of the plan's plan.json)
    ties the analysis to its plan."""
    report = result.to_json()
    if plan is not None:
        report["plan"] = {"plan_json_sha256": plan_sha256, "controller": plan.ran_on}
    files: dict[str, str | bytes] = {"analysis.json": json.dumps(report, indent=2) + "\n",
                                     "analysis.txt": summary_text(report)}
    aligned = {}
    for a in result.recordings:
        name = aligned_name(a.program, a.label)
        aligned[a.program] = files[f"aligned/{name}"] = aligned_csv(a)
        for pic, png in a.pictures.items():
            files[f"pictures/{name[:-len('.csv')]}_{pic}.png"] = png
    if plan is not None and html:
        # read from the aligned files as written, as ``sdit-path report`` reads them: the
        # same report either way
        devs = deviations(plan, [(prog, *_columns(text)) for prog, text in aligned.items()])
        files["report.html"] = report_html(plan, plan_sha256, report, devs, conditions)
    return files
