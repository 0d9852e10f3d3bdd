"""A program's motion as a real control runs it, for recordings made like a machine's.

``perturb --control linuxcnc`` makes its recording from this motion instead of the
plan's trajectory: LinuxCNC 2.9's planner (the model of
:mod:`sdit_path.timing.linuxcnc_tp`, which gives the real control's commanded position
to 0.001 um on the samples' programs) runs the program as written for LinuxCNC, servo
period by servo period: its chords, its blends, its ramps and its corner slow-downs,
and, on a 5-axis program in the machine frame, the runs that crawl where a rotary axis
turns (1.7-1.9 times the planned time on the 5-axis sample's top layer).  The machine
then stands for each dwell as long as the program says (a real control's dwell follows
its wall clock, 17-28 ms longer on the samples; not modelled).

The result is a :class:`~sdit_path.timing.trajectory.Samples` at the servo rate, with
every sample labelled by the planned segment nearest to it along the same stretch of
motion, so that effects, truth and reports name the segments the plan named.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ConfigError
from ..machine.kinematics import Kinematics
from ..timing.trajectory import Samples, axis_values_rad

CONTROLS = ("linuxcnc",)


def control_samples(plan, program: str, control: str = "linuxcnc") -> Samples:
    """The motion of ``program`` of ``plan`` (a :class:`~sdit_path.plan.files.PlanFiles`)
    as ``control`` runs it (see the module text)."""
    if control not in CONTROLS:
        raise ConfigError("--control", f"{control!r}: expected one of {', '.join(CONTROLS)}")
    from ..timing.linuxcnc_tp import ControlLimits, simulate, stretches

    found = plan.for_controller("linuxcnc").program_text(program)
    if found is None:
        raise ConfigError("--control", "the plan has no program files to run")
    text, entry = found
    cfg = plan.config
    kin = Kinematics(cfg.machine)
    table = (entry.get("frame") or {}).get("name", "table") == "table"
    axes = ("X", "Y", "Z") if table else tuple(kin.names)
    limits = ControlLimits.from_machine(cfg.machine, axes)
    try:
        moves = stretches(text, axes)
    except ValueError as exc:
        raise ConfigError(entry["file"], f"the LinuxCNC model cannot run it: {exc}") from None
    planned = plan.trajectory(program)
    q_planned = axis_values_rad(planned, kin)
    period = limits.servo_period_s
    # the plan's stretches of motion, in order, to label the control's samples by
    moving_plan = (planned.phase != "dwell") & (planned.phase != "reposition")
    edges = np.flatnonzero(np.diff(np.r_[0, moving_plan.astype(int), 0]))
    groups = list(zip(edges[::2], edges[1::2]))
    dwell = float(cfg.test.dwell_s)
    q_parts, label_parts, still_parts = [], [], []
    first_dwell = int(round(dwell / period))
    start_q = q_planned[0]
    q_parts.append(np.repeat(start_q[None, :], first_dwell, axis=0))
    label_parts.append(np.full(first_dwell, planned.segment[0], dtype=object))
    still_parts.append(np.ones(first_dwell, bool))
    motions = [m for m in (simulate(st, limits) for st in moves) if m.moving.any()]
    if len(motions) != len(groups):
        raise ConfigError(entry["file"], f"the control moves in {len(motions)} stretches, "
                                         f"the plan in {len(groups)}")
    for sim, (a, b), st in zip(motions, groups, moves):
        moving = np.flatnonzero(sim.moving)
        pos = sim.position[moving[0]:moving[-1] + 1]
        q = _machine_values(pos, axes, kin, table, q_planned[a:b])
        ball = kin.forward(q)
        tree = cKDTree(np.asarray(planned.ball_mm[a:b], dtype=float))
        near = tree.query(ball)[1]
        q_parts.append(q)
        label_parts.append(np.asarray(planned.segment[a:b], dtype=object)[near])
        still_parts.append(np.zeros(len(q), bool))
        stand = int(round(st.dwell_after_s / period))
        if stand:
            q_parts.append(np.repeat(q[-1:], stand, axis=0))
            after = planned.segment[min(b, len(planned.segment) - 1)]
            label_parts.append(np.full(stand, after, dtype=object))
            still_parts.append(np.ones(stand, bool))
    q = np.vstack(q_parts)
    segment = np.concatenate(label_parts)
    still = np.concatenate(still_parts)
    t = np.arange(len(q)) * period
    ball = kin.forward(q)
    speed = np.r_[0.0, np.linalg.norm(np.diff(ball, axis=0), axis=1) / period]
    accel = np.gradient(speed, period)
    phase = np.where(still, "dwell", np.where(accel > 1.0, "accelerate",
                                              np.where(accel < -1.0, "decelerate", "cruise")))
    axes_out = q.copy()
    for i in kin.rotary:
        axes_out[:, i] = np.degrees(axes_out[:, i])
    names = tuple(planned.axis_names)
    order = [kin.index[n] for n in names]
    return Samples(t, ball, axes_out[:, order], segment, phase.astype(object), speed, names,
                   tuple(planned.axis_units))


def control_plan(plan, program: str, control: str = "linuxcnc") -> tuple[object, list[dict]]:
    """``plan`` with its trajectories the control's motion (:func:`control_samples`;
    nothing else read from the plan changes, and no program geometry is added on top:
    the motion is the program as written), and per stretch of motion of ``program``
    between standstills the planned and the control's duration (s)."""
    moved = plan.moved_by(control)
    return moved, run_table(plan.planned().trajectory(program), moved.trajectory(program))


def run_times(samples: Samples) -> list[tuple[str, str, float]]:
    """Every stretch of motion between standstills: its first and last segment and its
    duration (s)."""
    moving = (samples.phase != "dwell") & (samples.phase != "reposition")
    edges = np.flatnonzero(np.diff(np.r_[0, moving.astype(int), 0]))
    step = float(np.median(np.diff(samples.t_s))) if len(samples.t_s) > 1 else 0.0
    return [(str(samples.segment[a]), str(samples.segment[b - 1]), (b - a) * step)
            for a, b in zip(edges[::2], edges[1::2])]


def run_table(planned: Samples, control: Samples) -> list[dict]:
    """Per stretch of motion the planned and the control's duration (s)."""
    return [{"from": p[0], "to": p[1], "planned_s": round(p[2], 4), "control_s": round(c[2], 4)}
            for p, c in zip(run_times(planned), run_times(control))]


def _machine_values(pos: np.ndarray, axes: tuple[str, ...], kin: Kinematics, table: bool,
                    q_plan: np.ndarray) -> np.ndarray:
    """Machine axis values (mm, rad; kinematics order) of the control's positions:
    a machine-frame program gives them itself; a table-frame one gives the ball, whose
    rotary angles are the plan's at the nearest planned point (a 3-axis machine has none)."""
    if not table:
        q = np.zeros((len(pos), len(kin.names)))
        for col, name in enumerate(axes):
            rot = kin.axes[kin.index[name]].is_rotary
            q[:, kin.index[name]] = np.radians(pos[:, col]) if rot else pos[:, col]
        return q
    if kin.rotary:
        near = cKDTree(kin.forward(q_plan)).query(pos)[1]
        angles = {kin.names[i]: q_plan[near, i] for i in kin.rotary}
    else:
        angles = {}
    return kin.inverse(pos, angles)


#: a real control's dwell follows its wall clock and lasts longer than programmed: by
#: 2-4 ms on LinuxCNC 2.9 running the samples here, 17-28 ms on another configuration
DWELL_EXTRA_S = (0.002, 0.030)


def longer_dwells(plan, program: str, control: str, seed: int,
                  extra_s: tuple[float, float] = DWELL_EXTRA_S) -> tuple[object, list[float]]:
    """``plan`` with ``program``'s motion by ``control`` (as :func:`control_plan` gives
    it) whose dwells between runs each last longer than programmed by a seeded amount
    within ``extra_s``, and those amounts (ms)."""
    from ..timing.retime import Retiming

    samples = plan.trajectory(program)
    moving = (samples.phase != "dwell") & (samples.phase != "reposition")
    edges = np.flatnonzero(np.diff(np.r_[0, moving.astype(int), 0]))
    t = np.asarray(samples.t_s, float)
    starts, ends = t[edges[::2]], t[np.minimum(edges[1::2], len(t) - 1)]
    extra = np.random.default_rng([seed, 47]).uniform(*extra_s, max(len(starts) - 1, 0))
    src, dst, shift = [0.0], [0.0], 0.0
    for k, (a, b) in enumerate(zip(starts, ends)):
        if k:
            shift += float(extra[k - 1])
        src += [float(a), float(b)]
        dst += [float(a) + shift, float(b) + shift]
    src.append(float(t[-1]))
    dst.append(float(t[-1]) + shift)
    moved = plan.timed_as_recorded(program, control, Retiming(tuple(src), tuple(dst)))
    return moved, [round(float(v) * 1e3, 3) for v in extra]
