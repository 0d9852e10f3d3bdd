"""Which program a recording is of: named, or recognised from its duration and from
where it stands still (the program's dwells fall on the recording's still windows),
then aligned (start, clock rate); a recording that fits no program of the plan, or
another one better than the program named, is refused with one line."""

from __future__ import annotations

import numpy as np

from ..diagnose.fitting import noise_estimate
from ..diagnose.align import LOCAL_SCAN_EXPLAINED
from ..diagnose.recording import AlignedRecording, align_by_runs, align_recording, \
    plausible_programs
from ..diagnose.runs import match_dwells, program_runs, still_stretches
from ..errors import ConfigError, RecordingError
from ..plan.files import PlanFiles
from ..reading.trace import Trace, block_means, standstill_floor


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
    if ok.sum() < 1000:
        return None
    # on 50 ms means (a steady vibration of the structure averages out of them) against
    # the spread a standstill shows in this recording
    noise = standstill_floor(t, y, noise_estimate(y[ok], t[ok]))
    t, y, _ = block_means(t, y)
    k = np.searchsorted(t, np.arange(t[0], t[-1], _WINDOW_S))
    still = np.array([b - a >= 6 and float(np.std(y[a:b])) <= 1.15 * noise + 0.01
                      for a, b in zip(k[:-1], k[1:])], bool)
    return None if still.mean() > 0.6 else still


def _why_no_dwells(trace: Trace) -> str:
    """Why the recording's still windows cannot tell its dwells, as it is: still indeed
    (its 50 ms means spread no more than a few times its noise), or changing too slowly
    for half a second to show a motion."""
    t = np.asarray(trace.t_s, float)
    y = np.asarray(trace.delta_l_um, float)
    ok = np.isfinite(y)
    if ok.sum() < 10:
        return "the recording holds too few readings to show its dwells"
    noise = noise_estimate(y[ok], t[ok])
    _, means, _ = block_means(t, y)
    spread = float(np.std(means)) if len(means) else 0.0
    if spread <= 3.0 * noise + 0.05:
        return (f"the recording stands still nearly throughout (its 50 ms means spread "
                f"{spread:.2f} um against {noise:.2f} um of noise: its dwells say nothing); "
                f"recognised by its alignment alone")
    return (f"the recording's dwells do not show: it changes by less than its noise within "
            f"half a second nearly throughout, though it spreads {spread:.2f} um over the "
            f"recording; recognised by its alignment alone")


def standstill_spread(trace: Trace) -> float:
    """The recording's spread (um RMS) where it stands still (its 0.5 s windows that
    :func:`still_windows` finds still): its noise and any steady vibration; its noise
    where it stands still nearly throughout or nowhere."""
    t = np.asarray(trace.t_s, float)
    y = np.asarray(trace.delta_l_um, float)
    still = still_windows(trace)
    ok = np.isfinite(y)
    if still is None or not still.any():
        # still nearly throughout (or nowhere): its noise is all it shows standing
        return noise_estimate(y[ok], t[ok]) if ok.sum() > 10 else 0.0
    t, y = t[ok], y[ok]
    k = np.searchsorted(t, np.arange(t[0], t[-1], _WINDOW_S))
    spread = [float(np.std(y[a:b])) for (a, b), s in zip(zip(k[:-1], k[1:]), still) if s and b > a]
    return float(np.median(spread)) if spread else 0.0


def _beyond(rms_um: float, floor_um: float) -> float:
    """What a residual of ``rms_um`` leaves beyond a floor (in quadrature; at least a
    hundredth of the floor, so that two residuals at the floor read alike)."""
    return float(np.sqrt(max(rms_um ** 2 - floor_um ** 2, (0.01 * floor_um) ** 2, 1e-12)))


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


#: a recording's own run timing replaces the plan's where its alignment leaves at most
#: this share of the residual the plan's timing leaves
RUNS_BETTER = 0.95
#: ... or, where the plan's timing explains the recording to its noise but places its
#: start worse than :data:`TIMED_S`, where it leaves at most this much more (both at
#: the noise: the runs' own timing is the better founded)
RUNS_ALIKE = 0.02
#: a start known this well (s, one standard uncertainty) by the plan's timing needs no
#: run-by-run timing when that timing explains the recording to its noise
TIMED_S = 0.02
#: programs whose dwells match the recording's still stretches at most this much worse
#: than the best one's are aligned run by run (the cost of :func:`match_dwells`)
DWELL_COST_MARGIN = 20.0


def match(plan: PlanFiles, trace: Trace, label: str, named: str | None = None
          ) -> tuple[AlignedRecording, str]:
    """The recording aligned to its program, and how the program was chosen.  Refuses
    (one line) a recording that fits no program of the plan, or fits another one better
    than the program named.

    The plan's timing first (a start and a clock rate); where that leaves more than the
    recording's noise or places its start no better than :data:`TIMED_S`, or is
    refused, and the recording stands still where it dwells,
    the recording's own timing run by run (:func:`align_by_runs`): from the plan's time
    law and, unless the controller was named, from that of every control the plan wrote
    programs for whose planner is modelled (LinuxCNC); the one that leaves the least
    is kept when it leaves clearly less than the plan's timing."""
    try:
        rec, how = _match_planned(plan, trace, label, named)
        refusal = None
    except RecordingError as exc:
        rec, how, refusal = None, "", exc
    # explained: to the recording's noise, or to the spread it shows standing still
    # where more (a steady vibration, which no timing explains)
    floor = standstill_spread(trace)
    explained = rec is not None and rec.alignment.rms_um <= LOCAL_SCAN_EXPLAINED * max(
        rec.noise_um, floor)
    if explained and rec.alignment.offset_std_s <= TIMED_S:
        return rec, how
    laws = _time_laws(plan)
    # (program, law, anchor) to try: a control's own time law from its own timing of
    # the whole program (each run as long as that law says, every dwell as long as the
    # reading says: a control's dwell follows its clock); where the plan's timing does
    # not explain the recording to its noise, the plan's law from the recording's still
    # stretches matched to the dwells, every run as long as the reading says (a quiet
    # reading holds still inside its runs too: where the plan's timing explains it, the
    # stretches are not needed and not trusted)
    trials = []
    dwelled = None if explained else ([named] if named else _dwell_candidates(plan, trace))
    for law in laws:
        if law is None:
            if not explained:
                trials += [(p, None, None) for p in dwelled]
            continue
        # a control's law: its own timing of the whole program (start and clock) first,
        # of the program the plan's timing or the dwells found, then run by run from it
        moved = plan.planned().moved_by(law)
        for program in ([rec.program] if explained else
                        list(dict.fromkeys([*dwelled, *([rec.program] if rec else [])]))):
            anchor = _law_alignment(moved, program, trace, label)
            if anchor is None and rec is not None and rec.program == program:
                anchor = rec.alignment
            if anchor is not None:
                trials.append((program, law, anchor))
    timed, refusals, anchored = [], [], set()
    for program, motion, anchor in trials:
        try:
            timed.append(align_by_runs(plan, program, trace, label, motion, anchor))
        except RecordingError as exc:
            refusals.append(str(exc).removeprefix(f"{label}: "))
            continue
        if anchor is not None:
            anchored.add(id(timed[-1]))
    if not timed:
        if rec is None:
            raise RecordingError(f"{refusal}" + (f"; run by run: {refusals[0]}" if refusals else ""))
        return rec, how
    # per program the best fit; a control's law (each run as long as its planner says)
    # before the plan's law with every run's duration free, unless that fits clearly
    # better (a free run takes up what the model lacks, and states its time too well)
    by_program: dict[str, AlignedRecording] = {}
    for r in sorted(timed, key=lambda r: r.alignment.rms_um
                    * (1.0 if r.motion is not None else 1.0 / RUNS_BETTER)):
        by_program.setdefault(r.program, r)
    ranked = sorted(by_program.values(), key=lambda r: r.alignment.rms_um)
    best = ranked[0]
    # a control's law from where the plan's timing puts the runs, each run as long as
    # that law says, is taken where it fits as well; the recording's own stretches,
    # where they fit clearly better
    alike = explained or id(best) in anchored
    if rec is not None and best.alignment.rms_um > (1.0 + RUNS_ALIKE if alike else RUNS_BETTER) \
            * rec.alignment.rms_um:
        return rec, how
    if len(ranked) > 1 and _beyond(ranked[1].alignment.rms_um, floor) \
            < 1.25 * _beyond(best.alignment.rms_um, floor):
        raise RecordingError(
            f"{label}: fits {best.program} and {ranked[1].program} alike run by run (alignment "
            f"residual {best.alignment.rms_um:.2f} and {ranked[1].alignment.rms_um:.2f} um); name "
            f"its program: --measured {best.program}={label}")
    law = "the plan's time law" if best.motion is None else f"{best.motion}'s motion"
    runs = f"timed run by run ({law}, {len(best.runs.planned)} runs between its dwells)"
    plan_said = (f"; the plan's timing left {rec.alignment.rms_um:.2f} um" if rec is not None
                 else f"; the plan's timing: {str(refusal).removeprefix(f'{label}: ')}")
    first = "named" if named else f"recognised by its dwells; alignment residual " \
                                  f"{best.alignment.rms_um:.2f} um"
    return best, f"{first}; {runs}{plan_said}"


def _law_alignment(moved: PlanFiles, program: str, trace: Trace, label: str):
    """The alignment (start, clock) of ``program`` of ``moved`` (a plan moved by a
    control's planner), or None where that is refused."""
    try:
        return align_recording(moved, program, trace, label).alignment
    except RecordingError:
        return None


def _time_laws(plan: PlanFiles) -> list[str | None]:
    """The time laws a recording's runs are re-timed from: the plan's trajectories as
    they are read (a named controller's motion included), and, unless a controller was
    named, the motion of LinuxCNC where the plan wrote programs for it and timed them
    otherwise."""
    if plan.controller is not None:
        return [plan.motion]
    laws: list[str | None] = [None]
    if "linuxcnc" in plan.controllers and plan.config.timing.control != "linuxcnc":
        laws.append("linuxcnc")
    return laws


def _dwell_candidates(plan: PlanFiles, trace: Trace) -> list[str]:
    """The programs whose dwells the recording's still stretches fit (in order, a run
    taking half to four times its planned time) nearly as well as the best one's (none
    where the recording holds fewer than three still stretches: nothing to time by)."""
    t_m = np.asarray(trace.t_s, float)
    y = np.asarray(trace.delta_l_um, float)
    ok = np.isfinite(y)
    noise = noise_estimate(y[ok], t_m[ok])
    dwell = float(plan.config.test.dwell_s)
    stretches = still_stretches(t_m, y, noise, 0.3 * dwell)
    if len(stretches) < 3:
        return []
    span = float(t_m[-1] - t_m[0])
    costs = {}
    for program in plan.program_names:
        traj = plan.trajectory(program)
        if span < 0.5 * float(traj.t_s[-1]):
            continue
        runs = program_runs(traj)
        found = match_dwells(runs, stretches, dwell)
        if found is not None:
            costs[program] = found[0]
    if not costs:
        return []
    best = min(costs.values())
    return sorted((p for p, c in costs.items() if c <= best + DWELL_COST_MARGIN),
                  key=costs.get)[:2]


def _match_planned(plan: PlanFiles, trace: Trace, label: str, named: str | None = None
                   ) -> tuple[AlignedRecording, str]:
    """:func:`match` with the plan's timing alone."""
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
        if scores else _why_no_dwells(trace))
    # a recording of its program scores well above DWELL_MATCH, another program of the
    # same plan about as much at most, another feed or plan far less: below DWELL_MATCH
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
            results[prog] = align_recording(plan, prog, trace, label)
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
    # told apart by what each leaves beyond the recording's own floor (its spread where
    # it stands still: the noise and a steady vibration, which no program explains)
    floor = standstill_spread(trace)
    if len(ranked) > 1 and _beyond(results[ranked[1]].alignment.rms_um, floor) \
            < 1.25 * _beyond(results[best].alignment.rms_um, floor):
        raise RecordingError(
            f"{label}: fits {best} and {ranked[1]} alike (alignment residual "
            f"{results[best].alignment.rms_um:.2f} and {results[ranked[1]].alignment.rms_um:.2f} um); "
            f"name its program: --measured {best}={label}")
    return results[best], (f"recognised: {seen}; alignment residual {results[best].alignment.rms_um:.2f} um"
                           + "".join(f", {p} {results[p].alignment.rms_um:.2f}" for p in ranked[1:]))
