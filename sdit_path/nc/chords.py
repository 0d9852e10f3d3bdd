"""3-D chords on the sphere for controllers without a 3-D spline (LinuxCNC).

Vertices are taken on the fitted spline, pushed radially onto the sphere and rounded
as they will be printed.  Three things bound a chord:

* the sphere: a chord between two points of the sphere dips inside it by its sagitta,
  ``R - sqrt(R^2 - c^2 / 4) ~ c^2 / (8 R)``, whatever the curve does (a hard limit);
* the planned curve: where the curve bends on the sphere (a wave's crest), a chord
  cuts across the bend by ``~ c^2 kappa / 8`` (a hard limit, so that the ball is where
  the plan says it is along the path, not only at the right distance);
* the corner at each vertex: a control joins two straight moves at the feed only when
  the turn between them is small (:class:`CornerModel`); larger turns make it slow
  down or round the corner within ``G64 P``, which at our tolerance nearly stops it
  (a soft limit: chords are shortened towards the control's shortest useful block).

Every achieved figure is computed for every chord as emitted (rounding included)
rather than assumed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import minimum_filter1d

from ..errors import PlanError
from ..fixed_point import round_to_decimals
from ..geometry.nurbs import BSplineCurve


@dataclass(frozen=True, slots=True)
class CornerModel:
    """When a control joins two straight moves without slowing.

    LinuxCNC 2.9 (``tp.c``) tries two ways.  A tangent join (``tpSetupTangent``) treats
    the direction change as taken within one servo period at the segments' top speed:
    an acceleration ``(v / T + a) * |t2 - t1|`` per axis, which must stay within
    ``kink_ratio`` of the axis' limit.  Otherwise it rounds the corner with an arc
    within ``G64 P`` (``tpCreateLineLineBlend``): for a turn ``theta`` the arc's radius
    is at most about ``8 P / theta^2``, passed at ``sqrt(a_n r)`` with ``a_n`` the
    normal share of the acceleration (``BLEND_ACC_RATIO_NORMAL``), and an arc shorter
    than a few servo periods at speed is useless.  ``margin`` leaves room for a feed
    override above 100 % and for what this model leaves out; a block shorter than about
    one servo period at its speed is slowed too (``TP_MIN_SEGMENT_CYCLES``), so chords
    are never shortened below ``min_block_periods`` periods at the feed."""

    servo_period_s: float
    kink_ratio: float
    normal_accel_ratio: float
    min_arc_periods: float
    margin: float
    min_block_periods: float

    def turn_limit_rad(self, feed_mm_per_s: float, accelerations_mm_per_s2,
                       tolerance_mm: float) -> float:
        """The largest turn between consecutive chords joined at ``feed_mm_per_s``
        with corners rounded within ``tolerance_mm``."""
        a = np.asarray(accelerations_mm_per_s2, dtype=float)
        v, T = feed_mm_per_s, self.servo_period_s
        tangent = self.kink_ratio * float(a.min()) / (v / T + float(a.max()))
        by_speed = math.sqrt(8.0 * tolerance_mm * self.normal_accel_ratio * float(a.min())) / v
        by_length = 8.0 * tolerance_mm / (self.min_arc_periods * v * T)
        return self.margin * max(tangent, min(by_speed, by_length))

    def shortest_chord_mm(self, feed_mm_per_s: float) -> float:
        return self.min_block_periods * self.servo_period_s * feed_mm_per_s


@dataclass(frozen=True, slots=True)
class ChordLimits:
    """What the chords of one run must hold: ``radial_mm`` from the sphere and
    ``curve_mm`` from the planned curve (hard), ``turn_rad`` between consecutive chords
    (soft, not pursued below ``shortest_mm``)."""

    radial_mm: float
    curve_mm: float
    turn_rad: float = math.pi
    shortest_mm: float = 0.0


@dataclass(frozen=True, slots=True)
class RunChords:
    """The chords of one run.  ``points_mm : (k, 3)`` the vertices after the run's start
    (the current position); ``labels``: (vertex index, piece id) where each piece's
    vertices begin; per piece the largest radial deviation from the sphere and the
    largest distance from the planned curve (mm); the largest turn between consecutive
    chords (rad) and how many vertices turn more than the limit."""

    points_mm: np.ndarray
    labels: tuple[tuple[int, str], ...]
    radial_mm: tuple[float, ...]
    curve_mm: tuple[float, ...]
    max_turn_rad: float
    sharp_corners: int


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


def turn_angles(points: np.ndarray) -> np.ndarray:
    """Angle (rad) between consecutive chords at every interior vertex ``(k - 2,)``."""
    d = np.diff(points, axis=0)
    n = np.linalg.norm(d, axis=1)
    u = d / np.where(n > 0, n, 1.0)[:, None]
    c = np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1.0, 1.0)
    # atan2 of the cross and the dot keeps tiny angles exact
    s = np.linalg.norm(np.cross(u[:-1], u[1:]), axis=1)
    return np.arctan2(s, c)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points ``p (m, k, 3)`` to the segments ``a[m] -> b[m]``."""
    d = (b - a)[:, None, :]
    dd = np.maximum(np.einsum("mij,mij->mi", d, d), 1e-300)
    t = np.clip(np.einsum("mkj,mij->mk", p - a[:, None, :], d) / dd, 0.0, 1.0)
    return np.linalg.norm(a[:, None, :] + t[..., None] * d - p, axis=2)


def curve_deviation(curve: BSplineCurve, u: np.ndarray, points: np.ndarray,
                    centre_mm: np.ndarray, radius_mm: float, samples: int = 12) -> np.ndarray:
    """Largest distance (mm) of the planned path between ``u[i]`` and ``u[i + 1]`` from
    the chord ``points[i] -> points[i + 1]``, on ``samples`` points of each stretch.  The
    planned path is the curve pushed radially onto the sphere, as the vertices are (a
    coarse spline tolerance would otherwise count as the chords' fault)."""
    f = np.linspace(0.0, 1.0, samples + 1)[1:-1]
    uu = u[:-1, None] + (u[1:] - u[:-1])[:, None] * f[None, :]
    c = curve.evaluate(uu.ravel()) - centre_mm
    c = centre_mm + c * (radius_mm / np.linalg.norm(c, axis=1))[:, None]
    c = c.reshape(len(u) - 1, len(f), 3)
    return _segment_distance(c, points[:-1], points[1:]).max(axis=1)


def _spacing(curve: BSplineCurve, u0: float, u1: float, limits: ChordLimits,
             chord_radial: float, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Dense parameters of ``[u0, u1]`` and the chord length wanted at each (mm)."""
    u = np.linspace(u0, u1, samples)
    p = curve.evaluate(u)
    d = np.diff(p, axis=0)
    ds = np.linalg.norm(d, axis=1)
    turn = turn_angles(p) if len(p) > 2 else np.zeros(0)
    kappa = np.zeros(len(u))
    if len(turn):
        kappa[1:-1] = turn / np.maximum(0.5 * (ds[:-1] + ds[1:]), 1e-12)
        kappa[0], kappa[-1] = kappa[1], kappa[-2]
    k = np.maximum(kappa, 1e-9)
    by_curve = np.sqrt(8.0 * 0.8 * limits.curve_mm / k)
    by_turn = np.maximum(0.8 * limits.turn_rad / k, limits.shortest_mm)
    want = np.minimum.reduce([np.full(len(u), chord_radial), by_curve, by_turn])
    # a chord sees the bend ahead of it: the wanted length is the smallest within the
    # reach of the longest chord (the refinement below makes it exact)
    window = int(min(len(u), max(1, math.ceil(chord_radial / max(float(ds.mean()), 1e-12)))))
    return u, minimum_filter1d(want, size=2 * window + 1, mode="nearest")


#: the 27 grid neighbours of a point (itself included first)
_NEIGHBOURS = np.array(sorted(((i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1)
                               for k in (-1, 0, 1)), key=lambda o: sum(map(abs, o))), float)


def coarse_grid(decimals: int, radial_mm: float) -> bool:
    """Whether rounding to ``decimals`` would take more than a quarter of the radial
    tolerance (a control that reads 3 or 4 decimals): then every vertex goes to the grid
    point nearest the sphere among its 27 neighbours (:func:`snap_to_sphere`), within
    half a step of it instead of up to sqrt(3) / 2 steps."""
    return 0.5 * 10.0 ** (-decimals) * math.sqrt(3.0) > 0.25 * radial_mm


def on_grid(points_mm: np.ndarray, centre_mm: np.ndarray, radius_mm: float, decimals: int,
            radial_mm: float) -> np.ndarray:
    """Points of the sphere as a chord program writes them: rounded, and on a coarse
    grid moved to the grid point nearest the sphere."""
    p = round_to_decimals(np.atleast_2d(points_mm), decimals)
    if coarse_grid(decimals, radial_mm):
        p = snap_to_sphere(p, centre_mm, radius_mm, decimals)
    return p.reshape(np.shape(points_mm))


def snap_to_sphere(points_mm: np.ndarray, centre_mm: np.ndarray, radius_mm: float,
                   decimals: int) -> np.ndarray:
    """``points_mm : (n, 3)`` on the ``decimals`` grid, each moved to the grid point
    nearest the sphere among its 27 neighbours (the nearest to it among equals):
    within half a grid step of the sphere."""
    step = 10.0 ** (-decimals)
    # the points are on the grid already: their neighbours are a step away, far from
    # any rounding boundary, and only the chosen ones are rounded as printed
    cand = points_mm[:, None, :] + _NEIGHBOURS[None, :, :] * step
    err = np.abs(np.linalg.norm(cand - centre_mm, axis=2) - radius_mm)
    best = np.argmin(err + 1e-9 * step * np.abs(_NEIGHBOURS).sum(axis=1)[None, :], axis=1)
    return round_to_decimals(cand[np.arange(len(cand)), best], decimals)


def run_chords(curve: BSplineCurve, pieces, centre_mm: np.ndarray, radius_mm: float,
               limits: ChordLimits, decimals: int, label: str, start_mm: np.ndarray,
               end_mm: np.ndarray | None = None) -> RunChords:
    """The chords of one run along ``curve`` over ``pieces`` (each with ``id``,
    ``u_start``, ``u_end``, ``length_mm``), from ``start_mm`` (the current position) to
    ``end_mm`` when given (a static node: the program dwells exactly where it says)."""
    snap = coarse_grid(decimals, limits.radial_mm)
    rounding = 0.5 * 10.0 ** (-decimals) * (1.0 if snap else math.sqrt(3.0))
    budget = limits.radial_mm - rounding
    if budget <= 0:
        raise PlanError(f"{label}: post.decimals = {decimals} cannot hold the chord tolerance "
                        f"{limits.radial_mm * 1e3:g} um; raise post.decimals")
    chord_radial = math.sqrt(8.0 * radius_mm * budget) * 0.98
    us: list[np.ndarray] = []
    for piece in pieces:
        fine = max(limits.shortest_mm, 1e-3) * 0.25
        samples = int(min(20001, max(257, math.ceil(piece.length_mm / fine))))
        u, want = _spacing(curve, piece.u_start, piece.u_end, limits, chord_radial, samples)
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(curve.evaluate(u), axis=0), axis=1))]
        n = np.r_[0.0, np.cumsum(np.diff(s) / (0.5 * (want[1:] + want[:-1])))]
        count = max(1, math.ceil(n[-1]))
        us.append(np.interp(np.linspace(0.0, n[-1], count + 1), n, u))
    first = [0]
    for u in us[:-1]:
        first.append(first[-1] + len(u) - 1)
    u_all = np.concatenate([us[0]] + [u[1:] for u in us[1:]])

    def vertices(u_all: np.ndarray) -> np.ndarray:
        p = curve.evaluate(u_all) - centre_mm
        p = centre_mm + p * (radius_mm / np.linalg.norm(p, axis=1))[:, None]
        p = round_to_decimals(p, decimals)
        if snap:
            p = snap_to_sphere(p, centre_mm, radius_mm, decimals)
        p[0] = start_mm
        if end_mm is not None:
            p[-1] = end_mm
        return p

    def measure(u_all: np.ndarray):
        p = vertices(u_all)
        return (p, chord_deviation(p[:-1], p[1:], centre_mm, radius_mm),
                curve_deviation(curve, u_all, p, centre_mm, radius_mm))

    p, radial, off = measure(u_all)
    for _ in range(30):
        length = np.linalg.norm(np.diff(p, axis=0), axis=1)
        split = (radial > limits.radial_mm) | (off > limits.curve_mm)
        sharp = np.flatnonzero(turn_angles(p) > limits.turn_rad)  # at vertex sharp + 1
        for c in np.unique(np.r_[sharp, sharp + 1]):
            if length[c] >= 2.0 * limits.shortest_mm:
                split[c] = True
        if not split.any() or length[split].min() < 1e-4:  # 0.1 um chords: give up
            break
        # midpoints only: every vertex already placed keeps its place
        idx = np.flatnonzero(split) + 1
        u_all = np.insert(u_all, idx, 0.5 * (u_all[:-1] + u_all[1:])[split])
        first = [f + int(np.searchsorted(idx, f, side="right")) for f in first]
        p, radial, off = measure(u_all)
    if (radial > limits.radial_mm).any() or (off > limits.curve_mm).any():
        worst = max(float((radial / limits.radial_mm).max()), float((off / limits.curve_mm).max()))
        raise PlanError(f"{label}: chords could not meet {limits.radial_mm * 1e3:g} um from the "
                        f"sphere and {limits.curve_mm * 1e3:g} um from the curve "
                        f"(worst at {worst:.2f} times its limit)")
    bounds = first + [len(u_all) - 1]
    per_radial = tuple(float(radial[a:b].max()) for a, b in zip(bounds[:-1], bounds[1:]))
    per_curve = tuple(float(off[a:b].max()) for a, b in zip(bounds[:-1], bounds[1:]))
    turn = turn_angles(p)
    return RunChords(points_mm=p[1:], labels=tuple((f, piece.id) for f, piece in zip(first, pieces)),
                     radial_mm=per_radial, curve_mm=per_curve,
                     max_turn_rad=float(turn.max()) if len(turn) else 0.0,
                     sharp_corners=int((turn > limits.turn_rad * (1 + 1e-9)).sum()))
