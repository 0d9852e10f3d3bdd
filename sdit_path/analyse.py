"""From real recordings to one answer: ``sdit-path analyse``.

Every recording is matched to its program (named, or recognised from its duration and
from where it stands still) and aligned (start, clock rate); each is diagnosed (the
effect library, the geometry estimated with it); then the geometry is identified from
all recordings together with every effect the diagnosis found as a nuisance of its
recording, estimated with the geometry and eliminated with the set-up, so that a servo
mismatch is not read as squareness and a drift not as a scale error.  Where an effect
and the geometry share a direction in the data at hand, the report says by how much and
which second run (reverse direction, half the feed) would separate them, computed on
the same poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from .reading.context import Context, build_context
from .diagnose.diagnose import Diagnosis, diagnose, dynamic_columns, noise_estimate
from .diagnose.diagnose import Options as DiagnosisOptions
from .diagnose.effects import Samples, library
from .diagnose.recording import AlignedRecording, align_recording, plausible_programs, poor_fit
from .diagnose.report import parameters_text, pictures as diagnosis_pictures
from .errormodel.errorset import ErrorSet
from .errormodel.model import ModelOptions
from .errors import ConfigError, RecordingError
from .heap import reusing_freed_memory
from .identify.identify import ExtraGroup, first_gram, identification_model, identify
from .parallel import each
from .plan.files import PlanFiles
from .reading.trace import Trace

#: findings that are the set-up, or geometry the identification models itself
_NOT_NUISANCE = ("setup_offset", "bar_length", "geometry_beyond_library")


@dataclass
class Analysed:
    label: str
    program: str
    matched: str  # how the program was chosen
    aligned: AlignedRecording
    diagnosis: Diagnosis
    trace: Trace  # the recording on program time (final alignment)
    ctx: Context  # the program's context
    pictures: dict[str, bytes] = field(default_factory=dict)  # name -> PNG


_WINDOW_S = 0.5

#: the least dwell score (:func:`dwell_score`) of a recording of the program
DWELL_MATCH = 0.4


def still_windows(trace: Trace) -> np.ndarray | None:
    """Per 0.5 s of the recording: does it stand still (its spread no more than its own
    noise allows)?  None when it stands still most of the time (a perfect set-up on a
    perfect machine: where it stands still says nothing about the program)."""
    t = np.asarray(trace.t_s, float)
    y = np.asarray(trace.delta_l_um, float)
    ok = np.isfinite(y)
    t, y = t[ok], y[ok]
    if len(t) < 1000:
        return None
    noise = noise_estimate(y, t)
    k = np.searchsorted(t, np.arange(t[0], t[-1], _WINDOW_S))
    still = np.array([b - a >= 20 and float(np.std(y[a:b])) <= 1.15 * noise + 0.01
                      for a, b in zip(k[:-1], k[1:])], bool)
    return None if still.mean() > 0.6 else still


def _dwell_windows(plan: PlanFiles, program: str) -> tuple[np.ndarray, np.ndarray]:
    """Per 0.5 s of the program: wholly inside a dwell, wholly in the motion (0 or 1)."""
    traj = plan.trajectory(program)
    edges = np.arange(0.0, float(traj.t_s[-1]), _WINDOW_S)
    k = np.searchsorted(traj.t_s, edges)
    dwell = (traj.phase == "dwell")
    inside = np.array([b > a and dwell[a:b].all() for a, b in zip(k[:-1], k[1:])], float)
    moving = np.array([b > a and not dwell[a:b].any() for a, b in zip(k[:-1], k[1:])], float)
    return inside, moving


def dwell_score(plan: PlanFiles, program: str, still: np.ndarray) -> float:
    """How well the program's dwells fall on the recording's still windows, at the best
    start: share of the windows inside a dwell that are still, less the share of the
    windows in the motion that are (1: a perfect match; near 0: another program)."""
    inside, moving = _dwell_windows(plan, program)
    if len(inside) > len(still) or not inside.any() or not moving.any():
        return 0.0
    s = still.astype(float)
    hits = np.correlate(s, inside, "valid") / inside.sum()
    false = np.correlate(s, moving, "valid") / moving.sum()
    return float(np.max(hits - false))


def match(plan: PlanFiles, trace: Trace, label: str, named: str | None = None,
          contexts: dict | None = None) -> tuple[AlignedRecording, str]:
    """The recording aligned to its program, and how the program was chosen.  Refuses
    (one line) a recording that fits no program of the plan, or fits another one better
    than the program named."""
    fits = plausible_programs(plan, trace)
    by_duration = [p for p, why in fits if not why]
    if named is not None and named not in plan.program_names:
        raise ConfigError(label, f"program {named[:40]!r} is not in the plan "
                                 f"({', '.join(plan.program_names)})")
    still = still_windows(trace)
    if not by_duration:
        raise RecordingError(f"{label}: fits no program of this plan: "
                             + "; ".join(why for _, why in fits)
                             + " (another plan or feed?)")
    scores = {p: dwell_score(plan, p, still) for p in by_duration} if still is not None else {}
    seen = ("dwells on the recording's still windows: " + ", ".join(
        f"{p} {v:.2f}" for p, v in sorted(scores.items(), key=lambda kv: -kv[1]))
        if scores else "the recording stands still nearly throughout (its dwells say nothing)")
    # a recording of its program scores 0.63-1.0 (every one made so far), another
    # program of the same plan up to 0.42, another feed or plan 0.25: below DWELL_MATCH
    # no program of this plan was recorded (when the recording stands still at least
    # half as long as the programs dwell: else it cannot tell)
    telling = still is not None and scores and still.sum() >= 0.5 * min(
        _dwell_windows(plan, p)[0].sum() for p in scores)
    if telling and scores and max(scores.values()) < DWELL_MATCH:
        raise RecordingError(f"{label}: matches no program of this plan: its still windows fall "
                             f"on no program's dwells ({seen}; a recording of its program scores "
                             f"{DWELL_MATCH} or more): another feed or plan?")
    if telling and named in scores and scores[named] < DWELL_MATCH:
        raise RecordingError(f"{label}: not a recording of {named}: its still windows fall on "
                             f"{named}'s dwells at {scores[named]:.2f} ({seen}; a recording of its "
                             f"program scores {DWELL_MATCH} or more): another program, feed or plan?")
    if scores:
        # the dwell pattern first: only the programs whose dwells fall on the
        # recording's still windows nearly as well as the best one's are aligned
        top = max(scores.values())
        near = [p for p in by_duration if scores[p] >= top - 0.15]
    else:
        near = list(by_duration)
    candidates = list(dict.fromkeys(([named] if named else []) + near))
    if named and named not in by_duration:
        why = dict(fits)[named]
        raise RecordingError(f"{label}: not a recording of {named}: {why}"
                             + (f"; its duration fits {', '.join(by_duration)}" if by_duration else ""))
    results, refusals = {}, {}
    for prog in candidates:
        try:
            results[prog] = align_recording(plan, prog, trace, label,
                                            _context(plan, prog, contexts))
        except RecordingError as exc:
            refusals[prog] = str(exc).removeprefix(f"{label}: ")
    if named:
        if named not in results:
            raise RecordingError(f"{label}: {refusals[named]}"
                                 + (f"; it fits {', '.join(results)}" if results else ""))
        mine = results[named].alignment.rms_um
        better = [p for p, r in results.items() if p != named and r.alignment.rms_um < 0.8 * mine]
        if better:
            b = min(better, key=lambda p: results[p].alignment.rms_um)
            raise RecordingError(
                f"{label}: fits {b} better than {named} (alignment residual "
                f"{results[b].alignment.rms_um:.2f} against {mine:.2f} um; {seen}): name the "
                f"program that was run")
        return results[named], "named"
    if not results:
        raise RecordingError(
            f"{label}: matches no program of this plan ({seen}): "
            + "; ".join(f"{p}: {why}" for p, why in refusals.items())[:600])
    ranked = sorted(results, key=lambda p: results[p].alignment.rms_um)
    best = ranked[0]
    if len(ranked) > 1 and results[ranked[1]].alignment.rms_um < 1.25 * results[best].alignment.rms_um:
        raise RecordingError(
            f"{label}: fits {best} and {ranked[1]} alike (alignment residual "
            f"{results[best].alignment.rms_um:.2f} and {results[ranked[1]].alignment.rms_um:.2f} um); "
            f"name its program: --measured {best}={label}")
    return results[best], (f"recognised: {seen}; alignment residual {results[best].alignment.rms_um:.2f} um"
                           + "".join(f", {p} {results[p].alignment.rms_um:.2f}" for p in ranked[1:]))


def _nuisance_effects(options: ModelOptions) -> set[str]:
    skip = set(_NOT_NUISANCE)
    if options.squareness:
        skip.add("squareness")
    if options.linear_order >= 1:
        skip.add("scale_mismatch")
    return skip


def effect_columns(plan: PlanFiles, d: Diagnosis, options: ModelOptions, ctx
                   ) -> tuple[np.ndarray | None, list[ExtraGroup]]:
    """The columns (trajectory samples) of what the diagnosis found beyond the set-up and
    the geometry the identification models, named for the aliasing report."""
    lib = {e.name: e for e in library(plan.config.machine, plan.tested_travel())}
    skip = _nuisance_effects(options)
    everywhere = Samples(np.arange(ctx.n), ctx.t_s)
    cols, groups, at = [], [], 0
    for f in d.findings:
        if f.effect in skip or f.effect not in lib:
            continue
        eff = lib[f.effect]
        C = _columns(eff, ctx, everywhere, f.nonlinear)
        if C is None:
            continue
        # the nonlinear parameters (a lag, a time constant) are estimated too: their
        # first-order change is a nuisance as well, so that their uncertainty reaches
        # the geometry's instead of biasing it
        for key, value in f.nonlinear.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or key in getattr(eff, "discrete", ()):
                continue
            h = 0.01 * abs(value) if value else 0.01
            up = _columns(eff, ctx, everywhere, {**f.nonlinear, key: value + h})
            down = _columns(eff, ctx, everywhere, {**f.nonlinear, key: value - h})
            if up is not None and down is not None and up.shape == C.shape:
                D = (up - down) / (2 * h)
                if np.abs(D).max() > 1e-9 * max(np.abs(C).max(), 1e-300):
                    C = np.column_stack([C, D])
        cols.append(C)
        groups.append(ExtraGroup(f.effect, at, at + C.shape[1], eff.reverse, eff.feed_power))
        at += C.shape[1]
    return (np.column_stack(cols) if cols else None), groups


def _columns(eff, ctx, samples: Samples, nl: dict) -> np.ndarray | None:
    try:
        C, _ = eff.columns(ctx, samples, nl)
    except (ValueError, np.linalg.LinAlgError):
        return None
    C = np.asarray(C, float).reshape(ctx.n, -1)
    return C if C.shape[1] and np.isfinite(C).all() else None


def _context(plan: PlanFiles, program: str, contexts: dict | None) -> Context:
    """The program's context, built once per analysis."""
    if contexts is None:
        return build_context(plan, program)
    if program not in contexts:
        contexts[program] = build_context(plan, program)
    return contexts[program]


def _every(trace: Trace, k: int) -> Trace:
    return Trace(trace.t_s[::k], trace.delta_l_um[::k], trace.segment, trace.phase, trace.header)


#: the diagnosis of each recording reads it at 500 Hz at most (the geometry, identified
#: afterwards, reads every sample)
DIAGNOSIS = DiagnosisOptions(max_rate_hz=500.0, max_fit_samples=30_000)

#: the job the pool's workers run (set before the pool forks, so that the workers
#: share the plan, the recordings and the contexts built so far without copying them)
def analyse(plan: PlanFiles, recordings: list[tuple[str, str | None, Trace]],
            options: ModelOptions, step=lambda msg: None, note=lambda msg: None,
            jobs: int = 1, pictures: bool = False) -> tuple[dict, list]:
    """``recordings``: (label, program or None, recording); ``jobs``: worker processes
    for the per-recording stages (matching, diagnosis); ``pictures``: each recording's
    diagnosis pictures drawn where it was diagnosed.  Returns the report and the
    analysed recordings (for pictures and aligned traces)."""
    with threadpool_limits(limits=1, user_api="blas"), reusing_freed_memory():
        return _analyse(plan, recordings, options, step, note, jobs, pictures)


def _analyse(plan, recordings, options, step, note, jobs, draw=False):
    first: list[tuple[str, str, AlignedRecording, Trace]] = []
    used: dict[str, str] = {}
    contexts: dict = {}
    labels = [label for label, _, _ in recordings]
    matched = each(lambda k: match(plan, recordings[k][2], recordings[k][0], recordings[k][1],
                                    contexts),
                    labels, jobs, step, "matching and aligning {label}",
                    sizes=[float(len(trace.t_s)) for _, _, trace in recordings])
    for (label, named, trace), (rec, how) in zip(recordings, matched):
        if rec.program in used:
            raise RecordingError(f"{label}: a second recording of {rec.program} (the first: "
                                 f"{used[rec.program]}); give each program once")
        used[rec.program] = label
        first.append((label, how, rec, trace))
    # the geometry first from the recordings as aligned, so that the diagnosis looks at
    # what the geometry leaves (the effect library holds only a few kinds of geometry);
    # then the geometry again with what the diagnosis found
    step("a first estimate of the geometry")
    # (every 5th sample: this estimate only feeds the diagnosis, the final one uses all;
    # with generic shapes of what any recording may hold - lags, a drift, reversal
    # steps - as nuisances, so that it does not take them for geometry and hide them)
    generic = [dynamic_columns(_context(plan, rec.program, contexts)) for _, _, rec, _ in first]
    geo0 = identify([(plan, rec.program, _every(rec.trace, 5)) for _, _, rec, _ in first], options,
                    extra=generic, jobs=jobs)
    model0 = ErrorSet("geometry identified from the recordings", options,
                      tuple(geo0["model_state"].items()))
    def diagnosed(k):
        label, how, rec, trace = first[k]
        ctx = _context(plan, rec.program, contexts)
        d = diagnose(plan, rec.program, trace, model0, DIAGNOSIS,
                     progress=note if jobs <= 1 else None, ctx=ctx, alignment=rec.alignment)
        # the effect columns on the trajectory grid: made where the context's caches are
        # (and the pictures in the worker too: drawn one after another they took seconds)
        return d, effect_columns(plan, d, options, ctx), diagnosis_pictures(d, ctx) if draw else {}

    # the final geometry's first normal equations of a recording are made here as soon
    # as its diagnosis is back and a core is free (while the last diagnoses run): the
    # same numbers as made by identify itself
    model, _ = identification_model([plan], options)
    done: dict[int, Analysed] = {}
    extra: dict[int, tuple[np.ndarray | None, list[ExtraGroup]]] = {}
    prepared: dict = {}
    waiting: list[int] = []

    def arrived(k, result, idle):
        label, how, rec, trace = first[k]
        d, (cols, grp), pngs = result
        ctx = _context(plan, rec.program, contexts)
        done[k] = Analysed(label, rec.program, how, rec, d,
                           _on_program_time(label, rec, trace, d, ctx), ctx, pngs)
        if cols is not None and len(cols) != len(plan.trajectory(rec.program).t_s):
            cols, grp = None, []  # not on the trajectory grid: identify without them
        extra[k] = (cols, grp)
        waiting.append(k)
        while idle and waiting:
            j = waiting.pop(0)
            prepared[j] = first_gram((plan, done[j].program, done[j].trace), model, extra[j][0])

    each(diagnosed, labels, jobs, step, "diagnosing {label}",
         sizes=[float(len(rec.trace.t_s)) for _, _, rec, _ in first], arrived=arrived)
    analysed = [done[k] for k in range(len(first))]
    step("identifying the geometry with the effects found")
    geometry = identify([(plan, a.program, a.trace) for a in analysed], options,
                        extra=[extra[k][0] for k in range(len(first))],
                        groups=[extra[k][1] for k in range(len(first))], jobs=jobs,
                        prepared=prepared)
    return _report(analysed, geometry), analysed


def _on_program_time(label: str, rec: AlignedRecording, trace: Trace, d: Diagnosis,
                     ctx: Context) -> Trace:
    """The recording on program time by the diagnosis' alignment, inside the program."""
    tau = d.alignment.program_time(np.asarray(trace.t_s, float))
    inside = (tau >= 0.0) & (tau <= float(ctx.t_s[-1]))
    return Trace(tau[inside], np.asarray(trace.delta_l_um, float)[inside],
                 np.array([], dtype=object), np.array([], dtype=object),
                 {**trace.header, "program": rec.program, "source": f"aligned {label}"})


def _report(done: list[Analysed], geometry: dict) -> dict:
    from .diagnose.report import to_json

    warnings = []
    noise = max(a.aligned.noise_um for a in done)
    if poor_fit(geometry["noise_std_um"], noise):
        warnings.append(
            f"geometry and effects together leave {geometry['noise_std_um']:.2f} um RMS against "
            f"the recordings' own noise of at most {noise:.2f} um: a set-up that moved, an effect "
            f"the library lacks, or a recording of something else (see each recording's "
            f"unexplained part)")
    per = []
    across: dict[str, list] = {}
    for k, a in enumerate(done):
        dj = to_json(a.diagnosis)
        if a.diagnosis.unexplained.get("significant"):
            warnings.append(f"{a.label} ({a.program}): {a.diagnosis.unexplained['rms_um']:.2f} um "
                            f"RMS left that no effect of the library explains")
        for f in dj["findings"]:
            across.setdefault(f["effect"], []).append(
                {"recording": a.label, "program": a.program, "confidence": f["confidence"],
                 "parameters": f["parameters"], "parameter_std": f["parameter_std"],
                 "contribution_rms_um": f["contribution_rms_um"]})
        per.append({"file": a.label, "program": a.program, "matched": a.matched,
                    "first_alignment": a.aligned.as_json(), "diagnosis": dj,
                    "nuisances": geometry["nuisances"][k]})
    return {"recordings": per, "geometry": geometry, "aliasing": geometry.get("aliasing", []),
            "across_recordings": across, "warnings": warnings}


def summary_text(report: dict) -> str:
    from .identify.summary import summary_text as geometry_text

    lines = [f"Analysis of {len(report['recordings'])} recording(s)."]
    for r in report["recordings"]:
        al = r["diagnosis"]["alignment"]
        lines.append(f"  {r['file']}: {r['program']} ({r['matched']}); program starts at "
                     f"{al['offset_s']:.4f} s of the recording (+- {_ms(al['offset_std_s'])} ms), "
                     f"clock {al['clock_ppm']:+.1f} ppm (+- {_num(al['clock_std_ppm'])}), noise "
                     f"{r['diagnosis']['noise_um']:.2f} um")
    for w in report["warnings"]:
        lines.append(f"WARNING: {w}")
    lines.append("")
    lines.append("GEOMETRY (estimated together with the effects below; each effect found in a "
                 "recording is a nuisance of that recording):")
    g = dict(report["geometry"])
    g.pop("recordings", None)
    g["warnings"] = report["warnings"] and ["see the warnings above"]
    lines.append(geometry_text(g))
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
    lines.append("EFFECTS across the recordings:")
    if not report["across_recordings"]:
        lines.append("  none found beyond the set-up.")
    for eff, hits in report["across_recordings"].items():
        lines.append(f"  {eff}: " + "; ".join(
            f"{h['program']} ({h['confidence']}, {h['contribution_rms_um']:.2f} um RMS)" for h in hits))
    for r in report["recordings"]:
        lines.append("")
        lines.append(f"RECORDING {r['file']} ({r['program']}):")
        lines.append(_diagnosis_text(r["diagnosis"]))
    return "\n".join(lines).rstrip() + "\n"


def _ms(v) -> str:
    return "?" if v is None else f"{v * 1e3:.2f}"


def _num(v) -> str:
    return "?" if v is None else f"{v:.1f}"


def _diagnosis_text(d: dict) -> str:
    lines = [f"  gap RMS {d['gap']['rms_um']:.3f} um, noise {d['noise_um']:.3f} um"]
    if not d["findings"]:
        lines.append("  findings: none beyond the set-up")
    for f in d["findings"]:
        par = parameters_text(f["parameters"], f.get("parameter_std", {}))
        name = " or ".join([f["effect"], *f.get("ambiguous_with", [])])
        lines.append(f"  {f['rank']}. {name} ({f['confidence']} confidence): {par}")
        lines.append(f"     held-out RMS {f['heldout_rms_before_um']:.3f} -> "
                     f"{f['heldout_rms_after_um']:.3f} um")
        if f.get("ambiguous_with"):
            lines.append(f"     AMBIGUOUS: to separate them, {f['separate_by']}")
    u = d["unexplained"]
    verdict = "NOT explained by the library" if u["significant"] else "at the noise level"
    lines.append(f"  unexplained: RMS {u['rms_um']:.3f} um ({verdict})"
                 + (": strongest in " + ", ".join(u["where"]["segments"][:6])
                    if u["significant"] and u.get("where", {}).get("segments") else ""))
    return "\n".join(lines)


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


def file_stem(label: str) -> str:
    stem = Path(label).stem or "recording"
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in stem)[:60]
