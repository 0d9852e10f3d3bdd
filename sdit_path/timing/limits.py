"""Path limits along a run that keep every machine axis within its own limits.

With ``s`` the path parameter (the ball's arc length in the table frame, or the arc
length of the machine's axis path: :class:`~sdit_path.timing.trajectory.RunParameter`)
and ``q_i(s)`` an axis value,

    dq_i/dt    = q_i' v
    d2q_i/dt2  = q_i'' v^2 + q_i' a
    d3q_i/dt3  = q_i''' v^3 + 3 q_i'' v a + q_i' j

for path speed ``v``, acceleration ``a`` and jerk ``j``.  A run is timed with constant
path limits (v_max, a_max, j_max) such that, with ``m_k`` the largest ``|q_i^(k)|``
over the run,

    m1 v_max                                   <= V_i
    m2 v_max^2 + m1 a_max                      <= A_i
    m3 v_max^3 + 3 m2 v_max a_max + m1 j_max   <= J_i

for every axis, at any |v| <= v_max, |a| <= a_max, |j| <= j_max.  Tight curvature (or
a fast-turning rotary axis) eats into the acceleration and jerk budgets as v_max
grows.  Runs are cut into short windows, each with a :class:`Budget` that gives the
usable path acceleration and jerk as a function of the speed it runs at; the speed
changes, which may span several windows, are scheduled by
:func:`~sdit_path.timing.profile.plan_chain`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True)
class PathLimits:
    """Constant limits of one run along arc length (mm/s, mm/s^2, mm/s^3); ``binding``
    names what set v_max (``feed``, ``<axis> velocity``, or ``<axis> curvature`` when
    an axis' acceleration or jerk budget made a lower speed faster overall)."""

    v_max: float
    a_max: float
    j_max: float
    binding: str


@dataclass(frozen=True, slots=True)
class Budget:
    """What a stretch of path leaves of the axes' budgets at a given path speed.

    ``m1, m2, m3 : (n_axes,)`` are the largest first, second and third derivatives of
    the axis values along the stretch; ``v_cap`` the highest speed it allows (feed, axis
    velocity, or 95 % of the speed at which curvature alone would use an axis' whole
    acceleration or jerk)."""

    m1: np.ndarray
    m2: np.ndarray
    m3: np.ndarray
    a_limit: np.ndarray
    j_limit: np.ndarray
    v_cap: float
    binding: str
    jerk_share: float = 0.5
    _rows: tuple = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        # per axis (m1, m2, m3, a_limit, j_limit) as floats: ``at`` is called hundreds
        # of thousands of times per layer on 3-6 axes, where numpy's per-call cost rules
        rows = tuple(zip(*(np.asarray(x, dtype=float).tolist() for x in
                           (self.m1, self.m2, self.m3, self.a_limit, self.j_limit))))
        object.__setattr__(self, "_rows", rows)

    def at(self, v: float) -> tuple[float, float]:
        """Path acceleration and jerk limits usable at path speeds up to ``v``."""
        # plain comparisons rather than min(): this runs millions of times per 5-axis
        # layer, and each builtin call costs more than the arithmetic it guards
        v = min(max(v, 0.0), self.v_cap)
        v3 = v ** 3
        share = self.jerk_share
        a = math.inf
        for m1, m2, m3, a_lim, j_lim in self._rows:
            x = (a_lim - m2 * v * v) / m1
            if x < a:
                a = x
            if m2 * v > 1e-12:
                x = share * (j_lim - m3 * v3) / (3.0 * m2 * v)
                if x < a:
                    a = x
        j = math.inf
        for m1, m2, m3, _, j_lim in self._rows:
            x = (j_lim - m3 * v3 - 3.0 * m2 * v * a) / m1
            if x < j:
                j = x
        return a, j

    def limits(self, v: float) -> PathLimits:
        a, j = self.at(v)
        return PathLimits(float(v), a, j, self.binding)

    def weaker(self, other: Budget) -> Budget:
        """A budget that holds on both stretches (largest derivatives, lowest cap)."""
        return Budget(np.maximum(self.m1, other.m1), np.maximum(self.m2, other.m2),
                      np.maximum(self.m3, other.m3), self.a_limit, self.j_limit,
                      min(self.v_cap, other.v_cap),
                      self.binding if self.v_cap <= other.v_cap else other.binding,
                      self.jerk_share)


def budget(d1: np.ndarray, d2: np.ndarray, d3: np.ndarray, v_limit: np.ndarray,
           a_limit: np.ndarray, j_limit: np.ndarray, names: tuple[str, ...], feed: float,
           cruise_share: float = 0.95) -> Budget:
    """The :class:`Budget` of a stretch from its axis derivatives ``(n, n_axes)``."""
    tiny = 1e-12
    m1 = np.maximum(np.abs(d1).max(axis=0), tiny)
    m2 = np.abs(d2).max(axis=0)
    m3 = np.abs(d3).max(axis=0)
    caps = {"feed": feed}
    for i, n in enumerate(names):
        caps[f"{n} velocity"] = v_limit[i] / m1[i]
        cap = np.inf
        if m2[i] > tiny:
            cap = min(cap, np.sqrt(a_limit[i] / m2[i]))
        if m3[i] > tiny:
            cap = min(cap, np.cbrt(j_limit[i] / m3[i]))
        caps[f"{n} curvature"] = cruise_share * cap
    binding = min(caps, key=caps.get)
    return Budget(m1, m2, m3, np.asarray(a_limit, dtype=float), np.asarray(j_limit, dtype=float),
                  float(caps[binding]), binding)
