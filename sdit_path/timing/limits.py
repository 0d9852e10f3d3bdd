"""Path limits along arc length that keep every machine axis within its own limits.

With ``s`` the ball's arc length in the table frame and ``q_i(s)`` an axis value,

    dq_i/dt    = q_i' v
    d2q_i/dt2  = q_i'' v^2 + q_i' a
    d3q_i/dt3  = q_i''' v^3 + 3 q_i'' v a + q_i' j

for path speed ``v``, acceleration ``a`` and jerk ``j``.  A run is timed with constant
path limits (v_max, a_max, j_max); they are chosen so that the worst point of the run,
at any |v| <= v_max, |a| <= a_max, |j| <= j_max, keeps every axis within its limits:
curvature may use ``curvature_share`` of an axis' acceleration budget and the
curvature terms ``jerk_share`` of its jerk budget each, which caps v_max where the path
is tightly curved (or where a rotary axis turns fast); the rest goes to a_max and
j_max.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class PathLimits:
    """Constant limits of one run along arc length (mm/s, mm/s^2, mm/s^3); ``binding``
    names what set v_max (``feed``, or ``<axis> velocity/curvature/jerk``)."""

    v_max: float
    a_max: float
    j_max: float
    binding: str


def path_limits(d1: np.ndarray, d2: np.ndarray, d3: np.ndarray, v_limit: np.ndarray,
                a_limit: np.ndarray, j_limit: np.ndarray, names: tuple[str, ...], feed: float,
                curvature_share: float = 0.5, jerk_share: float = 0.25) -> PathLimits:
    """Limits from the path derivatives ``d1, d2, d3 : (n, n_axes)`` (d/ds of the axis
    values on a grid along the run) and per-axis limits ``(n_axes,)``."""
    m1 = np.abs(d1).max(axis=0)
    m2 = np.abs(d2).max(axis=0)
    m3 = np.abs(d3).max(axis=0)
    tiny = 1e-12
    caps = {"feed": feed}
    for i, n in enumerate(names):
        caps[f"{n} velocity"] = v_limit[i] / max(m1[i], tiny)
        caps[f"{n} curvature"] = math.sqrt(curvature_share * a_limit[i] / max(m2[i], tiny))
        caps[f"{n} jerk"] = (jerk_share * j_limit[i] / max(m3[i], tiny)) ** (1.0 / 3.0)
    binding = min(caps, key=caps.get)
    v = caps[binding]
    # acceleration: what curvature leaves, and what the 3 q'' v a jerk term may take
    a_caps = [(a_limit[i] - m2[i] * v * v) / max(m1[i], tiny) for i in range(len(names))]
    a_caps += [jerk_share * j_limit[i] / max(3.0 * m2[i] * v, tiny) for i in range(len(names))]
    a = min(a_caps)
    j = min((j_limit[i] - m3[i] * v ** 3 - 3.0 * m2[i] * v * a) / max(m1[i], tiny)
            for i in range(len(names)))
    return PathLimits(v, a, j, binding)
