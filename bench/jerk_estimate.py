"""How fast could any jerk-limited motion run these paths?  An estimate, beside our plan.

``bench_timing.py`` compares the plan with toppra's acceleration-limited optimum, which
has no jerk limit, and with a jerk-aware lower bound that only sees the ramps at the
ends of a run.  Neither says how much of the gap on tightly curved runs (wave crests,
a C axis near the pole) a better planner could win.  This script estimates the
jerk-limited optimum of each run directly.

With b = v^2 and a the path acceleration along arc length s, the axis limits are

    |q_i' v| <= V_i,   |q_i'' b + q_i' a| <= A_i,
    |q_i''' b + 3 q_i'' a + q_i' da/ds| <= J_i / sqrt(b)      (jerk = v da/ds)

and db/ds = 2a.  On a grid (a linear in s per cell, so b follows exactly) the first
two are linear; the jerk row is linear on the left and convex on the right, so it is
replaced by its tangent at the current b (a restriction: every iterate keeps the true
row) and the linear program (scipy HiGHS; time from tangent cuts of 1/sqrt(b)) is
solved again until the time settles.  Started from the planned profile, which is
feasible, the time can only fall.

It is an estimate, not a bound: the jerk rows are enforced at cell midpoints on
derivatives taken by differences on a uniform grid (which smooths the jumps of q'''
at the knots of a cubic: a relaxation), the profile shape per cell is restricted and
the iteration finds a local optimum.  On straight runs, where the rigorous bound of
``bench_timing.py`` is tight, it lands 1-2 % above that bound; a variant enforcing the
jerk rows at both ends of every cell with one-sided derivatives at the knots came out
about 2 % slower.  Read its figures as +-2 %.

    python bench/jerk_estimate.py [CONFIG] [--feed 5000] [--layers D,E] [--runs N]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog

from bench_timing import toppra_time
from sdit_path.config import load_config
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.timing.trajectory import TimedRun, Timer, axis_derivatives
from memory import peak_memory_line


def estimate(timer: Timer, timed: TimedRun, feed: float, step_mm: float = 0.1,
             iterations: int = 30) -> float:
    """Estimated least motion time (s) of one run at path speed <= ``feed`` (mm/s)."""
    geo = timed.geometry
    n = max(100, math.ceil(geo.length_mm / step_mm))
    s = np.linspace(0.0, geo.length_mm, n + 1)
    h = s[1] - s[0]
    q, _ = timer.axis_values(geo.points(s), timed.carry_in)
    d1, d2, d3 = axis_derivatives(q, h)
    cells, nax = np.arange(n), q.shape[1]
    nb = n + 1
    nv = 2 * nb + n  # b_k, a_k, t_m
    ib, ia, it = 0, nb, 2 * nb

    def sparse(data, rows, cols, shape0):
        return sp.coo_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(shape0, nv))

    # db/ds = 2a exactly for a linear in s: b_{k+1} - b_k = h (a_k + a_{k+1})
    dyn = sparse([np.ones(n), -np.ones(n), -h * np.ones(n), -h * np.ones(n)],
                 [cells] * 4, [ib + cells + 1, ib + cells, ia + cells, ia + cells + 1], n)
    nodes = np.arange(nb)
    acc = sp.vstack([sparse([d2[:, i], d1[:, i]], [nodes, nodes], [ib + nodes, ia + nodes], nb)
                     for i in range(nax)])
    acc_rhs = np.repeat(timer.a_lim, nb)
    mid = [(d[:-1] + d[1:]) / 2.0 for d in (d1, d2, d3)]

    def jerk_rows(i: int, sign: float, b_mid: np.ndarray) -> tuple:
        # sign * (q''' b_m + 3 q'' a_m + q' (a_{k+1} - a_k)/h) + J/2 b0^-1.5 b_m <= 1.5 J b0^-0.5
        slope = 0.25 * timer.j_lim[i] * b_mid ** -1.5  # per node: b_m = (b_k + b_{k+1}) / 2
        m1, m2, m3 = (m[:, i] for m in mid)
        rows = sparse([sign * m3 / 2 + slope, sign * m3 / 2 + slope,
                       sign * (1.5 * m2 - m1 / h), sign * (1.5 * m2 + m1 / h)],
                      [cells] * 4, [ib + cells, ib + cells + 1, ia + cells, ia + cells + 1], n)
        return rows, 1.5 * timer.j_lim[i] * b_mid ** -0.5

    def cuts(betas) -> tuple:
        # t_m >= h / sqrt(b_m), from below by tangents at ``beta``
        mats, rhs = [], []
        for beta in betas:
            beta = np.broadcast_to(beta, (n,))
            g = -0.25 * h * beta ** -1.5
            mats.append(sparse([-np.ones(n), g, g], [cells] * 3,
                               [it + cells, ib + cells, ib + cells + 1], n))
            rhs.append(-1.5 * h * beta ** -0.5)
        return mats, rhs

    fixed_cuts = cuts((feed * np.geomspace(0.01, 1.0, 30)) ** 2)
    v_cap = np.minimum(feed, np.min(timer.v_lim / np.maximum(np.abs(d1), 1e-12), axis=1))
    bounds = ([(0.0, c * c) for c in v_cap] + [(None, None)] * nb + [(0.0, None)] * n)
    for k in (ib, ib + n, ia, ia + n):
        bounds[k] = (0.0, 0.0)
    cost = np.zeros(nv)
    cost[it:] = 1.0
    # start from the planned profile (feasible within its limits)
    tt = np.linspace(0.0, timed.profile.duration_s, 20000)
    ps, pv, *_ = timed.profile.evaluate(tt)
    ps, pv = timed.param.s(ps), timed.param.ds(ps) * pv  # the ball's arc length and speed
    b = np.minimum(np.interp(s, ps, pv) ** 2 * 0.98, v_cap ** 2)
    best = math.inf
    for _ in range(iterations):
        b_mid = np.maximum((b[:-1] + b[1:]) / 2.0, (0.002 * feed) ** 2)
        mats, rhs = [acc, -acc], [acc_rhs, acc_rhs]
        for i in range(nax):
            for sign in (1.0, -1.0):
                rows, r = jerk_rows(i, sign, b_mid)
                mats.append(rows)
                rhs.append(r)
        here = cuts([b_mid])
        res = linprog(cost, A_ub=sp.vstack(mats + fixed_cuts[0] + here[0]).tocsr(),
                      b_ub=np.concatenate(rhs + fixed_cuts[1] + here[1]), A_eq=dyn.tocsr(),
                      b_eq=np.zeros(n), bounds=bounds, method="highs")
        if res.status != 0:
            raise RuntimeError(f"linear program failed: {res.message}")
        b = np.maximum(res.x[ib:ib + nb], 0.0)
        t = float(np.sum(2.0 * h / (np.sqrt(b[:-1]) + np.sqrt(b[1:]) + 1e-300)))
        if abs(best - t) < 1e-5 * t:
            return t
        best = t
    return best


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--feed", type=float, default=5000.0, help="mm/min")
    ap.add_argument("--layers", default="E", help="e.g. D,E")
    ap.add_argument("--runs", type=int, default=0, help="only the first N runs of a layer")
    args = ap.parse_args()
    base = load_config(args.config)
    cfg = dataclasses.replace(base, test=dataclasses.replace(base.test,
                                                             feed_mm_per_min=args.feed))
    hemi = partition(cfg)
    timer = Timer(cfg)
    builder = PathBuilder(cfg, hemi)
    feed = args.feed / 60.0
    print(f"jerk_estimate: {base.source}, F{args.feed:g}; motion time per layer: toppra "
          f"(no jerk limit), jerk-limited estimate (+-2 %), our plan (ruckig)")
    for layer in hemi.layers:
        if layer.name not in args.layers.split(","):
            continue
        timed = timer.time_layer(builder.layer_path(layer))
        runs = [i for i in timed.items if isinstance(i, TimedRun)]
        if args.runs:
            runs = runs[:args.runs]
        sums = {}  # kind -> [toppra, estimate, ruckig, count]
        t0 = time.perf_counter()
        for r in runs:
            windows, _ = timer.run_windows(r.geometry, r.carry_in)
            kind = "curved" if min(w[1].v_cap for w in windows) < feed * 0.999 else "feed-bound"
            row = sums.setdefault(kind, [0.0, 0.0, 0.0, 0])
            for k, x in enumerate((toppra_time(timer, r, feed), estimate(timer, r, feed),
                                   r.profile.duration_s)):
                row[k] += x
            row[3] += 1
        took = time.perf_counter() - t0
        total = [sum(v[k] for v in sums.values()) for k in range(3)]
        for kind, (tp, est, ours, count) in sorted(sums.items()) + [("all", (*total, len(runs)))]:
            print(f"  layer {layer.name} {kind:>10} runs ({count:2d}): toppra {tp:7.2f} s  "
                  f"estimate {est:7.2f} s ({est / tp:5.3f})  ruckig {ours:7.2f} s "
                  f"({ours / tp:5.3f})  ruckig/estimate {ours / est:5.3f}")
        print(f"  ({took:.0f} s for layer {layer.name})")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
