"""Clearance along a run: every pose (path spacing <= ``check.pose_spacing_mm``), every
checked pair; per piece the minimum clearance, the pair and where it occurs, and a
collision violation when it falls below ``check.safety_clearance_mm``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..machine.poses import RunPoses
from ..machine.reach import Violation, _point
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
    d = scene.clearances(poses.q)
    best_pair = np.argmin(d, axis=1)
    best = d[np.arange(len(d)), best_pair]
    out: dict[int, Clearance] = {}
    violations: dict[int, list[Violation]] = {}
    for k in np.unique(poses.piece):
        sel = np.where(poses.piece == k)[0]
        i = sel[int(np.argmin(best[sel]))]
        pair = int(best_pair[i])
        a, b = scene.nearest_points(poses.q[i], pair)
        c = Clearance(float(best[i]), scene.pair_names[pair], _point(poses.points_mm[i]),
                      (_point(a), _point(b)))
        out[int(k)] = c
        if c.value_mm < safety_mm:
            hits = {scene.pair_names[p] for p in np.unique(best_pair[sel][best[sel] < safety_mm])}
            others = sorted(f"{x}/{y}" for x, y in hits - {c.pair})
            detail = (f", contact near ({', '.join(f'{v:.1f}' for v in a)}) mm bed frame"
                      + (f"; also {', '.join(others)}" if others else ""))
            violations[int(k)] = [Violation("collision", f"{c.pair[0]}/{c.pair[1]}", c.value_mm,
                                            safety_mm, safety_mm - c.value_mm, "mm", c.ball_mm,
                                            detail)]
    return out, violations
