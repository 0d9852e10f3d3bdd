"""What the diagnosis knows about every trajectory sample: the nominal ball, the bar
direction, how each machine axis moves the bar, axis directions and reversals.

Everything here follows from the plan (trajectory + kinematics); nothing from a trace.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..timing.trajectory import axis_values_rad
from .rows import (GridRows, Labels, RateRows, Rows, RunEdge, UnitRows, blocks, gradient_rows,
                   uniform_step)
from .written import written_deviation_um


#: what a context's cache of derived arrays may hold (a sweep of a mode's frequencies
#: over 40,000 samples is 92 MB, kept only until the next array comes; a reversal's
#: onsets of a 5-minute program at 1 kHz are 4 MB): 128 MB took 0.15 GB more at the peak
#: of a diagnosis of the default sample's layer D and saved a tenth of its time
CACHE_BYTES = 48 << 20


def _nbytes(value) -> int:
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    if isinstance(value, dict):
        return sum(_nbytes(v) for v in value.values())
    return 0


class ArrayCache(OrderedDict):
    """Arrays derived from a context, kept by the stages that read them: once they hold
    more than ``limit_bytes`` together, any larger than half of it go first, then the
    least recently used (the newest stays whatever its size).  A value is the same
    whether kept or made again, so what is let go changes the time, never a result."""

    def __init__(self, limit_bytes: int = CACHE_BYTES):
        super().__init__()
        self.limit_bytes = limit_bytes

    def __getitem__(self, key):
        value = super().__getitem__(key)
        self.move_to_end(key)
        return value

    def __setitem__(self, key, value):
        super().__setitem__(key, value)
        self.move_to_end(key)
        sizes = {k: _nbytes(v) for k, v in self.items()}
        total = sum(sizes.values())
        # an array larger than half the bound goes first (kept only until the next one
        # comes), then the least recently used: the small ones read at every step stay
        order = sorted((k for k in self if k != key),
                       key=lambda k: sizes[k] <= self.limit_bytes // 2)
        for k in order:
            if total <= self.limit_bytes:
                break
            total -= sizes[k]
            super().__delitem__(k)

    def setdefault(self, key, default=None):
        if key not in self:
            self[key] = default
        return self[key]

    def nbytes(self) -> int:
        return sum(_nbytes(v) for v in self.values())


@dataclass(frozen=True, slots=True)
class Context:
    """Per-sample geometry of one program on its trajectory grid (program time).

    ``t_s : (n,)``; ``ball_mm, u : (n, 3)`` nominal ball (table frame) and unit bar
    direction from the pivot; ``length_mm : (n,)``; ``speed_mm_per_s : (n,)`` ball speed
    relative to the table; ``q : (n, m)`` axis values (mm, rad); ``qdot : (n, m)``
    axis velocities; ``gain : (n, m)`` bar reading change (mm) per unit axis error (mm
    or rad); ``direction : (n, m)`` +-1 last direction of motion of each axis;
    ``reversal_index``: per axis, the samples where it reversed (:attr:`reversal_times`,
    their times; :meth:`since_reversal_s` and :meth:`position_at_reversal` read from them
    what a sample needs); ``observable``: axes whose motion the bar sees at all (an axis
    always moving across the bar, e.g. Y of a B-C table set-up that keeps the bar in the
    XZ plane, is not); ``moving : (n,)``; labels ``segment, phase : (n,)``.

    On a program longer than :data:`TALL_ROWS` samples, ``u``, ``qdot``, ``gain``,
    ``run_start_mm`` and ``run_end_mm`` are made where read (:mod:`.rows`: the same
    numbers, indexed the same way), ``direction`` is held as int8 and ``segment`` and
    ``phase`` as codes of their labels.
    """

    t_s: np.ndarray
    ball_mm: np.ndarray
    u: np.ndarray | Rows
    length_mm: np.ndarray
    speed_mm_per_s: np.ndarray
    q: np.ndarray
    qdot: np.ndarray | Rows
    gain: np.ndarray | Rows
    direction: np.ndarray
    reversal_index: tuple
    moving: np.ndarray
    segment: np.ndarray | Labels
    phase: np.ndarray | Labels
    axis_names: tuple[str, ...]
    linear: tuple[int, ...]
    pivot_mm: np.ndarray
    arc_mm: np.ndarray
    arc_integral: np.ndarray
    run_start_mm: np.ndarray | RunEdge
    run_end_mm: np.ndarray | RunEdge
    #: unit bar direction in the machine's (bed) frame, ``(n, 3)``: a spindle's drift is
    #: seen through it (``u`` turns with a rotary table; without one it is ``u`` itself)
    u_bed: np.ndarray | Rows
    observable: tuple[int, ...] = ()
    #: ``(n,)`` um: the bar length along the program as written for the plan's
    #: controller less that along the planned path (LinuxCNC's chords; zeros for a
    #: controller that writes the curve, or none on a tall program): part of every
    #: expected reading
    written_um: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: the trajectory is a control's motion of the program as written (its chords
    #: included), not the planned curve: its own distance from the pivot is the reading
    control_path: bool = False
    #: longer than :data:`TALL_ROWS` samples: its per-sample values, and the diagnosis'
    #: tall models of it, are made where they are read
    tall: bool = False
    #: arrays derived from the others, kept by the stages that read them (keyed by each),
    #: within :data:`CACHE_BYTES`
    cache: ArrayCache = field(default_factory=ArrayCache)

    @property
    def reversal_times(self) -> tuple[np.ndarray, ...]:
        """Per axis, the program times at which it reversed."""
        return tuple(self.t_s[f] for f in self.reversal_index)

    def _last_reversal(self, idx: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Of the samples ``idx``: whether axis j has reversed at or before each, and the
        sample of its latest reversal (0 where it has not)."""
        flips = self.reversal_index[j]
        k = np.searchsorted(flips, idx, side="right") - 1
        last = flips[np.maximum(k, 0)] if len(flips) else np.zeros(len(k), dtype=int)
        return k >= 0, last

    def since_reversal_s(self, idx: np.ndarray, j: int) -> np.ndarray:
        """At the samples ``idx``: the time since axis j last reversed (inf before its
        first reversal)."""
        idx = np.asarray(idx)
        ok, last = self._last_reversal(idx, j)
        out = np.full(len(idx), np.inf)
        out[ok] = self.t_s[idx[ok]] - self.t_s[last[ok]]
        return out

    def position_at_reversal(self, idx: np.ndarray, j: int) -> np.ndarray:
        """At the samples ``idx``: axis j's value where it last reversed (NaN before its
        first reversal)."""
        idx = np.asarray(idx)
        ok, last = self._last_reversal(idx, j)
        out = np.full(len(idx), np.nan)
        out[ok] = self.q[last[ok], j]
        return out

    def run_id(self) -> np.ndarray:
        """``(n,)``: the number of the run of motion (a stretch between stops) each sample
        belongs to, -1 while standing."""
        return _run_ids(self.moving)

    def slow_state(self, j: int, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """Whether axis j crawls (moving, slower than ``speed``) and the time since it
        began to, per grid sample (cached)."""
        key = (j, speed)
        if key not in self.cache:
            slow = (np.abs(self.qdot[:, j]) < speed) & self.moving
            self.cache[key] = (slow, self.t_s - self.t_s[_crawl_start(slow)])
        return self.cache[key]

    def crawl_travel(self, j: int, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """Axis j's commanded travel so far (mm, on the grid) and its value where the
        current crawl began (cached)."""
        key = ("travel", j, speed)
        if key not in self.cache:
            slow, _ = self.slow_state(j, speed)
            dt = np.diff(self.t_s, prepend=self.t_s[0])
            travel = np.cumsum(np.abs(self.qdot[:, j]) * dt)
            self.cache[key] = (travel, travel[_crawl_start(slow)])
        return self.cache[key]

    def uniform_step(self) -> float:
        """The grid's step if every step is equal (numpy's gradient then takes its
        uniform formula), else NaN (cached)."""
        key = ("uniform step",)
        if key not in self.cache:
            self.cache[key] = (np.array([uniform_step(self.t_s)]),)
        return float(self.cache[key][0][0])

    @property
    def n(self) -> int:
        return len(self.t_s)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])


def _run_ids(moving: np.ndarray) -> np.ndarray:
    """Runs: maximal stretches of motion between stops, numbered from 0 (-1 standing)."""
    return np.cumsum(np.diff(np.r_[0, moving.astype(int)]) == 1) * moving - 1


def _crawl_start(slow: np.ndarray) -> np.ndarray:
    """Per sample, the index where the latest stretch of ``slow`` began (0 before the
    first)."""
    enter = np.flatnonzero(np.diff(np.r_[False, slow]).astype(bool) & slow)
    last = np.full(len(slow), -1)
    last[enter] = enter
    return np.maximum(np.maximum.accumulate(last), 0)


def directions(qdot: np.ndarray, eps: float) -> np.ndarray:
    """+-1 last direction of motion per column; before the first motion, the first
    direction (an axis that has not moved yet shows no step)."""
    sign = np.where(qdot > eps, 1.0, np.where(qdot < -eps, -1.0, 0.0))
    out = np.empty_like(sign)
    for j in range(sign.shape[1]):
        s = sign[:, j]
        idx = np.where(s != 0, np.arange(len(s)), -1)
        idx = np.maximum.accumulate(idx)
        first = np.flatnonzero(s)
        col = np.where(idx >= 0, s[np.maximum(idx, 0)], s[first[0]] if first.size else 1.0)
        out[:, j] = col
    return out


def reversals(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Of one axis' +-1 direction: the indices where it flips, and for every sample the
    index of the last flip at or before it (-1 before the first)."""
    flips = np.flatnonzero(np.diff(direction) != 0) + 1
    last = np.full(len(direction), -1)
    last[flips] = flips
    return flips, np.maximum.accumulate(last)


def strided(n: int, points_mm: np.ndarray, spacing_mm: float = 0.5, max_stride: int = 20
            ) -> np.ndarray:
    """Indices of a sub-grid no coarser than ``spacing_mm`` of path (nor ``max_stride``
    samples), always with the last sample: where smooth functions of the pose are
    evaluated and then interpolated."""
    if n < 3:
        return np.arange(n)
    step = float(np.max(np.linalg.norm(np.diff(points_mm, axis=0), axis=1)))
    stride = int(np.clip(spacing_mm / max(step, 1e-12), 1, max_stride))
    k = np.arange(0, n, stride)
    return k if k[-1] == n - 1 else np.r_[k, n - 1]


def sample_rows(t: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where :func:`sample_at` reads the uniform grid ``t`` at ``tau``: the rows below
    and above each time and the fraction of the way between them."""
    dt = (t[-1] - t[0]) / max(len(t) - 1, 1)
    x = np.clip((tau - t[0]) / dt, 0.0, len(t) - 1.000001)
    i = x.astype(int)
    return i, np.minimum(i + 1, len(t) - 1), x - i


def sample_at(t: np.ndarray, X: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Rows of ``X`` (on the uniform grid ``t``) linearly interpolated at ``tau``."""
    i, nxt, f = sample_rows(t, tau)
    f = f[:, None] if X.ndim == 2 else f
    # the same arithmetic as X[i] * (1 - f) + X[i + 1] * f, in place (two gathers of a
    # tall matrix instead of four temporaries)
    out = X[i]
    out *= 1 - f
    for a in range(0, len(out), _ROWS):  # the next rows a block at a time: no second copy
        out[a:a + _ROWS] += X[nxt[a:a + _ROWS]] * f[a:a + _ROWS]
    return out


def sample_made(t: np.ndarray, tau: np.ndarray, rows) -> np.ndarray:
    """:func:`sample_at` of a ``X`` not held: ``rows(r)`` makes its rows ``r`` (increasing,
    each once), those the interpolation reads; the same arithmetic."""
    i, nxt, f = sample_rows(t, tau)
    need = np.unique(np.r_[i, nxt])
    made = rows(need)
    out = made[np.searchsorted(need, i)]
    f = f[:, None] if out.ndim == 2 else f
    out *= 1 - f
    out += made[np.searchsorted(need, nxt)] * f
    return out


_ROWS = 16384


def nearest_samples(ctx: "Context", tau: np.ndarray) -> np.ndarray:
    """The trajectory samples nearest the program times ``tau`` (clipped to the
    program)."""
    t0, T = ctx.t_s[0], ctx.t_s[-1]
    return np.clip(np.rint((tau - t0) / (T - t0) * (ctx.n - 1)).astype(int), 0, ctx.n - 1)


#: programs longer than this many trajectory samples (17 min at 1 kHz) keep what follows
#: sample by sample from the rest as its recipe (:mod:`.rows`): held whole, the bar
#: direction, the axis rates and the gains are 0.23 GB an hour, and their making twice that
TALL_ROWS = 1_000_000

def build_context(plan: PlanFiles, program: str, velocity_eps: float = 1e-3) -> Context:
    """``velocity_eps``: axis speed (mm/s or rad/s) below which an axis counts as
    standing still when its direction is tracked."""
    cfg = plan.config
    kin = Kinematics(cfg.machine)
    traj = plan.trajectory(program)
    q = axis_values_rad(traj, kin)
    t = np.asarray(traj.t_s, dtype=float)
    pivot = np.asarray(cfg.ballbar.pivot_mm, dtype=float)
    ball = np.asarray(traj.ball_mm, dtype=float)  # = kin.forward(q), as the plan wrote it
    n = len(t)
    tall = n > TALL_ROWS
    u: np.ndarray | Rows
    if tall:  # (the same arithmetic row by row, a block of rows at a time)
        length = np.empty(n)
        for a, b in blocks(n):
            length[a:b] = np.linalg.norm(ball[a:b] - pivot, axis=1)
        u = UnitRows(ball, pivot, length)
    else:
        r = ball - pivot
        length = np.linalg.norm(r, axis=1)
        u = r / length[:, None]
        del r
    m = q.shape[1]
    # gains vary smoothly with the pose: evaluate on a coarser grid and interpolate
    k = strided(n, ball)
    qs, us = q[k], u[k]
    bs = kin.forward(qs)
    grid = np.zeros((len(k), m))
    for j in range(m):
        h = 1e-6 if kin.axes[j].is_rotary else 1e-3
        qh = qs.copy()
        qh[:, j] += h
        grid[:, j] = np.einsum("ni,ni->n", kin.forward(qh) - bs, us) / h
    gain: np.ndarray | Rows
    if tall:
        gain = GridRows(n, k, grid)
    else:
        gain = np.zeros((n, m))
        for j in range(m):
            gain[:, j] = np.interp(np.arange(n), k, grid[:, j])
    qdot: np.ndarray | Rows
    if tall:
        qdot = RateRows(q, t)
        speed = np.empty(n)
        step = uniform_step(t)
        for a, b in blocks(n):
            v = gradient_rows(t, step, lambda i: ball[i], np.arange(a, b))
            speed[a:b] = np.linalg.norm(v, axis=1)
        direction = np.empty((n, m), dtype=np.int8)
        for j in range(m):
            direction[:, j] = directions(qdot[:, j][:, None], velocity_eps)[:, 0]
    else:
        qdot = np.gradient(q, t, axis=0) if n > 2 else np.zeros_like(q)
        v = np.gradient(ball, t, axis=0) if n > 2 else np.zeros_like(ball)
        speed = np.linalg.norm(v, axis=1)
        direction = directions(qdot, velocity_eps)
    del v
    rev_index = tuple(reversals(direction[:, j])[0] for j in range(m))
    phase = np.asarray(traj.phase, dtype=object)
    moving = (phase != "dwell") & (phase != "reposition")
    run_id = _run_ids(moving)
    linear = tuple(j for j in range(m) if not kin.axes[j].is_rotary)
    # arc length along each run on one increasing axis (runs spaced apart), and the
    # running integral of the position over it (for arc-length averages)
    new_run = np.r_[True, run_id[1:] != run_id[:-1]]
    del run_id
    ds = np.zeros(n)
    if tall:
        for a, b in blocks(n, 1):
            ds[a:b] = np.linalg.norm(ball[a:b] - ball[a - 1:b - 1], axis=1)
    else:
        ds[1:] = np.linalg.norm(np.diff(ball, axis=0), axis=1)
    ds[~moving] = 0.0
    ds[new_run] = 1e3  # a gap between runs no window bridges
    arc = np.cumsum(ds)
    starts = np.flatnonzero(new_run)
    run_start: np.ndarray | RunEdge
    run_end: np.ndarray | RunEdge
    if tall:
        # the running sum a block at a time, each block begun from the sum before it
        # (so added in the same order as the sum over the whole)
        integral = np.empty((n, 3))
        carry = np.zeros((1, 3))
        for a, b in blocks(n):
            lo = max(a, 1)
            mid = np.zeros((b - a, 3))
            mid[lo - a:] = 0.5 * (ball[lo:b] + ball[lo - 1:b - 1]) * ds[lo:b, None]
            mid[new_run[a:b]] = 0.0
            integral[a:b] = np.cumsum(np.r_[carry, mid], axis=0)[1:]
            carry = integral[b - 1:b]
        run_start, run_end = RunEdge(arc, starts, last=False), RunEdge(arc, starts, last=True)
    else:
        mid = np.r_[ball[:1] * 0, 0.5 * (ball[1:] + ball[:-1])] * ds[:, None]
        mid[new_run] = 0.0
        integral = np.cumsum(mid, axis=0)
        first = np.maximum.accumulate(np.where(new_run, np.arange(n), 0))
        last_idx = np.r_[starts[1:] - 1, n - 1]
        run_no = np.cumsum(new_run) - 1
        run_start, run_end = arc[first], arc[last_idx][run_no]
    del mid, ds
    u_bed = u
    if any(kin.axes[i].is_rotary for i in kin.workpiece):
        rot, _ = kin.table_transform(q)  # p_bed = rot p_table + trans
        u_bed = np.einsum("nij,nj->ni", rot, np.asarray(u))
    segment = np.asarray(traj.segment, dtype=object)
    labels = (Labels(segment), Labels(phase)) if tall else (segment, phase)
    written = written_deviation_um(plan, program, ball, moving)
    if tall and not written.any():
        written = np.zeros(0)  # (none: what every reader takes for zeros)
    return Context(t, ball, u, length, speed, q, qdot, gain, direction, rev_index, moving,
                   labels[0], labels[1], tuple(kin.names), linear,
                   pivot, arc, integral, run_start, run_end, u_bed,
                   tuple(j for j in range(m) if float(np.sqrt(np.mean(gain[:, j] ** 2))) > 1e-6),
                   written_um=written,
                   control_path=plan.motion_of(program) is not None, tall=tall)
