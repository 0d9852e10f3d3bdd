"""Clearance along a run: every pose (path spacing <= ``check.pose_spacing_mm``), every
checked pair; per piece the minimum clearance, the pair and where it occurs, and a
collision violation when it falls below ``check.safety_clearance_mm``.

Every (pose, pair) gets a cheap vectorised lower bound first; fcl is asked for the
exact distance in increasing order of that bound, until the bound of every remaining
(pose, pair) is at least the smallest exact distance found.  So each pose is checked
against each pair, and the reported minimum is exactly the one an exhaustive fcl scan
would give, at a fraction of the calls."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..machine.poses import RunPoses
from ..machine.reach import Violation, point_tuple
from .scene import Scene


@dataclass(frozen=True, slots=True)
class Clearance:
    """Smallest clearance of one piece: ``value_mm``, the pair, the ball centre
    (table frame) and the nearest points of the two parts (bed frame)."""

    value_mm: float
    pair: tuple[str, str]
    ball_mm: tuple[float, float, float]
    contact_mm: tuple[tuple[float, float, float], tuple[float, float, float]]


def run_clearances(poses: RunPoses, scene: Scene, safety_mm: float
                   ) -> tuple[dict[int, Clearance], dict[int, list[Violation]]]:
    """Minimum clearance per piece index, and collision violations per piece index."""
    if not scene.pairs:
        return {}, {}
    world = scene.part_poses(poses.q)
    lower = scene.lower_bounds(world)
    out: dict[int, Clearance] = {}
    violations: dict[int, list[Violation]] = {}
    for k in np.unique(poses.piece):
        sel = np.where(poses.piece == k)[0]
        lb = lower[sel].ravel()
        order = np.argsort(lb, kind="stable")
        best, best_at = np.inf, (0, 0)
        hits = set()
        for flat in order:
            if lb[flat] >= best and lb[flat] >= safety_mm:
                break
            i, pair = sel[flat // len(scene.pairs)], int(flat % len(scene.pairs))
            d = scene.exact(world, i, pair)
            if d < safety_mm:
                hits.add(scene.pair_names[pair])
            if d < best:
                best, best_at = d, (i, pair)
        i, pair = best_at
        a, b = scene.nearest_points(poses.q[i], pair)
        c = Clearance(float(best), scene.pair_names[pair], point_tuple(poses.points_mm[i]),
                      (point_tuple(a), point_tuple(b)))
        out[int(k)] = c
        if c.value_mm < safety_mm:
            others = sorted(f"{x}/{y}" for x, y in hits - {c.pair})
            detail = (f", contact near ({', '.join(f'{v:.1f}' for v in a)}) mm bed frame"
                      + (f"; also {', '.join(others)}" if others else ""))
            violations[int(k)] = [Violation("collision", f"{c.pair[0]}/{c.pair[1]}", c.value_mm,
                                            safety_mm, safety_mm - c.value_mm, "mm", c.ball_mm,
                                            detail)]
    return out, violations
