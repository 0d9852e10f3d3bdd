"""Cycle time against the acceleration-limited time-optimal bound (toppra).

For every layer program of a sample and every feed, the motion time of the planned
jerk-limited trajectory (sum of its ruckig runs; dwells are equal on both sides and
left out) is compared with toppra's time-optimal parametrisation (ParametrizeConstAccel,
no jerk limit) of the same runs under the same per-axis velocity and acceleration
limits and the same path speed limit (the feed).  Targets: ratio <= 1.05 up to F2000,
<= 1.10 at F5000.  Also prints the planning time per layer.

    python bench/bench_timing.py [CONFIG] [--feeds 200,600,2000,5000]
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

from sdit_path.config import load_config
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.timing.trajectory import RunGeometry, Timer, TimedRun

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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--feeds", default="200,600,2000,5000")
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
            path = builder.layer_path(layer)
            t0 = time.perf_counter()
            timed = timer.time_layer(path)
            t_plan = time.perf_counter() - t0
            runs = [i for i in timed.items if isinstance(i, TimedRun)]
            ours = sum(r.profile.duration_s for r in runs)
            bound = sum(toppra_time(timer, r, feed / 60.0) for r in runs)
            ratio = ours / bound
            worst = max(worst, ratio)
            print(f"  F{feed:<6g} layer {layer.name}: ruckig {ours:8.2f} s  toppra {bound:8.2f} s  "
                  f"ratio {ratio:6.3f}   planning {t_plan * 1e3:6.0f} ms/layer "
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
