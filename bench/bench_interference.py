"""Interference check throughput and whole-hemisphere plan time.

Prints, measured in this one run:
- poses per second of the interference check *including* kinematics (pose sampling,
  rotary schedule, inverse kinematics, part poses, bounds and fcl queries) on the
  5-axis sample, against the target of 20,000 poses/s;
- the number of fcl distance queries the bounded search made, against the number an
  exhaustive scan (every pose x every pair) would make;
- whole-hemisphere plan time (plan, check, post for every controller) for the 3-axis
  and the 5-axis sample.

    python bench/bench_interference.py
"""

from __future__ import annotations

import time

import numpy as np

from sdit_path.config import load_config, sample_path
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.interference.check import run_clearances
from sdit_path.interference.scene import Scene
from sdit_path.machine.kinematics import Kinematics
from sdit_path.machine.poses import layer_poses
from sdit_path.plan.pipeline import plan
from memory import peak_memory_line

TARGET = 20000


def main() -> None:
    cfg = load_config(sample_path("bc_table_5axis.toml"))
    hemi = partition(cfg)
    kin = Kinematics(cfg.machine)
    scene = Scene(cfg, kin)
    builder = PathBuilder(cfg, hemi)
    paths = [builder.layer_path(layer) for layer in hemi.layers]

    calls = 0
    exact = scene.exact

    def counting(*args):
        nonlocal calls
        calls += 1
        return exact(*args)

    scene.exact = counting
    t0 = time.perf_counter()
    n = 0
    worst = np.inf
    for path in paths:
        for rp in layer_poses(path, cfg, kin):
            found, _ = run_clearances(rp, scene, cfg.check.safety_clearance_mm)
            n += len(rp.q)
            worst = min([worst] + [c.value_mm for c in found.values()])
    dt = time.perf_counter() - t0
    rate = n / dt
    print("interference check incl. kinematics, 5-axis sample, whole hemisphere:")
    print(f"  poses {n}, pairs {len(scene.pairs)}, time {dt:.3f} s")
    print(f"  poses/s {rate:,.0f}  (target {TARGET:,}; ratio {rate / TARGET:.2f})")
    print(f"  fcl queries {calls:,} of {n * len(scene.pairs):,} exhaustive "
          f"({calls / (n * len(scene.pairs)):.3f})")
    print(f"  minimum clearance {worst:.4f} mm")
    print()
    for name in ("vmc_3axis.toml", "bc_table_5axis.toml"):
        c = load_config(sample_path(name))
        t0 = time.perf_counter()
        result = plan(c)
        dt = time.perf_counter() - t0
        print(f"whole-hemisphere plan + check + post, {name}: {dt:.2f} s "
              f"({len(result.programs)} programs)")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
