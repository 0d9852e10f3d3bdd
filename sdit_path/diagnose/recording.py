"""Matching a recording to its program and aligning it: the one way every command that
reads a measured recording (``identify``, ``diagnose``) puts it on its program's time.

A ballbar recording has its own clock: it starts seconds before the program, its rate
is off by up to a few hundred ppm, and nothing in it says which program it recorded.
Its samples are put on program time by the alignment the diagnosis uses (a global
search over start and clock rate with a linear model of what any trace may hold:
set-up, lag, reversal steps, pose-locked geometry).  A recording whose duration does
not fit its program is refused; a fit (of the analysis that follows) whose residual is
far above the recording's own noise (:func:`poor_fit`) is not a measurement of this
program as planned, and its numbers are not printed as determined without saying so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import RecordingError
from ..plan.files import PlanFiles
from ..reading.trace import Trace, block_means, standstill_floor
from .align import Alignment, AlignmentError, align, check_span
from ..reading.context import build_context
from .columns import expected_reading
from .effects.generic import alignment_blocks, alignment_columns
from .fitting import noise_estimate
from .timing import widened
from .runs import RunTiming, anchored_timing, first_timing, fit_runs, match_dwells, \
    program_runs, still_stretches

#: a residual this many times the recording's own noise (and 0.5 um above it) is not
#: this program's recording as planned, or holds what the alignment model cannot
POOR_FIT = 3.0


@dataclass(frozen=True, slots=True)
class AlignedRecording:
    """A recording on its program's time: ``trace`` holds the samples inside the
    program (program time, readings as recorded), ``alignment`` how it was put there
    (its residual is that of the alignment's model, which lacks most of the geometry:
    whether the recording fits is judged on the fit of the analysis that follows)."""

    program: str
    alignment: Alignment
    noise_um: float
    trace: Trace
    warning: str | None
    #: when the recording's own timing was taken run by run (:mod:`.runs`): when each
    #: run began and ended, and the control whose motion it re-timed (None: the plan's)
    runs: RunTiming | None = None
    motion: str | None = None

    def retimed(self, plan: PlanFiles) -> PlanFiles:
        """``plan`` with this recording's program timed as the recording showed (as it
        is when the plan's timing was kept)."""
        if self.runs is None:
            return plan
        base = plan.planned() if self.motion is None else plan.planned().moved_by(self.motion)
        end = float(base.trajectory(self.program).t_s[-1])
        return plan.timed_as_recorded(self.program, self.motion, self.runs.retiming(end))

    def as_json(self) -> dict:
        a = self.alignment
        return {"program": self.program, "offset_s": a.offset_s, "offset_std_s": a.offset_std_s,
                "clock_ppm": a.clock_ppm, "clock_std_ppm": a.clock_std_ppm,
                "residual_rms_um": a.rms_um, "noise_um": self.noise_um,
                "samples_in_program": int(np.isfinite(self.trace.delta_l_um).sum()),
                "warning": self.warning}


def poor_fit(residual_um: float, noise_um: float) -> bool:
    """A model that leaves this much is not describing the recording: another program,
    feed or plan, a set-up that moved, or an effect the model lacks."""
    return residual_um > max(POOR_FIT * noise_um, noise_um + 0.5)


#: share of the program's dwells at which an aligned recording must stand still
STILL_SHARE = 0.75

#: the instrument's clock error the alignment searches (the documented contract): an
#: alignment that ends at this edge wanted more, which no instrument in it needs
CLOCK_LIMIT_PPM = 200.0


def stillness(t_s: np.ndarray, phase: np.ndarray, t_m: np.ndarray, y: np.ndarray,
              al: Alignment, noise_um: float, margin_s: float = 0.3) -> tuple[int, int, float]:
    """Does the recording stand still where the program dwells?  (dwells where it
    does, dwells, share of equally long windows in the middle of the motion between
    dwells where it stands still as well).

    Nothing in a bar reading says that the machine moves, except that a real set-up
    is never perfect: the few microns of centring residual every mounting leaves make
    the reading wander while the ball moves over the sphere, and hold it still while
    the program dwells at a node.  A recording of another program, feed or plan,
    aligned as well as it goes, does not stand still at this program's dwells.  When
    the reading is still during much of the motion as well (a slow feed, a small set-up
    offset), a real recording is still at the dwells all the more: the dwells decide
    either way (the share in the motion is returned for the caller to see).  A dwell
    counts as still where its second half is: a machine that rings after the stop is
    still recording its program; and it is judged on 50 ms means against the spread a
    standstill shows in this recording, so that a steady vibration does not hide it."""
    dwell = (phase == "dwell").astype(np.int8)
    edge = np.diff(np.r_[0, dwell, 0])
    starts, ends = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1) - 1
    spans = [(t_s[a] + margin_s, t_s[b] - margin_s) for a, b in zip(starts, ends)
             if t_s[b] - t_s[a] > 2 * margin_s + 0.2]
    if not spans:
        return 0, 0, 0.0
    width = float(np.median([b - a for a, b in spans]))
    motion = [(0.5 * (b0 + a1) - width / 2, 0.5 * (b0 + a1) + width / 2)
              for (_, b0), (a1, _) in zip(spans[:-1], spans[1:]) if a1 - b0 > width + 2 * margin_s]
    # judged on 50 ms means: a steady vibration of the structure averages out
    limit = 1.5 * standstill_floor(t_m, y, noise_um) + 0.05
    t_ok, y_ok, _ = block_means(t_m, y)

    def still(a: float, b: float) -> bool | None:
        lo, hi = np.searchsorted(t_ok, al.measured_time(np.array([a, b])))
        if hi - lo < 6:
            return None
        return bool(np.std(y_ok[lo:hi]) <= limit)

    # a dwell judged on its second half: a machine that rings after the stop (a mode
    # the deceleration excites) has settled by then, and is still this program
    d = [v for v in (still(0.5 * (a + b), b) for a, b in spans) if v is not None]
    m = [v for v in (still(a, b) for a, b in motion) if v is not None]
    return int(sum(d)), len(d), (float(np.mean(m)) if m else 0.0)


def _unfit(plan: PlanFiles, program: str, trace: Trace, ctx=None) -> bool:
    span = float(trace.t_s[-1] - trace.t_s[0]) if len(trace.t_s) > 1 else 0.0
    try:
        check_span(span, float((ctx or plan.trajectory(program)).t_s[-1]))
    except AlignmentError:
        return True
    return False


def plausible_programs(plan: PlanFiles, trace: Trace) -> list[tuple[str, str]]:
    """(program, why not) for every program of the plan; ``why not`` is empty when the
    recording's duration admits it."""
    span = float(trace.t_s[-1] - trace.t_s[0]) if len(trace.t_s) > 1 else 0.0
    out = []
    for prog in plan.program_names:
        dur = float(plan.trajectory(prog).t_s[-1])
        try:
            check_span(span, dur)
            out.append((prog, ""))
        except AlignmentError:
            how = "shorter than the program" if span < dur else "far longer than the program"
            out.append((prog, f"{prog} lasts {dur:.1f} s, the recording {span:.1f} s ({how})"))
    return out


def align_recording(plan: PlanFiles, program: str, trace: Trace, label: str,
                    ctx=None) -> AlignedRecording:
    """Align ``trace`` (a recording of ``program``; ``label`` names it in messages) to
    its program (``ctx``: its context, if the caller has it).  Refuses (RecordingError,
    one line) a recording whose duration does not fit the program, naming the programs
    whose durations would."""
    # the program's own duration first (every program's trajectory is read only to
    # name the others in a refusal: a control's motion of each is minutes of work)
    if _unfit(plan, program, trace, ctx):
        fits = plausible_programs(plan, trace)
        why = dict(fits)
        others = [p for p, w in fits if not w]
        raise RecordingError(
            f"{label}: not a recording of {program}: {why[program]}"
            + (f"; its duration fits {', '.join(others)}" if others else
               "; it fits no program of this plan (another plan, another feed?)"))
    ctx = ctx or build_context(plan, program)
    expected = expected_reading(plan, ctx, None)
    t_m = np.asarray(trace.t_s, float)
    y = np.asarray(trace.delta_l_um, float)
    ok = np.isfinite(y)
    noise = noise_estimate(y[ok], t_m[ok])
    try:
        al = align(ctx, expected, t_m, y, ppm_limit=CLOCK_LIMIT_PPM,
                   extra=lambda: alignment_blocks(plan, ctx), noise_um=noise)
    except AlignmentError as exc:
        raise RecordingError(f"{label}: {exc}") from None
    tau = al.program_time(t_m)
    inside = (tau >= 0.0) & (tau <= float(ctx.t_s[-1]))
    still, dwells, moving_still = stillness(ctx.t_s, ctx.phase, t_m, y,
                                            al, noise)
    # a recording quiet in most of the motion as well (a slow feed, a small set-up) is
    # not judged by its dwells alone: a genuine one leaves some of its dwells not still
    # (hard cases: blind-bad-SDIT_C-s1-9, blind-bad-SDIT_C-s1-47); with a model that fits
    # far worse than the noise and two dwells or more not still it is a mismatch (another
    # plan of the same program names, or the layer at another feed, aligned as well as
    # it goes, keeps most of the dwells still)
    misfit = poor_fit(al.rms_um, noise) and still <= dwells - 2
    if dwells and ((moving_still <= 0.5 and still < STILL_SHARE * dwells) or misfit):
        raise RecordingError(
            f"{label}: does not match {program}: aligned as well as it goes (start "
            f"{al.offset_s:.2f} s, clock {al.clock_ppm:+.0f} ppm), only {still} of the program's "
            f"{dwells} dwells fall where the recording stands still"
            + (f" and it leaves {al.rms_um:.2f} um against {noise:.2f} um of noise" if misfit else "")
            + "; a recording of another program, feed or plan?")
    # quiet everywhere (a set-up centred to a micron), the dwells cannot tell: a recording
    # of another feed then aligns nowhere - its clock undetermined over more than the
    # whole contract, many times its noise left - where a recording of the program
    # leaves its noise at a clock known to tens of ppm
    if al.clock_std_ppm >= CLOCK_LIMIT_PPM and poor_fit(al.rms_um, noise):
        raise RecordingError(
            f"{label}: does not match {program}: no timing fits it (clock {al.clock_ppm:+.0f} "
            f"+- {al.clock_std_ppm:.0f} ppm, start {al.offset_s:.2f} s) and the alignment leaves "
            f"{al.rms_um:.2f} um against {noise:.2f} um of noise; a recording of another program, "
            f"feed or plan, or of a set-up that moved during it?")
    # at the clock's limit with a fit at the noise is a weak timing, not a mismatch: a
    # clean recording's first alignment may end there (hard case: blind-bad-SDIT_C-s1-0)
    if abs(al.clock_ppm) >= CLOCK_LIMIT_PPM * (1.0 - 1e-6) and poor_fit(al.rms_um, noise):
        raise RecordingError(
            f"{label}: does not match {program}: its best alignment needs the clock at the "
            f"limit of the search ({al.clock_ppm:+.0f} ppm; instruments keep within "
            f"+-{CLOCK_LIMIT_PPM:.0f} ppm), leaving {al.rms_um:.2f} um against {noise:.2f} um of "
            f"noise; a recording of another program, feed or plan?")
    header = {**trace.header, "program": program, "source": "aligned recording"}
    aligned = Trace(tau[inside], y[inside], np.array([], dtype=object),
                    np.array([], dtype=object), header)
    if not math.isfinite(al.rms_um):
        raise RecordingError(f"{label}: the alignment failed (no finite residual)")
    return AlignedRecording(program, al, noise, aligned, None)


#: each run keeps the duration a control's own planner gives it (LinuxCNC's, which
#: gives the real control's motion to a servo period) to this share (one standard
#: uncertainty): only the dwells, which follow the control's wall clock, are left to
#: the reading (a quiet reading must not stretch a run by seconds to fit its noise)
ANCHORED_LAW = 0.002

#: a recording whose runs all take this many times their planned time or more (or this
#: share of it or less), alike, ran at another feed: its runs are not re-timed
FEED_RATIO = 1.3


def align_by_runs(plan: PlanFiles, program: str, trace: Trace, label: str,
                  motion: str | None = None, anchor: Alignment | None = None
                  ) -> AlignedRecording:
    """``trace`` aligned to ``program`` run by run (:mod:`.runs`): the recording's still
    stretches matched to the program's dwells, every run re-timed between them and
    placed by the reading, then the whole aligned as :func:`align_recording` does.
    ``motion``: the control whose motion of the program is re-timed (None: the plan's
    trajectory).  ``anchor``: an alignment of the plan's own trajectory that explains the
    recording; the runs then start where it puts them (a recording whose reading holds
    still for seconds inside its runs has more still stretches than dwells).  Refuses
    (one line) a recording whose still stretches do not fit the program's dwells, or
    whose runs all took alike longer or shorter (another feed)."""
    base = plan.planned() if motion is None else plan.planned().moved_by(motion)
    if plan.controller:
        base = replace(base, controller=plan.controller)
    traj = base.trajectory(program)
    t_m = np.asarray(trace.t_s, float)
    y = np.asarray(trace.delta_l_um, float)
    ok = np.isfinite(y)
    noise = noise_estimate(y[ok], t_m[ok])
    dwell = float(plan.config.test.dwell_s)
    runs = program_runs(traj)
    if anchor is not None:
        # the base's runs from the anchor's place of the plan's first run
        own = program_runs(plan.trajectory(program))
        rate = 1.0 + anchor.clock_ppm * 1e-6
        first = float(anchor.measured_time(np.array([own[0][0]]))[0])
        timing = anchored_timing(runs, first - runs[0][0] * rate, rate)
    else:
        timing = _stretch_timing(runs, t_m, y, noise, dwell, program, label)
    end = float(traj.t_s[-1])
    bctx = build_context(base, program)
    X = pose_columns(base, bctx)
    # a control's own planner gives each run's duration (a plan timed by LinuxCNC's
    # planner too); the plan's time law, for a control of unknown rules, does not
    # (unless anchored)
    planner = motion is not None or plan.config.timing.control == "linuxcnc"
    prior = ANCHORED_LAW if planner or anchor is not None else None
    timing, _ = fit_runs(timing, bctx.t_s, X, t_m, y, dwell, prior)
    del bctx, X
    retimed = plan.timed_as_recorded(program, motion, timing.retiming(end))
    rec = align_recording(retimed, program, trace, label, build_context(retimed, program))
    # the program starts a planned first dwell before its first run: as well known as
    # the reading places that run's start (the alignment on the re-timed trajectory is
    # consistent with the timing by construction, and states far less)
    al = widened(rec.alignment, (timing.std_s[0][0], 0.0),
                 "the first run's start, as the reading places it")
    return replace(rec, alignment=al, runs=timing, motion=motion)


def pose_columns(plan: PlanFiles, ctx) -> np.ndarray:
    """``(n, m)``: what the reading holds as a function of the pose alone (the expected
    reading, the set-up: a constant and the bar direction, its drift, and the
    geometry's pose blocks), on ``ctx``'s grid: the model a time law is fitted with.
    Nothing that follows the time law (a lag, an acceleration) and nothing with a step
    (a reversal, the start of motion): a fitted step pins a run's start where noise put
    it."""
    expected = expected_reading(plan, ctx, None)
    # a drift of the set-up is slow in time (a thermal drift): left out, a time law
    # fitted without it stretches the runs to follow it
    cols = [np.ones(ctx.n), ctx.u[:, 0], ctx.u[:, 1], ctx.u[:, 2],
            ctx.u_bed * (ctx.t_s / 3600.0)[:, None], alignment_columns(plan, ctx, pose_only=True)]
    if np.ptp(expected) > 1e-3:
        cols.insert(0, expected)
    X = np.column_stack(cols)
    keep = np.ptp(X, axis=0) > 1e-9
    keep[0] = True
    return X[:, keep]


def _stretch_timing(runs, t_m: np.ndarray, y: np.ndarray, noise: float, dwell: float,
                    program: str, label: str) -> RunTiming:
    """The runs placed by the recording's still stretches matched to the program's
    dwells; refuses a recording whose stretches fit no order of them, or whose runs all
    took alike longer or shorter (another feed)."""
    stretches = still_stretches(t_m, y, noise, 0.3 * dwell)
    found = match_dwells(runs, stretches, dwell)
    timing = first_timing(runs, stretches, found[1], dwell) if found is not None else None
    if timing is None:
        raise RecordingError(f"{label}: not a recording of {program}: its {len(stretches)} still "
                             f"stretches do not fit the program's {len(runs) + 1} dwells in order")
    ratios = np.array([m / p for p, m, _ in timing.durations() if p > 0])
    told = np.array([a and b for a, b in timing.told])
    if told.sum() >= 3:
        r = ratios[told]
        common = float(np.median(r))
        if (common >= FEED_RATIO or common <= 1 / FEED_RATIO) and np.all(np.abs(r / common - 1) < 0.1):
            raise RecordingError(
                f"{label}: not a recording of {program} as planned: every run took {common:.2f} "
                f"times its planned time: a recording at another feed or with a feed override? "
                f"(plan at the feed that was run)")
    return timing
