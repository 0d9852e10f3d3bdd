"""Machine-axis representations of a run for five-axis programs.

* ``rotary_controls``: rotary-axis values on the knots of the table-frame spline, for
  840D programs under TRAORI (the control keeps the ball on the programmed table-frame
  spline; the rotary words only say how the table turns meanwhile).
* ``machine_spline``: one B-spline through the machine axis values (X Y Z B C),
  for 840D programs without TRAORI.  The control interpolates the axes, so the ball
  path is FK(spline); the knot count grows until that path, with every control value
  rounded as printed, is within the radial tolerance of the sphere.
* ``machine_chords``: straight moves in machine axis space (LinuxCNC without a TCP
  kinematics): between two vertices every axis moves linearly, so the ball follows
  FK(linear joint path); vertices are added until that stays within the tolerance.

Every function takes the unwrapped azimuth ``carry`` of the previous run and returns
the one to hand to the next, so the rotary angles never jump between runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla
from scipy.interpolate import BSpline

from ..errors import PlanError
from ..fixed_point import round_to_decimals
from ..geometry.nurbs import BSplineCurve
from ..geometry.paths import Run
from ..machine.kinematics import Kinematics
from ..machine.schedule import RotarySchedule


def _uniform_knots(degree: int, a: float, b: float, intervals: int) -> np.ndarray:
    inner = np.linspace(a, b, intervals + 1)
    return np.concatenate([np.full(degree, a), inner, np.full(degree, b)])


def fit_on_knots(knots: np.ndarray, degree: int, u: np.ndarray, values: np.ndarray,
                 start: np.ndarray, end: np.ndarray, start_der: np.ndarray | None = None,
                 end_der: np.ndarray | None = None) -> np.ndarray:
    """Least-squares control values ``(n, k)`` on a clamped knot vector, with the end
    values (and, when given, end derivatives d/du) fixed."""
    n = len(knots) - degree - 1
    q = np.zeros((n, values.shape[1]))
    q[0], q[-1] = start, end
    fixed = [0, n - 1]
    if start_der is not None and n >= 4:
        q[1] = start + start_der * (knots[degree + 1] - knots[1]) / degree
        q[-2] = end - end_der * (knots[-2] - knots[-degree - 2]) / degree
        fixed = [0, 1, n - 2, n - 1]
    free = np.array([i for i in range(n) if i not in fixed])
    if free.size:
        B = BSpline.design_matrix(u, knots, degree).tocsc()
        rhs = values - B[:, fixed] @ q[fixed]
        Bf = B[:, free]
        q[free] = spla.spsolve((Bf.T @ Bf).tocsc(), Bf.T @ rhs).reshape(len(free), -1)
    return q


@dataclass(frozen=True, slots=True)
class AxisTrack:
    """Rotary and machine values of a run, as the schedule makes them."""

    kin: Kinematics
    schedule: RotarySchedule

    def angles(self, points_mm: np.ndarray, carry: float | None):
        return self.schedule.angles(points_mm, carry)

    def q(self, points_mm: np.ndarray, carry: float | None) -> tuple[np.ndarray, float | None]:
        angles, out = self.schedule.angles(points_mm, carry)
        return self.kin.inverse(points_mm, angles), out


def round_axis_values(q: np.ndarray, kin: Kinematics, decimals: int) -> np.ndarray:
    """Round machine values as printed: mm for linear axes, degrees for rotary ones."""
    out = np.array(q, dtype=float)
    for i in kin.rotary:
        out[..., i] = np.radians(round_to_decimals(np.degrees(out[..., i]), decimals))
    for i in kin.linear:
        out[..., i] = round_to_decimals(out[..., i], decimals)
    return out


def rotary_controls(curve: BSplineCurve, track: AxisTrack, carry: float | None, decimals: int
                    ) -> tuple[dict[str, np.ndarray], float | None]:
    """Rotary values (deg, rounded as printed) at the control points of ``curve``."""
    kin = track.kin
    a, b = curve.domain
    u = np.linspace(a, b, 12 * len(curve.control_points_mm))
    angles, carry_out = track.angles(curve.evaluate(u), carry)
    ends, _ = track.angles(curve.evaluate(np.array([a, b])), carry)
    out = {}
    for i in kin.rotary:
        name = kin.names[i]
        vals = np.degrees(angles[name])[:, None]
        e = np.degrees(ends[name])
        ctrl = fit_on_knots(curve.knots, curve.degree, u, vals, e[:1], e[1:])[:, 0]
        out[name] = round_to_decimals(ctrl, decimals)
    return out, carry_out


def _fk_deviation(q_of_u, kin: Kinematics, centre: np.ndarray, radius: float,
                  breaks: np.ndarray, ranges, samples: int = 24) -> list[float]:
    """Largest radial deviation of FK(q(u)) on each range; ``breaks`` are the knots
    (or vertices) between which q is smooth."""
    frac = np.linspace(0.0, 1.0, samples + 1)
    a, b = breaks[:-1], breaks[1:]
    u = (a[:, None] + (b - a)[:, None] * frac[None, :])
    p = kin.forward(q_of_u(u.ravel()))
    dev = np.abs(np.linalg.norm(p - centre, axis=1) - radius).reshape(u.shape)
    worst = np.argmax(dev, axis=1)
    h = (b - a) / samples
    u2 = np.clip(u[np.arange(len(a)), worst][:, None] + h[:, None] * np.linspace(-1, 1, 17)[None, :],
                 a[:, None], b[:, None])
    p2 = kin.forward(q_of_u(u2.ravel()))
    dev2 = np.abs(np.linalg.norm(p2 - centre, axis=1) - radius).reshape(u2.shape)
    per = np.maximum(dev.max(axis=1), dev2.max(axis=1))
    return [float(per[(a >= lo - 1e-12) & (b <= hi + 1e-12)].max()) for lo, hi in ranges]


def _on_sphere(points: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Points pushed radially onto the sphere (the fitted table spline is within
    nanometres of it; machine-space fits aim at the sphere itself)."""
    d = points - centre
    return centre + d * (radius / np.linalg.norm(d, axis=1))[:, None]


def machine_spline(run: Run, track: AxisTrack, carry: float | None, centre: np.ndarray,
                   radius: float, tolerance_mm: float, decimals: int, label: str
                   ) -> tuple[BSplineCurve, list[float], float | None]:
    """A B-spline in machine axis space ``(n, n_axes)`` (mm, rad) whose FK stays within
    ``tolerance_mm`` of the sphere; per-piece deviations; the carry for the next run."""
    kin = track.kin
    curve = run.curve
    a, b = curve.domain
    intervals = len(curve.interval_knots) - 1
    ranges = [(p.u_start, p.u_end) for p in run.pieces]
    def q_at(u):
        return track.q(_on_sphere(curve.evaluate(u), centre, radius), carry)

    exact_ends = q_at(np.array([a, b]))[0]
    ends_q = round_axis_values(exact_ends, kin, decimals)
    h = 1e-6 * (b - a)
    d0 = (q_at(np.array([a + h]))[0][0] - exact_ends[0]) / h
    d1 = (exact_ends[1] - q_at(np.array([b - h]))[0][0]) / h
    for factor in (1, 2, 3, 4, 6, 8):
        m = intervals * factor
        knots = _uniform_knots(curve.degree, a, b, m)
        u = np.linspace(a, b, 10 * m + 1)
        q_samples, carry_out = q_at(u)
        ctrl = fit_on_knots(knots, curve.degree, u, q_samples, ends_q[0], ends_q[1], d0, d1)
        ctrl = round_axis_values(ctrl, kin, decimals)
        spline = BSpline(knots, ctrl, curve.degree, extrapolate=False)
        devs = _fk_deviation(spline, kin, centre, radius, np.unique(knots), ranges)
        if max(devs) <= tolerance_mm:
            return BSplineCurve(curve.degree, knots, ctrl), devs, carry_out
    raise PlanError(f"{label}: machine-axis spline could not keep the ball within "
                    f"{tolerance_mm * 1e3:g} um of the sphere (best {max(devs) * 1e3:.4f} um)")


def _curve_distance(q_of_t, kin: Kinematics, curve: BSplineCurve, u: np.ndarray,
                    samples: int = 8) -> float:
    """Largest distance (mm) of the ball, FK(q(t)) for ``t`` in ``[0, len(u) - 1]``, from
    the planned curve: from the curve point at the same fraction of each chord's
    parameter span, across the curve's tangent there (the along-path offset between
    the two parametrisations is not a distance from the curve)."""
    t = np.linspace(0.0, len(u) - 1.0, (len(u) - 1) * samples + 1)
    i = np.clip(np.floor(t).astype(int), 0, len(u) - 2)
    uu = u[i] + (u[i + 1] - u[i]) * (t - i)
    p = kin.forward(q_of_t(t))
    c = curve.evaluate(uu)
    h = 1e-4 * (u[-1] - u[0])
    lo, hi = curve.domain
    tan = curve.evaluate(np.clip(uu + h, lo, hi)) - curve.evaluate(np.clip(uu - h, lo, hi))
    tan /= np.linalg.norm(tan, axis=1)[:, None]
    d = p - c
    d -= np.einsum("ij,ij->i", d, tan)[:, None] * tan
    return float(np.linalg.norm(d, axis=1).max())


def machine_chords(run: Run, track: AxisTrack, carry: float | None, centre: np.ndarray,
                   radius: float, tolerance_mm: float, decimals: int, start_q: np.ndarray,
                   label: str, curve_tolerance_mm: float = math.inf):
    """Vertices in machine axis space for straight joint-space moves.

    Returns ``(q (k, n_axes), table-frame chord lengths (k,), labels, per-piece
    deviations from the sphere, per-piece distances from the planned curve, carry)``;
    the first vertex (``start_q``, the current position) is not part of ``q``."""
    kin = track.kin
    curve = run.curve
    chord = math.sqrt(8.0 * radius * tolerance_mm) * 0.9
    qs: list[np.ndarray] = []
    labels: list[tuple[int, str]] = []
    devs: list[float] = []
    offs: list[float] = []
    current = start_q
    carry_now = carry
    for k, piece in enumerate(run.pieces):
        count = max(1, math.ceil(1.1 * piece.length_mm / chord))
        for _ in range(12):
            u = np.linspace(piece.u_start, piece.u_end, count + 1)
            p = curve.evaluate(u) - centre
            p = centre + p * (radius / np.linalg.norm(p, axis=1))[:, None]
            q, carry_out = track.q(p, carry_now)
            q = round_axis_values(q, kin, decimals)
            q[0] = current
            breaks = np.arange(count + 1, dtype=float)

            def joint_path(t, q=q):
                i = np.clip(np.floor(t).astype(int), 0, len(q) - 2)
                f = (t - i)[:, None]
                return q[i] * (1 - f) + q[i + 1] * f

            dev = _fk_deviation(joint_path, kin, centre, radius, breaks, [(0.0, float(count))],
                                samples=8)[0]
            off = _curve_distance(joint_path, kin, curve, u)
            if dev <= tolerance_mm and off <= curve_tolerance_mm:
                break
            count = math.ceil(count * 1.25) + 1
        else:
            raise PlanError(f"{label}, {piece.id}: joint-space chords could not keep the ball "
                            f"within {tolerance_mm * 1e3:g} um of the sphere and "
                            f"{curve_tolerance_mm * 1e3:g} um of the planned curve")
        labels.append((sum(len(x) for x in qs), piece.id))
        qs.append(q[1:])
        devs.append(dev)
        offs.append(off)
        current = q[-1]
        carry_now = carry_out
    q_all = np.vstack(qs)
    p_all = kin.forward(np.vstack([start_q[None, :], q_all]))
    lengths = np.linalg.norm(np.diff(p_all, axis=0), axis=1)
    return q_all, lengths, tuple(labels), devs, offs, carry_now
