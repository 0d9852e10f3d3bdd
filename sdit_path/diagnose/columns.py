"""Regressor columns on the trajectory grid: the expected reading, the findings' own
columns and their shapes' first-order change, a partner's columns, and the blocks a
recording needs beside them."""

from __future__ import annotations

import logging
import math

import numpy as np

from ..errormodel.chain import actual_ball
from ..errormodel.errorset import ErrorSet
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..reading.context import Context, nearest_samples, sample_at, strided
from ..reading.rows import BLOCK_ROWS
from ..sim.simulate import error_values
from .align import Alignment, generic_columns, lsq
from .effects import Effect, Samples, fitted_beside
from .fitting import serial_correlation

log = logging.getLogger(__name__)


def expected_reading(plan: PlanFiles, ctx: Context, model: ErrorSet | None) -> np.ndarray:
    """The simulated bar reading (um) on the trajectory grid: exact chain, no noise,
    along the program as written for the plan's controller (``ctx.written_um``)."""
    cfg = plan.config
    written = ctx.written_um if len(ctx.written_um) == ctx.n else np.zeros(ctx.n)
    if model is None:
        if ctx.control_path:
            # the trajectory is the control's path (its chords): its own distance
            return (np.linalg.norm(ctx.ball_mm - ctx.pivot_mm, axis=1)
                    - cfg.ballbar.bar_length_mm) * 1e3
        return written.copy()
    kin = Kinematics(cfg.machine)
    em, theta = error_values(plan, model)
    k = strided(ctx.n, ctx.ball_mm)  # smooth in the pose: a coarser grid, interpolated
    ball = actual_ball(kin, em, theta, ctx.q[k])
    val = (np.linalg.norm(ball - ctx.pivot_mm, axis=1) - cfg.ballbar.bar_length_mm) * 1e3
    return np.interp(np.arange(ctx.n), k, val) + written


class TrialModel:
    """``generic_columns(ctx, expected, [fixed, cols])`` for one trial's ``cols`` after
    another (a parameter profiled on a grid; ``fixed`` a matrix or its blocks): the same matrix, built once and its last
    columns overwritten while every new column varies as the last ones did (the generic
    columns drop a constant column, so the matrix's shape can depend on them)."""

    def __init__(self, ctx: Context, expected: np.ndarray,
                 fixed: np.ndarray | list[np.ndarray]):
        self.ctx, self.expected, self.fixed = ctx, expected, fixed
        self.X: np.ndarray | None = None
        self.width = 0

    def with_columns(self, cols: np.ndarray) -> np.ndarray:
        cols = np.asarray(cols, float).reshape(self.ctx.n, -1)
        varies = bool((np.ptp(cols, axis=0) > 1e-9).all())
        if self.X is not None and varies and cols.shape[1] == self.width:
            self.X[:, -self.width:] = cols
            return self.X
        fixed = self.fixed if isinstance(self.fixed, list) else [self.fixed]
        X = generic_columns(self.ctx, self.expected, [*fixed, cols])
        if varies and isinstance(X, np.ndarray):  # (a model made where read is made anew)
            self.X, self.width = X, cols.shape[1]
        return X


def partner_columns(ctx: Context, eff: Effect, expected: np.ndarray, t_m: np.ndarray,
                     y: np.ndarray, al: Alignment, max_samples: int = 60_000):
    """``eff``'s columns on the trajectory grid, its nonlinear parameters searched on
    what the set-up leaves of the reading at the timing ``al``; None when it has nothing
    to offer."""
    tau = al.program_time(t_m)
    ok = np.flatnonzero(np.isfinite(y) & (tau >= ctx.t_s[0]) & (tau <= ctx.t_s[-1]))
    if len(ok) < 1000:
        return None
    ok = ok[:: max(1, len(ok) // max_samples)]
    tt = tau[ok]
    idx = nearest_samples(ctx, tt)
    # the set-up only: the generic columns' v^2 and acceleration terms are the lag's own
    # signature and would leave it nothing but its longest tail
    G = sample_at(ctx.t_s, np.column_stack([expected, np.ones(ctx.n), ctx.u]), tt)
    r = y[ok] - G @ lsq(G, y[ok])
    # judged as fitted together with the set-up (which shares a smoothing's or a lag's
    # shrink while moving)
    Q, sv, _ = np.linalg.svd(G, full_matrices=False)
    with fitted_beside(Q[:, sv > sv[0] * 1e-10]):
        cand = search_candidate(eff, ctx, Samples(idx, tt), r)
    if cand is None:
        return None
    log.debug("partner %s: %s", eff.name, cand[0])
    return eff.columns(ctx, Samples(np.arange(ctx.n), ctx.t_s), cand[0])[0]


def needed_blocks(ctx: Context, expected: np.ndarray, t_m: np.ndarray, y: np.ndarray,
                   al: Alignment, found: np.ndarray, blocks: list[np.ndarray],
                   margin: float, max_samples: int = 300_000) -> list[np.ndarray]:
    """The blocks the recording needs beyond the generic columns and what was found, each
    judged on its own by the information criterion (samples counted by the residual's
    correlation) at the first alignment.  Columns a trace does not need only blur its
    timing: on a slow 5-axis program, whose reading hardly moves, unneeded geometry
    columns leave the clock several times less certain than the recording allows."""
    tau = al.program_time(t_m)
    ok = np.flatnonzero(np.isfinite(y) & (tau >= ctx.t_s[0]) & (tau <= ctx.t_s[-1]))
    if len(ok) < 100:
        return blocks
    ok = ok[:max_samples]  # contiguous: the residual's correlation is read sample to sample
    yy = y[ok]
    base = sample_at(ctx.t_s, generic_columns(ctx, expected, found), tau[ok])
    r0 = yy - base @ lsq(base, yy)
    rss0 = float(r0 @ r0)
    rho = serial_correlation(r0, tau[ok])
    n_eff = max(len(ok) * (1 - rho) / (1 + rho), 10.0)
    keep = []
    for B in blocks:
        if B.shape[1] == 0:
            continue
        A = np.column_stack([base, sample_at(ctx.t_s, B, tau[ok])])
        r1 = yy - A @ lsq(A, yy)
        dbic = n_eff * math.log(rss0 / max(float(r1 @ r1), 1e-30)) - B.shape[1] * math.log(n_eff)
        if dbic >= margin:
            keep.append(B)
    return keep


def every_sample(eff: Effect, ctx: Context, nl: dict) -> tuple[np.ndarray, tuple]:
    """``eff.columns`` on every trajectory sample; on a tall program a block of samples
    at a time (each row is made from its own sample: the same numbers, without every
    sample's temporaries at once, several times the columns themselves)."""
    if not ctx.tall:
        return eff.columns(ctx, Samples(np.arange(ctx.n), ctx.t_s), nl)
    out, labels = None, ()
    for a in range(0, ctx.n, BLOCK_ROWS):
        idx = np.arange(a, min(a + BLOCK_ROWS, ctx.n))
        cols, labels = eff.columns(ctx, Samples(idx, ctx.t_s[idx]), nl)
        if out is None:
            out = np.empty((ctx.n, cols.shape[1]))
        out[a:a + len(idx)] = cols
    return out, labels


def shape_columns(ctx, lib, findings) -> np.ndarray:
    """The first-order change of each finding's columns with its continuous nonlinear
    parameters (a pulse's rise and decay, a play's width, a mode's frequency): fitted
    beside the timing, the shape is free within its linearisation, so that the timing's
    uncertainty takes in what the shape leaves open instead of holding the shape found
    at the first timing.  Parameters profiled with the timing and discrete ones are left
    out."""
    by = {e.name: e for e in lib}
    out = []
    for f in locked_findings(lib, findings):
        eff = by[f.effect]
        skip = set(getattr(eff, "discrete", ())) | (
            {eff.timing_parameter[0]} if eff.timing_parameter else set())
        try:
            C = every_sample(eff, ctx, f.nonlinear)[0]
        except (ValueError, np.linalg.LinAlgError):
            continue
        shape, largest = C.shape, max(float(np.abs(C).max()), 1e-300) if C.size else 1e-300
        del C  # (its shape and size are what is read)
        for key, value in f.nonlinear.items():
            if key in skip or isinstance(value, bool) or not isinstance(value, (int, float)):
                continue
            h = 0.01 * abs(value) if value else 0.01
            try:
                up = every_sample(eff, ctx, {**f.nonlinear, key: value + h})[0]
                down = every_sample(eff, ctx, {**f.nonlinear, key: value - h})[0]
            except (ValueError, np.linalg.LinAlgError):
                continue
            if up.shape != shape or not (np.isfinite(up).all() and np.isfinite(down).all()):
                continue
            Dk = up - down  # (up - down) / (2 h), the division in place
            del up, down
            Dk /= 2 * h
            keep = np.abs(Dk).max(axis=0) > 1e-9 * largest
            if keep.any():
                out.append(Dk[:, keep])
    return np.column_stack(out) if out else np.zeros((ctx.n, 0))


def locked_findings(lib: list[Effect], findings: list) -> list:
    """The findings whose reading is locked to the program (``locked_to_program``), to
    be fitted beside the timing."""
    by = {e.name: e for e in lib}
    return [f for f in findings if by[f.effect].locked_to_program(f.nonlinear)]


def model_columns(ctx, lib, expected, findings) -> np.ndarray:
    """The expected reading, a constant and the columns of every finding that is
    :func:`timed`, in that order."""
    by = {e.name: e for e in lib}
    return np.column_stack([expected[:, None], np.ones((ctx.n, 1))]
                           + [every_sample(by[f.effect], ctx, f.nonlinear)[0]
                              for f in locked_findings(lib, findings)])


def search_candidate(eff: Effect, ctx: Context, S: Samples, r: np.ndarray, pinned: dict | None = None):
    """An effect's nonlinear parameters searched on the residual ``r`` (those in
    ``pinned`` kept as given) and its columns there, or None when it has nothing to
    offer."""
    try:
        fixed = (pinned or {}).get(eff.name)
        # an effect whose search takes what is pinned searches the rest at that value
        nl = (eff.search(ctx, S, r, fixed=fixed) if fixed and eff.searches_with_fixed
              else eff.search(ctx, S, r))
    except (ValueError, np.linalg.LinAlgError):
        return None
    if nl is None:
        return None
    if pinned and eff.name in pinned:
        nl = {**nl, **pinned[eff.name]}
    C, labels = eff.columns(ctx, S, nl)
    if C.shape[1] == 0 or not np.isfinite(C).all():
        return None
    return nl, C, labels
