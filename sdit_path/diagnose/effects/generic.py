"""Generic shapes of what any recording may hold, from the library's effects: fitted
beside the timing so that they cannot pull it."""

from __future__ import annotations

import numpy as np

from ...plan.files import PlanFiles
from ...reading.context import Context, strided
from ..align import axis_acceleration_readings
from ..tall import Interpolated, Made
from .base import Samples, linear_axes
from .friction import ReversalSpike
from .geometry import GeometryBeyond, ScaleMismatch, Squareness
from .play import Backlash, LateralPlay
from .servo import ServoMismatch


def pose_blocks(plan: PlanFiles, ctx: Context) -> list:
    """Geometry as functions of the pose, one block per kind (squareness, scale, the
    smooth geometry beyond the model), on the trajectory grid: arrays, or on a tall
    program (:attr:`~sdit_path.reading.context.Context.tall`: held whole they are 42
    columns on every sample, 1.1 GB an hour) the same columns made where they are read
    (:class:`~sdit_path.diagnose.tall.Interpolated`)."""
    m, travel = plan.config.machine, plan.tested_travel()
    k = strided(ctx.n, ctx.ball_mm)
    sub = Samples(k, ctx.t_s[k])
    out: list = []
    for E in (Squareness(m, travel), ScaleMismatch(m, travel), GeometryBeyond(m, travel)):
        G = E.columns(ctx, sub, {})[0]
        if ctx.tall:
            out.append(Interpolated(ctx.n, k, G))
            continue
        # written column by column into the block (stacked from a list, the columns and
        # the block were held at once: 2 GB for an hour's 36 columns of geometry)
        block = np.empty((ctx.n, G.shape[1]))
        at = np.arange(ctx.n)
        for i in range(G.shape[1]):
            block[:, i] = np.interp(at, k, G[:, i])
        out.append(block)
    return out


def alignment_blocks(plan: PlanFiles, ctx: Context) -> list:
    """The blocks of :func:`alignment_columns`, for ``generic_columns(..., consume=True)``
    to copy and let go one by one."""
    return pose_blocks(plan, ctx) + _dynamic_blocks(ctx)


def alignment_columns(plan: PlanFiles, ctx: Context, pose_only: bool = False) -> np.ndarray:
    """Columns the alignment fits besides its generic ones, so that what every trace
    may hold cannot pull the timing: geometry as functions of the pose (squareness,
    scale, and the smooth geometry beyond the model) and, unless ``pose_only``,
    different servo lags, a drift, and reversal-locked steps and pulses (backlash,
    lateral play, friction spikes).  (Stacked once from their blocks: tall, 65 columns
    on every trajectory sample.)"""
    blocks = pose_blocks(plan, ctx) if pose_only else alignment_blocks(plan, ctx)
    return np.column_stack([b if isinstance(b, np.ndarray) else b.full() for b in blocks])


def dynamic_columns(ctx: Context) -> np.ndarray:
    """What any recording may hold besides geometry, in generic shapes: different servo
    lags, a drift, and reversal-locked steps and pulses (backlash, lateral play,
    friction spikes)."""
    return np.column_stack([b.full() if isinstance(b, Made) else b for b in _dynamic_blocks(ctx)])


def _dynamic_blocks(ctx: Context) -> list:
    """The blocks of :func:`dynamic_columns`: arrays, or on a tall program the same
    columns made where they are read (each an effect's columns at the samples asked
    for: held whole they are 23 columns on every sample, 0.6 GB an hour)."""
    tall = ctx.tall

    def block(make):
        if tall:
            return Made(ctx.n, lambda idx: make(Samples(idx, ctx.t_s[idx])))
        return make(Samples(np.arange(ctx.n), ctx.t_s))

    servo = ServoMismatch()
    cols = [block(lambda s: servo.columns(ctx, s, {})[0])]
    cols.append(block(lambda s: ctx.u_bed[s.idx] * (ctx.t_s[s.idx] / 3600.0)[:, None]))
    # each axis deflects with its own acceleration (its structure's compliance, a mode
    # of tens of Hz quasi-static below it): microns at each start and stop, which pull
    # the start by tens of ms and the clock by a hundred ppm unless fitted.  Not
    # generic: on a trace without it the same columns take the starts and stops the
    # timing is read from
    cols.append(block(lambda s: axis_acceleration_readings(ctx, s.idx if tall else None)))
    widths = {f"width_{ctx.axis_names[j]}_um": 6.5 for j in linear_axes(ctx)
              if len(ctx.reversal_times[j])}
    if widths:
        cols.append(block(lambda s: Backlash().columns(ctx, s, widths)[0]))
        # a pulse at the sign change and one at a breakaway speed (25 ms later on a
        # slow reversal inside a curve)
        for onset in (ReversalSpike.onsets_mm_s[0], 0.05):
            nl = {"tau_ms": 25.0, "onset_mm_s": onset}
            cols.append(block(lambda s, nl=nl: ReversalSpike().columns(ctx, s, nl)[0]))
        cols.append(block(lambda s: LateralPlay().columns(ctx, s, {})[0]))
    if tall:  # their spreads read once per program (a pass over every row)
        key = ("dynamic spreads",)
        if key not in ctx.cache:
            ctx.cache[key] = tuple(b.spread() for b in cols)
        for b, spread in zip(cols, ctx.cache[key]):
            b.known_spread = spread
    return cols
