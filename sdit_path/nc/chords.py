"""3-D chords on the sphere for controllers without a 3-D spline (LinuxCNC).

Vertices are taken on the fitted spline, pushed radially onto the sphere and rounded
as they will be printed.  A chord between two points of the sphere dips inside it by
its sagitta, ``R - sqrt(R^2 - c^2 / 4) ~ c^2 / (8 R)``, whatever the curve does, so the
chord length follows from the tolerance.  The achieved deviation is then computed
exactly for every chord (rounding included) rather than assumed.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import PlanError
from ..fixed_point import round_to_decimals
from ..geometry.nurbs import BSplineCurve


def chord_deviation(a: np.ndarray, b: np.ndarray, centre_mm: np.ndarray,
                    radius_mm: float) -> np.ndarray:
    """Largest ``|radial deviation|`` (mm) along each chord ``a[i] -> b[i]``, exact."""
    pa, pb = a - centre_mm, b - centre_mm
    d = pb - pa
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(-np.einsum("ij,ij->i", pa, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    closest = np.linalg.norm(pa + t[:, None] * d, axis=1)
    ra, rb = np.linalg.norm(pa, axis=1), np.linalg.norm(pb, axis=1)
    # the distance to the centre along a segment is convex: extremes are the ends
    # (farthest) and the closest point
    return np.maximum.reduce([np.abs(ra - radius_mm), np.abs(rb - radius_mm),
                              np.abs(closest - radius_mm)])


def chords_for_range(curve: BSplineCurve, u0: float, u1: float, centre_mm: np.ndarray,
                     radius_mm: float, tolerance_mm: float, decimals: int,
                     label: str, start_mm: np.ndarray | None = None,
                     end_mm: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Vertices ``(k, 3)`` after the start of ``[u0, u1]`` and the achieved deviation.

    The first vertex (at ``u0``) is the current position and is not returned;
    ``start_mm`` / ``end_mm`` pin the first / last vertex to points already emitted
    elsewhere (a static node), so the program dwells exactly where it says.
    """
    rounding = 0.5 * 10.0 ** (-decimals) * math.sqrt(3.0)
    budget = tolerance_mm - rounding
    if budget <= 0:
        raise PlanError(f"{label}: post.decimals = {decimals} cannot hold the chord tolerance "
                        f"{tolerance_mm * 1e3:g} um; raise post.decimals")
    chord = math.sqrt(8.0 * radius_mm * budget) * 0.98
    probe = curve.evaluate(np.linspace(u0, u1, 257))
    length = float(np.linalg.norm(np.diff(probe, axis=0), axis=1).sum())
    count = max(1, math.ceil(length / chord))
    for _ in range(8):
        u = np.linspace(u0, u1, count + 1)
        p = curve.evaluate(u) - centre_mm
        p = centre_mm + p * (radius_mm / np.linalg.norm(p, axis=1))[:, None]
        p = round_to_decimals(p, decimals)
        if start_mm is not None:
            p[0] = start_mm
        if end_mm is not None:
            p[-1] = end_mm
        dev = chord_deviation(p[:-1], p[1:], centre_mm, radius_mm)
        worst = float(dev.max())
        if worst <= tolerance_mm:
            return p[1:], worst
        count = math.ceil(count * 1.1) + 1
    raise PlanError(f"{label}: chords could not meet {tolerance_mm * 1e3:g} um "
                    f"(best {worst * 1e3:.4f} um)")
