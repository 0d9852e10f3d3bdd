"""Cycle time against the acceleration-limited time-optimal bound (toppra).

For every layer program of a sample and every feed, the motion time of the planned
jerk-limited trajectory (sum of its ruckig runs; dwells are equal on both sides and
left out) is compared with toppra's time-optimal parametrisation (ParametrizeConstAccel,
no jerk limit) of the same runs under the same per-axis velocity and acceleration
limits and the same path speed limit (the feed).  Targets: ratio <= 1.05 up to F2000,
<= 1.10 at F5000.  Also prints the planning time per layer.

toppra's bound ignores the jerk limits, so the rest-to-rest ramps at both ends of
every run are too short in it (0 to F5000 takes ~0.9 mm without a jerk limit and
~3.4 mm with the default sample's 50 m/s^3).  A second, jerk-aware lower bound (LB)
is printed beside it.  With s the arc length and q_i(s) the axis values, any motion
within the axis limits has path speed v <= feed and, at every s, path acceleration
|a| <= min_i (A_i + |d2q_i/ds2| v^2) / |dq_i/ds| and path jerk
|j| <= min_i (J_i + |d3q_i/ds3| v^3 + 3 |d2q_i/ds2| v |a|) / |dq_i/ds|, because
d2q/dt2 = q'' v^2 + q' a and d3q/dt3 = q''' v^3 + 3 q'' v a + q' j.  The largest of
those over the first and last stretch of a run, with v at the feed, are constant
limits that every feasible motion obeys there; no motion covers a stretch from rest
faster than the fastest velocity ramp under them (ruckig, velocity interface), and none
crosses the middle faster than at the feed.  LB per run is the larger of that and
toppra's.  It is loose where curvature couples acceleration and jerk in the middle of
a run (tight wave crests), so ruckig/LB overstates what a better planner could gain.

    python bench/bench_timing.py [CONFIG] [--feeds 200,600,2000,5000] [--layers D,E]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import time

import numpy as np
import toppra as ta
import toppra.algorithm as algo
import toppra.constraint as constraint
from ruckig import ControlInterface, InputParameter, Ruckig, Trajectory

from sdit_path.config import load_config
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.timing.trajectory import RunGeometry, TimedRun, Timer, axis_derivatives
from memory import peak_memory_line

logging.getLogger("toppra").setLevel(logging.ERROR)
TARGETS = {200: 1.05, 600: 1.05, 2000: 1.05, 5000: 1.10}


def toppra_time(timer: Timer, timed: TimedRun, feed_mm_per_s: float, step_mm: float = 0.25) -> float:
    geo: RunGeometry = timed.geometry
    n = max(50, math.ceil(geo.length_mm / step_mm))
    s = np.linspace(0.0, geo.length_mm, n + 1)
    q, _ = timer.axis_values(geo.points(s), timed.carry_in)
    path_q = np.column_stack([q, s])  # the last "axis" is s itself: its speed is the feed
    path = ta.SplineInterpolator(s, path_q)
    vlim = np.concatenate([timer.v_lim, [feed_mm_per_s]])
    alim = np.concatenate([timer.a_lim, [1e9]])
    pc_v = constraint.JointVelocityConstraint(np.column_stack([-vlim, vlim]))
    pc_a = constraint.JointAccelerationConstraint(np.column_stack([-alim, alim]))
    inst = algo.TOPPRA([pc_v, pc_a], path, parametrizer="ParametrizeConstAccel",
                       gridpoints=np.linspace(0.0, geo.length_mm, min(n + 1, 800)))
    traj = inst.compute_trajectory(0, 0)
    if traj is None:
        raise RuntimeError("toppra failed")
    return float(traj.duration)


def _ramp_time(dist: float, feed: float, a_max: float, j_max: float) -> tuple[float, float]:
    """Least time to cover ``dist`` from rest under (feed, a_max, j_max), and the length
    of the fastest ramp to the feed."""
    otg, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
    inp.control_interface = ControlInterface.Velocity
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_velocity, inp.target_acceleration = [feed], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [feed], [a_max], [j_max]
    otg.calculate(inp, traj)
    ts = np.linspace(0.0, traj.duration, 2001)
    pos = np.array([traj.at_time(t)[0][0] for t in ts])
    if pos[-1] <= dist:
        return traj.duration + (dist - pos[-1]) / feed, float(pos[-1])
    return float(np.interp(dist, pos, ts)), float(pos[-1])


def jerk_bound(timer: Timer, timed: TimedRun, feed: float, step_mm: float = 0.05) -> float:
    """The jerk-aware lower bound on a run's motion time (see the module text)."""
    geo: RunGeometry = timed.geometry
    n = max(200, math.ceil(geo.length_mm / step_mm))
    s = np.linspace(0.0, geo.length_mm, n + 1)
    q, _ = timer.axis_values(geo.points(s), timed.carry_in)
    h = s[1] - s[0]
    d1, d2, d3 = axis_derivatives(q, h)
    q1 = np.maximum(np.abs(d1), 1e-9)
    a_ub = np.min((timer.a_lim + np.abs(d2) * feed ** 2) / q1, axis=1)

    def limits(sel: np.ndarray) -> tuple[float, float]:
        a_top = float(a_ub[sel].max())
        j_ub = (timer.j_lim + np.abs(d3[sel]) * feed ** 3
                + 3 * np.abs(d2[sel]) * feed * a_top) / q1[sel]
        return a_top, float(np.min(j_ub, axis=1).max())

    half = geo.length_mm / 2.0
    total = used = 0.0
    for stretch in (lambda d: s <= d, lambda d: s >= geo.length_mm - d):
        d = half
        for _ in range(3):  # the stretch: as long as the ramp its own limits allow
            _, ramp = _ramp_time(half, feed, *limits(stretch(d)))
            d = min(half, ramp * 1.0001)
        t, _ = _ramp_time(d, feed, *limits(stretch(d)))
        total += t
        used += d
    return total + (geo.length_mm - used) / feed


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--feeds", default="200,600,2000,5000")
    ap.add_argument("--layers", default="", help="only these layers, e.g. D,E (default: all)")
    args = ap.parse_args()
    base = load_config(args.config)
    feeds = [float(f) for f in args.feeds.split(",")]
    print(f"bench_timing: {base.source}; motion time of the jerk-limited plan (ruckig) / "
          f"acceleration-limited optimum (toppra)")
    worst_by_feed = {}
    for feed in feeds:
        cfg = dataclasses.replace(base, test=dataclasses.replace(base.test, feed_mm_per_min=feed))
        hemi = partition(cfg)
        timer = Timer(cfg)
        builder = PathBuilder(cfg, hemi)
        worst = 0.0
        for layer in hemi.layers:
            if args.layers and layer.name not in args.layers.split(","):
                continue
            path = builder.layer_path(layer)
            t0 = time.perf_counter()
            timed = timer.time_layer(path)
            t_plan = time.perf_counter() - t0
            runs = [i for i in timed.items if isinstance(i, TimedRun)]
            ours = sum(r.profile.duration_s for r in runs)
            bounds = [toppra_time(timer, r, feed / 60.0) for r in runs]
            bound = sum(bounds)
            lower = sum(max(b, jerk_bound(timer, r, feed / 60.0)) for b, r in zip(bounds, runs))
            ratio = ours / bound
            worst = max(worst, ratio)
            print(f"  F{feed:<6g} layer {layer.name}: ruckig {ours:8.2f} s  toppra {bound:8.2f} s  "
                  f"ratio {ratio:6.3f}   jerk-aware LB {lower:8.2f} s  ruckig/LB "
                  f"{ours / lower:6.3f}   planning {t_plan * 1e3:6.0f} ms/layer "
                  f"({t_plan / len(runs) * 1e3:.1f} ms/run)")
        worst_by_feed[feed] = worst
    print()
    for feed, worst in worst_by_feed.items():
        target = TARGETS.get(int(feed))
        verdict = "" if target is None else f"  target <= {target:.2f}: " + (
            "met" if worst <= target else "NOT met")
        print(f"F{feed:g}: worst layer ratio {worst:.3f}{verdict}")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
