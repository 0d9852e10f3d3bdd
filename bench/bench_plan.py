"""Whole-hemisphere plan and post for a config (default: the bundled sample).

Prints, measured in this one run:
- wall time of partition + curve fitting, and of posting (per controller);
- block counts per program;
- the largest radial deviation from the sphere per controller;
- the ratio of NC blocks the BSPLINE program needs to a G1 polyline at the *same*
  radial tolerance (the 840D spline tolerance), on the same paths.

    python bench/bench_plan.py [CONFIG]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from sdit_path import __version__
from sdit_path.config import load_config
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.interference.scene import Scene
from sdit_path.machine.kinematics import Kinematics
from sdit_path.nc.chords import ChordLimits, run_chords
from sdit_path.nc.words import count_blocks
from sdit_path.plan.pipeline import check_layer, post_layer

from memory import peak_memory_line


def main(argv: list[str]) -> None:
    cfg = load_config(argv[1] if len(argv) > 1 else None)
    t0 = time.perf_counter()
    hemi = partition(cfg)
    builder = PathBuilder(cfg, hemi)
    paths = [builder.layer_path(layer) for layer in hemi.layers]
    t_plan = time.perf_counter() - t0
    t1 = time.perf_counter()
    kin = Kinematics(cfg.machine)
    scene = Scene(cfg, kin)
    for path in paths:
        check_layer(path, cfg, kin, scene)
    t_check = time.perf_counter() - t1
    t_post, progs = {}, []
    for controller in cfg.post.controllers:
        t1 = time.perf_counter()
        progs += [post_layer(p, cfg, hemi, controller) for p in paths]
        t_post[controller] = time.perf_counter() - t1
    total = time.perf_counter() - t0

    print(f"sdit-path {__version__} bench_plan: {cfg.source}, R {hemi.radius_mm:g} mm, "
          f"{hemi.segment_count} segments")
    print(f"plan (partition + fit)        {t_plan:8.3f} s")
    print(f"check (reach + interference)  {t_check:8.3f} s")
    for c, t in t_post.items():
        print(f"post {c:<24} {t:8.3f} s")
    print(f"total                         {total:8.3f} s")
    print()
    print(f"{'program':<28}{'blocks':>8}{'max radial dev [um]':>22}")
    for p in progs:
        print(f"{p.file:<28}{count_blocks(p.text):>8}{p.built.max_deviation_mm * 1e3:>22.5f}")
    for c in cfg.post.controllers:
        worst = max(p.built.max_deviation_mm for p in progs if p.controller == c)
        print(f"max radial deviation {c}: {worst * 1e3:.5f} um")

    # BSPLINE vs G1 polyline at equal radial tolerance, same paths, motion blocks only
    tol = cfg.post.spline_tolerance_um * 1e-3
    spline_blocks = sum(len(r.curve.control_points_mm) - 1 for p in paths for r in p.runs)
    # (the table-frame spline; 5-axis machine-axis programs are fitted separately)
    chord_blocks = 0
    limits = ChordLimits(radial_mm=tol, curve_mm=cfg.post.chord_curve_tolerance_um * 1e-3)
    for p in paths:
        for r in p.runs:
            start = np.asarray(r.curve.control_points_mm[0], dtype=float)
            chords = run_chords(r.curve, r.pieces, hemi.centre_mm, hemi.radius_mm, limits,
                                cfg.post.decimals, r.pieces[0].id, start_mm=start)
            chord_blocks += len(chords.points_mm)
    print()
    print(f"motion blocks at {tol * 1e3:g} um radial tolerance (chords also within "
          f"{cfg.post.chord_curve_tolerance_um:g} um of the curve), whole hemisphere:")
    print(f"  BSPLINE (SD={cfg.post.spline_degree}) {spline_blocks:>10}")
    print(f"  G1 polyline        {chord_blocks:>10}")
    print(f"  ratio BSPLINE / G1 {spline_blocks / chord_blocks:>10.4f}")


if __name__ == "__main__":
    main(sys.argv)
    print(peak_memory_line())
