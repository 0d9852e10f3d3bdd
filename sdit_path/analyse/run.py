"""From real recordings to one answer: ``sdit-path analyse``.

Every recording is matched to its program (:mod:`.matching`) and aligned; each is
diagnosed (the effect library, the geometry estimated with it); then the geometry is
identified from all recordings together with every effect the diagnosis found as a
nuisance of its recording, estimated with the geometry and eliminated with the set-up,
so that a servo mismatch is not read as squareness and a drift not as a scale error.
Where an effect and the geometry share a direction in the data at hand, the result says
by how much and which second run (reverse direction, half the feed) would separate them,
computed on the same poses.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
from threadpoolctl import threadpool_limits

from ..diagnose import Diagnosis, diagnose
from ..diagnose import Options as DiagnosisOptions
from ..diagnose.effects import EFFECTS, Samples, library
from ..diagnose.effects.generic import dynamic_columns
from ..diagnose.recording import CLOCK_LIMIT_PPM, AlignedRecording, poor_fit
from ..errormodel.errorset import ErrorSet
from ..errormodel.model import ModelOptions
from ..errors import RecordingError
from ..heap import release_freed_memory, reusing_freed_memory
from ..identify.identify import ExtraGroup, first_gram, identification_model, identify
from ..identify.results import Identification
from ..parallel import each, jobs_within
from ..plan.files import PlanFiles
from ..reading.context import Context, build_context
from ..reading.trace import Trace
from .matching import match
from .results import Analysed, AnalysisResult


def _nuisance_effects(options: ModelOptions) -> set[str]:
    """The effects the identification's model holds itself (the set-up, and geometry it
    models): their findings are not nuisances of the geometry."""
    return {e.name for e in EFFECTS if e.covered_by(options)}


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


def _every(trace: Trace, k: int) -> Trace:
    return Trace(trace.t_s[::k], trace.delta_l_um[::k], trace.segment, trace.phase, trace.header)


#: the diagnosis of each recording reads it at 500 Hz at most (the geometry, identified
#: afterwards, reads every sample)
DIAGNOSIS = DiagnosisOptions(max_rate_hz=500.0, max_fit_samples=30_000)

#: what matching or diagnosing one recording takes beside the main process, per second
#: of its program (a 1 kHz trajectory: its context, the alignment's columns, the
#: selection's candidates; the default sample's layers took 1.4 to 1.9 MB a second, and
#: the main process gathers the results and the first geometry meanwhile)
WORKER_MB_PER_S = 2.8


def analyse(plan: PlanFiles, recordings: list[tuple[str, str | None, Trace]],
            options: ModelOptions, step=lambda msg: None, note=lambda msg: None,
            jobs: int = 1,
            draw: Callable[[Diagnosis, Context], Mapping[str, bytes]] | None = None,
            memory_mb: float | None = None) -> AnalysisResult:
    """``recordings``: (label, program or None, recording); ``jobs``: worker processes
    for the per-recording stages (matching, diagnosis), as many as ``memory_mb`` (all
    processes together; None: no bound) allows; ``draw``: what draws a diagnosis'
    pictures (``sdit_path.reports.diagnosis.pictures``), run where each recording was
    diagnosed (drawn one after another they take seconds), or None."""
    longest_s = max((float(np.nanmax(trace.t_s) - np.nanmin(trace.t_s))
                     for _, _, trace in recordings if len(trace.t_s)), default=0.0)
    with threadpool_limits(limits=1, user_api="blas"), reusing_freed_memory():
        jobs = jobs_within(memory_mb, WORKER_MB_PER_S * longest_s, jobs)
        return _analyse(plan, recordings, options, step, note, jobs, draw)


def _analyse(plan, recordings, options, step, note, jobs, draw):
    # each program's context (a hundred MB at 1 kHz, built in a second) is built where
    # it is read and let go there: kept for the whole analysis, five of them and their
    # caches held most of its memory
    first: list[tuple[str, str, AlignedRecording, Trace]] = []
    used: dict[str, str] = {}
    labels = [label for label, _, _ in recordings]

    def matched_one(k):
        found = match(plan, recordings[k][2], recordings[k][0], recordings[k][1])
        release_freed_memory()
        return found

    matched = each(matched_one, labels, jobs, step, "matching and aligning {label}",
                   sizes=[float(len(trace.t_s)) for _, _, trace in recordings])
    for (label, named, trace), (rec, how) in zip(recordings, matched):
        if rec.program in used:
            raise RecordingError(f"{label}: a second recording of {rec.program} (the first: "
                                 f"{used[rec.program]}); give each program once")
        used[rec.program] = label
        first.append((label, how, rec, trace))
    # recordings timed run by run: their programs' trajectories re-timed as they showed
    for _, _, rec, _ in first:
        if rec.runs is not None:
            plan = rec.retimed(plan)
    # the geometry first from the recordings as aligned, so that the diagnosis looks at
    # what the geometry leaves (the effect library holds only a few kinds of geometry);
    # then the geometry again with what the diagnosis found
    step("a first estimate of the geometry")
    # (every 5th sample: this estimate only feeds the diagnosis, the final one uses all;
    # with generic shapes of what any recording may hold - lags, a drift, reversal
    # steps - as nuisances, so that it does not take them for geometry and hide them)
    generic = [dynamic_columns(build_context(plan, rec.program)) for _, _, rec, _ in first]
    geo0 = identify([(plan, rec.program, _every(rec.trace, 5)) for _, _, rec, _ in first], options,
                    extra=generic, jobs=jobs)
    del generic
    plan.let_go()
    release_freed_memory()
    model0 = ErrorSet("geometry identified from the recordings", options,
                      tuple(geo0.model_state.items()))

    def diagnosed(k):
        label, how, rec, trace = first[k]
        ctx = build_context(plan, rec.program)
        d = diagnose(plan, rec.program, trace, model0, DIAGNOSIS,
                     progress=note if jobs <= 1 else None, ctx=ctx, alignment=rec.alignment)
        # the effect columns on the trajectory grid: made where the context's caches are
        # (and the pictures in the worker too: drawn one after another they take seconds)
        out = (d, effect_columns(plan, d, options, ctx), draw(d, ctx) if draw else {},
               (ctx.n, float(ctx.t_s[-1])))
        del ctx
        plan.let_go()
        release_freed_memory()
        return out

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
        d, (cols, grp), pngs, (n, end_s) = result
        done[k] = Analysed(label, rec.program, how, rec, d,
                           _on_program_time(label, rec, trace, d, end_s), pngs)
        if cols is not None and len(cols) != n:
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
    return _result(analysed, geometry, _timing(plan, analysed))


def _on_program_time(label: str, rec: AlignedRecording, trace: Trace, d: Diagnosis,
                     end_s: float) -> Trace:
    """The recording on program time by the diagnosis' alignment, inside the program
    (which ends at ``end_s``)."""
    tau = d.alignment.program_time(np.asarray(trace.t_s, float))
    inside = (tau >= 0.0) & (tau <= end_s)
    return Trace(tau[inside], np.asarray(trace.delta_l_um, float)[inside],
                 np.array([], dtype=object), np.array([], dtype=object),
                 {**trace.header, "program": rec.program, "source": f"aligned {label}"})


def _timing(plan: PlanFiles, done: list[Analysed]) -> tuple[dict, ...]:
    """Per recording, whose timing its program was read with: the plan's, the control's
    own (LinuxCNC's planner on a plan timed by our model), or the recording's own run by
    run, then with every run's planned and measured duration (s, and its standard
    uncertainty where the recording measured it)."""
    out = []
    for a in done:
        runs = a.aligned.runs
        if runs is not None:
            own = None
            if a.aligned.motion is not None:
                from ..diagnose.runs import program_runs

                own = [b - s for s, b, _, _ in program_runs(plan.planned().trajectory(a.program))]
            out.append({"model": "recording", "from": a.aligned.motion or "plan",
                        "placed_std_s": round(runs.placed_std_s(), 4),
                        "runs": runs.as_table(own)})
        elif plan.motion_of(a.program) is not None:
            from ..plan.control_motion import run_table

            out.append({"model": plan.motion_of(a.program),
                        "runs": run_table(plan.planned().trajectory(a.program),
                                          plan.trajectory(a.program))})
        else:
            out.append({"model": "plan"})
    return tuple(out)


def _result(done: list[Analysed], geometry: Identification,
            timing: tuple[dict, ...] = ()) -> AnalysisResult:
    """The analysis, with a warning where geometry and effects leave more than the
    recordings' noise and one per recording whose rest no effect explains."""
    warnings = []
    noise = max(a.aligned.noise_um for a in done)
    if poor_fit(geometry.noise_std_um, noise):
        warnings.append(
            f"geometry and effects together leave {geometry.noise_std_um:.2f} um RMS against "
            f"the recordings' own noise of at most {noise:.2f} um: a set-up that moved, an effect "
            f"the library lacks, or a recording of something else (see each recording's "
            f"unexplained part)")
    for a in done:
        al = a.diagnosis.alignment
        if a.aligned.runs is None and abs(al.clock_ppm) > CLOCK_LIMIT_PPM * (1.0 + 1e-6):
            # a clock beyond the contract is never a result: the timing is not established
            warnings.append(f"{a.label} ({a.program}): its alignment needs the clock at "
                            f"{al.clock_ppm:+.1f} ppm, beyond the +-{CLOCK_LIMIT_PPM:.0f} ppm "
                            f"instruments keep: its timing is not established, and what is read "
                            f"from it is what the model makes of it")
        if a.diagnosis.unexplained.get("significant"):
            warnings.append(f"{a.label} ({a.program}): {a.diagnosis.unexplained['rms_um']:.2f} um "
                            f"RMS left that no effect of the library explains")
    return AnalysisResult(tuple(done), geometry, tuple(warnings), timing)
