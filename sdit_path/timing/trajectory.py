"""Timed trajectories: where the machine is at every moment of a layer program.

Every run (dwell to dwell) is timed by ruckig along the ball's arc length or, where
that is quicker on a machine with rotary axes, along the arc length of the machine's
axis path (:class:`RunParameter`), with limits from :mod:`~sdit_path.timing.limits`;
where anything but the feed binds, by its time-optimal speed law
(:mod:`~sdit_path.timing.topp`) if that is quicker;
at every static node the machine rests for the dwell; where a program steps over
left-out segments (bar off) it repositions along straight lines, rest to rest.  The
program's own first positioning move (from wherever the machine was) is not part of
the trajectory: time 0 is the start of the first dwell.

``sample`` turns a timed layer into arrays at a fixed rate (written as the
trajectory file by :mod:`sdit_path.plan.trajectory_csv`): ``t_s``, the ball centre in the table frame (``ball_x_mm`` ...), every
machine axis (``axis_X_mm`` ... ``axis_C_deg``), ``segment``, ``phase`` (accelerate,
cruise, decelerate, dwell, reposition) and ``path_speed_mm_per_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, PPoly, make_interp_spline, make_lsq_spline

from ..config import Config
from ..fixed_point import round_to_decimals
from ..geometry.paths import Dwell, LayerPath, Remount, Run
from ..machine.kinematics import Kinematics
from ..machine.schedule import RotarySchedule
from .limits import Budget, PathLimits, budget
from . import topp
from .profile import PHASES, ChainProfile, Profile, plan_chain, plan_profile
from .topp import SpeedLaw


def quintic_hermite(x: np.ndarray, y: np.ndarray, dy: np.ndarray, ddy: np.ndarray) -> PPoly:
    """The piecewise quintic through ``(x, y)`` with first and second derivatives
    ``dy``, ``ddy`` at every sample (``x`` increasing): C2, exact where its data are."""
    h = np.diff(x)
    dy_ = np.diff(y)  # the step, not the values: no cancellation of large coordinates
    d0, d1, c0, c1 = dy[:-1] * h, dy[1:] * h, ddy[:-1] * h * h, ddy[1:] * h * h
    t = [y[:-1], d0, 0.5 * c0,
         10 * dy_ - 6 * d0 - 4 * d1 - 1.5 * c0 + 0.5 * c1,
         -15 * dy_ + 8 * d0 + 7 * d1 + 1.5 * c0 - c1,
         6 * dy_ - 3 * d0 - 3 * d1 - 0.5 * c0 + 0.5 * c1]
    coeffs = np.array([t[k] / h ** k for k in range(5, -1, -1)])
    return PPoly(coeffs, x)


class RunGeometry:
    """Arc length <-> parameter of a run's fitted spline, and points along it.

    Arc length comes from 5-point Gauss-Legendre quadrature of |C'(u)| on a fine grid
    (exact to ~1e-13 relative); its inverse u(s) is a quintic interpolant, whose third
    derivative is continuous: a cubic one would put a staircase into the third
    derivative of every position, and so into the jerk the trajectory is checked for."""

    def __init__(self, run: Run, per_interval: int = 24):
        curve = run.curve
        knots = curve.interval_knots
        frac = np.linspace(0.0, 1.0, per_interval + 1)[:-1]
        u = (knots[:-1, None] + np.diff(knots)[:, None] * frac[None, :]).ravel()
        u = np.append(u, knots[-1])
        deriv = BSpline(curve.knots, curve.control_points_mm, curve.degree).derivative()
        nodes, weights = np.polynomial.legendre.leggauss(5)
        a, b = u[:-1], u[1:]
        mid, half = 0.5 * (a + b), 0.5 * (b - a)
        x = mid[:, None] + half[:, None] * nodes[None, :]
        speed = np.linalg.norm(deriv(x.ravel()), axis=1).reshape(x.shape)
        seg = half * (speed @ weights)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self.run = run
        self.curve = curve
        self.length_mm = float(s[-1])
        # u(s) from its exact first two derivatives at every sample (quintic Hermite):
        # an interpolant through the values alone rings in its third derivative where
        # the spline's knots make u''' jump, and the jerk of every axis follows u'''
        second = BSpline(curve.knots, curve.control_points_mm, curve.degree).derivative(2)
        d1, d2 = deriv(u), second(u)
        speed = np.linalg.norm(d1, axis=1)
        ddu = -np.einsum("ij,ij->i", d1, d2) / speed ** 4
        self._u_of_s = quintic_hermite(s, u, 1.0 / speed, ddu)
        self._s_of_u = make_interp_spline(u, s, k=5)

    def u(self, s: np.ndarray) -> np.ndarray:
        a, b = self.curve.domain
        return np.clip(self._u_of_s(np.clip(s, 0.0, self.length_mm)), a, b)

    def s(self, u: np.ndarray) -> np.ndarray:
        return self._s_of_u(u)

    def points(self, s: np.ndarray) -> np.ndarray:
        return self.curve.evaluate(self.u(s))


class RunParameter:
    """What a run is timed along: the arc length of the machine's axis path.

    It counts every linear axis in mm and every rotary axis at ``a_ref / A_r`` mm per
    rad (``a_ref`` the smallest linear acceleration limit, ``A_r`` the rotary axis'
    own), and is scaled to the length of the ball's path, so that windows of a given
    length are as many along either.  The identity map (no ``s_of_sigma``) is the
    ball's arc length ``s`` itself.  Where a table turns fast under a slow ball, the
    ball's arc length is a poor parameter: the rotary angle bends tightly along it, and
    its curvature terms (``q'' v^2``, ``q''' v^3``) eat the whole budget of constant
    path limits although the axis itself moves smoothly.  Along the axis path the
    dominant axis moves nearly linearly, and the same limits lose little.

    ``length_mm`` is the length of both; :meth:`s` maps the parameter to the ball's arc
    length, :meth:`ds` is ``ds/dsigma`` (the ball's speed per unit parameter speed);
    both come from one quintic interpolant, whose third derivative is continuous."""

    def __init__(self, length_mm: float, s_of_sigma: BSpline | None = None):
        self.length_mm = float(length_mm)
        self._s = s_of_sigma
        self._ds = None if s_of_sigma is None else s_of_sigma.derivative()

    @property
    def identity(self) -> bool:
        return self._s is None

    def s(self, sigma: np.ndarray) -> np.ndarray:
        """The ball's arc length at parameter values ``sigma``."""
        if self._s is None:
            return sigma
        return np.clip(self._s(np.clip(sigma, 0.0, self.length_mm)), 0.0, self.length_mm)

    def ds(self, sigma: np.ndarray) -> np.ndarray:
        """``ds/dsigma`` at parameter values ``sigma``."""
        if self._ds is None:
            return np.ones_like(np.asarray(sigma, dtype=float))
        return self._ds(np.clip(sigma, 0.0, self.length_mm))


def _smooth_map(x: np.ndarray, y: np.ndarray, knot_mm: float) -> BSpline:
    """A quintic ``y(x)`` through the ends of the samples, fitted to the rest by least
    squares with interior knots about ``knot_mm`` apart.  An interpolant through every
    sample would follow the summation's rounding (1e-12 mm every 5 um), and its third
    derivative, which the jerk of every axis follows, would swing by orders of
    magnitude between samples; the fit keeps the map's shape on the scale of its knots
    and a third derivative of its own."""
    count = max(1, round(float(x[-1] - x[0]) / knot_mm))
    inner = np.linspace(x[0], x[-1], count + 1)[1:-1]
    if len(x) < len(inner) + 12:
        return make_interp_spline(x, y, k=5)
    knots = np.r_[[x[0]] * 6, inner, [x[-1]] * 6]
    w = np.ones(len(x))
    w[[0, -1]] = 1e6  # through the run's ends
    fit = make_lsq_spline(x, y, knots, k=5, w=w)
    if np.any(fit.derivative()(x) <= 0.0):  # a map must move forward
        return make_interp_spline(x, y, k=5)
    return fit


def _inside(d1: np.ndarray, d2: np.ndarray, d3: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Derivatives from :func:`axis_derivatives` on one knot interval, with the values
    at its ends that rest on one-sided differences (the first and last two of the
    second, three of the third) extrapolated linearly from the central ones next to
    them: the one-sided ones fall short where the third derivative, just past a knot,
    changes fastest (by 5 % at a crest of the 5-axis sample)."""
    n = len(d3)
    if n < 10:
        return d1, d2, d3
    d2, d3 = d2.copy(), d3.copy()
    for d, k in ((d2, 2), (d3, 3)):
        steps = np.arange(k, 0, -1)[:, None]
        d[:k] = d[k] + steps * (d[k] - d[k + 1])
        d[n - k:] = d[n - 1 - k] + steps[::-1] * (d[n - 1 - k] - d[n - 2 - k])
    return d1, d2, d3


def _knots_along(geo: RunGeometry, param: RunParameter) -> np.ndarray:
    """The spline's knots as values of ``param`` (0 and its length at the ends)."""
    s_knots = np.clip(geo.s(geo.curve.interval_knots), 0.0, geo.length_mm)
    if param.identity:
        x = s_knots
    else:
        grid = np.linspace(0.0, param.length_mm, 4097)
        x = np.interp(s_knots, param.s(grid), grid)
        for _ in range(3):  # Newton on s(x) = s_knot
            x = np.clip(x - (param.s(x) - s_knots) / param.ds(x), 0.0, param.length_mm)
    x = np.r_[0.0, x[1:-1], param.length_mm]
    keep = np.r_[True, np.diff(x) > 1e-9]
    return x[keep]


def axis_derivatives(q: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First, second and third derivatives along s of axis values ``q : (n, n_axes)``
    sampled every ``h`` mm (second-order differences, one-sided at the ends)."""
    d1 = np.gradient(q, h, axis=0, edge_order=2)
    d2 = np.gradient(d1, h, axis=0, edge_order=2)
    return d1, d2, np.gradient(d2, h, axis=0, edge_order=2)


def _cap_time(windows: list[tuple[float, Budget]]) -> float:
    """Time to cross the windows at their speed caps (no ramps): which parameter has
    more room."""
    return sum(length / bud.v_cap for length, bud in windows)


def _same(a: Budget, b: Budget, tol: float = 0.005) -> bool:
    """Neighbours with the same budget merge (a straight transit is one window)."""
    return (abs(a.v_cap - b.v_cap) <= tol * max(a.v_cap, b.v_cap)
            and all(np.allclose(x, y, rtol=tol, atol=1e-12)
                    for x, y in ((a.m1, b.m1), (a.m2, b.m2), (a.m3, b.m3))))


def _cruising(s: np.ndarray, speed: np.ndarray, feed: float, margin_mm: float,
              share: float = 0.999, grid_mm: float = 0.5) -> np.ndarray:
    """Spans ``(k, 2)`` (mm) where the ball's ``speed`` at ``s`` stays at ``share`` of
    the feed or more, each shrunk by ``margin_mm`` at both ends and then to multiples
    of ``grid_mm`` (runs that differ in the last digits of their plan get equal cells,
    and can share a speed law)."""
    at = np.r_[False, speed >= share * feed, False].astype(int)
    change = np.flatnonzero(np.diff(at))
    starts, ends = change[::2], change[1::2] - 1
    spans = np.column_stack([np.ceil((s[starts] + margin_mm) / grid_mm) * grid_mm,
                             np.floor((s[ends] - margin_mm) / grid_mm) * grid_mm])
    return spans[spans[:, 1] > spans[:, 0]]


@dataclass(frozen=True, slots=True)
class TimedRun:
    """A run timed along ``param`` (the profile's position is that parameter; a speed
    law runs along the ball's arc length)."""

    geometry: RunGeometry
    profile: ChainProfile | SpeedLaw
    start_s: float
    carry_in: float | None
    param: RunParameter


@dataclass(frozen=True, slots=True)
class TimedDwell:
    node_id: str
    position_mm: np.ndarray
    start_s: float
    duration_s: float


@dataclass(frozen=True, slots=True)
class TimedLine:
    """A straight repositioning move in the table frame (the bar is off), with the
    rotary angles moving linearly from ``angles_from`` to ``angles_to`` (rad)."""

    a_mm: np.ndarray
    b_mm: np.ndarray
    angles_from: dict
    angles_to: dict
    profile: Profile
    start_s: float


@dataclass(frozen=True, slots=True)
class TimedLayer:
    layer: str
    items: tuple
    duration_s: float
    axis_names: tuple[str, ...]
    axis_units: tuple[str, ...]

    @property
    def motion_s(self) -> float:
        return sum(i.profile.duration_s for i in self.items if not isinstance(i, TimedDwell))


class Timer:
    """Times layer paths for one configuration."""

    def __init__(self, config: Config, kinematics: Kinematics | None = None,
                 optimal: bool = True):
        self.config = config
        self.optimal = optimal
        self._laws: dict[tuple, list] = {}  # speed laws found, by cell count and feed
        self.kin = kinematics or Kinematics(config.machine)
        self.schedule = RotarySchedule(config, self.kin)
        self.feed = config.test.feed_mm_per_min / 60.0
        axes = self.kin.axes
        self.v_lim = np.array([a.max_velocity for a in axes])
        self.a_lim = np.array([a.max_acceleration for a in axes])
        self.j_lim = np.array([a.max_jerk for a in axes])
        self._weights = None
        if self.kin.rotary:  # mm per axis unit in the axis path's arc length (RunParameter)
            a_ref = min((self.a_lim[i] for i in self.kin.linear), default=1.0)
            self._weights = np.where([a.is_rotary for a in axes], a_ref / self.a_lim, 1.0)

    def axis_values(self, points: np.ndarray, carry: float | None) -> tuple[np.ndarray, float | None]:
        angles, carry_out = self.schedule.angles(points, carry)
        return self.kin.inverse(points, angles), carry_out

    def parameter(self, geo: RunGeometry, carry: float | None, step_mm: float = 0.005,
                  per_knot: int = 64, knot_mm: float = 0.5) -> RunParameter:
        """The :class:`RunParameter` of a run (the identity without rotary axes): the
        axis path's arc length summed on a grid of at most ``step_mm``, and the ball's
        arc length over it fitted by least squares with knots about ``knot_mm`` apart
        (:func:`_smooth_map`)."""
        if self._weights is None:
            return RunParameter(geo.length_mm)
        intervals = len(geo.curve.interval_knots) - 1
        step = min(step_mm, geo.length_mm / (intervals * per_knot))
        n = max(256, math.ceil(geo.length_mm / step))
        s = np.linspace(0.0, geo.length_mm, n + 1)
        q, _ = self.axis_values(geo.points(s), carry)
        g = np.linalg.norm(np.gradient(q, s[1] - s[0], axis=0, edge_order=2) * self._weights,
                           axis=1)
        sigma = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(s))])
        sigma *= geo.length_mm / sigma[-1]  # as long as the ball's path: same windows
        return RunParameter(geo.length_mm, _smooth_map(sigma, s, knot_mm))

    def run_windows(self, geo: RunGeometry, carry: float | None,
                    param: RunParameter | None = None, step_mm: float = 0.1,
                    window_mm: float = 2.0, per_knot: int = 16, feed: float | None = None,
                    axis_path_step_mm: float = 0.005
                    ) -> tuple[list[tuple[float, Budget]], float | None]:
        """The run cut into windows of about ``window_mm`` of its parameter (``param``,
        by default the ball's arc length), each with its own budget (from the axis
        derivatives inside it); neighbours with the same budget merge.

        The derivatives are taken on a grid of at most ``step_mm`` and at least
        ``per_knot`` points per knot interval, each interval on its own: the fit puts its
        knots densest where the curve turns tightest, and a coarser grid would average
        the largest third derivatives away (a crest of a fraction of a millimetre's
        radius is under-read by half, and its jerk limit broken; hard case:
        test-axis-limits-seed2); differences across a knot would average the two values
        the third derivative takes there.  Along an axis path the grid is at most
        ``axis_path_step_mm``: next to a knot the rotary axes' third derivative along it
        rises and falls within a tenth of a millimetre (the map from the ball's arc
        length is smooth, the path's own derivatives are not), which the differences on
        a coarser grid average away (the jerk of C was 2.2 times its limit there).  The
        feed caps the parameter's speed at ``feed / max ds/dsigma`` in each window,
        with the largest step of ``ds/dsigma`` between grid points added so that the
        ball keeps within the feed between them too.  ``feed``: the run's own (mm/s;
        by default the timer's)."""
        feed = self.feed if feed is None else feed
        param = param or RunParameter(geo.length_mm)
        length = param.length_mm
        breaks = _knots_along(geo, param)
        step = step_mm if param.identity else min(step_mm, axis_path_step_mm)
        counts = np.maximum(per_knot, np.ceil(np.diff(breaks) / step)).astype(int)
        # every knot interval on its own grid, its ends included: the derivatives are
        # taken inside it (one-sided at its ends), so q''' keeps the values on either
        # side of a knot, where the spline's third derivative jumps
        x = np.concatenate([np.linspace(a, b, c + 1) for a, b, c in
                            zip(breaks[:-1], breaks[1:], counts)])
        q, carry_out = self.axis_values(geo.points(param.s(x)), carry)
        d1, d2, d3 = (np.empty_like(q) for _ in range(3))
        first = 0
        for a, b, c in zip(breaks[:-1], breaks[1:], counts):
            sl = slice(first, first + c + 1)
            d1[sl], d2[sl], d3[sl] = _inside(*axis_derivatives(q[sl], (b - a) / c))
            first += c + 1
        ds = param.ds(x)
        count = max(1, round(length / window_mm))
        edges = np.searchsorted(x, np.linspace(0.0, length, count + 1))
        edges[-1] = len(x) - 1
        windows: list[tuple[float, Budget]] = []
        for a, b in zip(edges[:-1], edges[1:]):
            sl = slice(max(a - 1, 0), min(b + 2, len(x)))  # one grid point of overlap
            ball_per_param = ds[sl].max() + np.abs(np.diff(ds[sl])).max(initial=0.0)
            bud = budget(d1[sl], d2[sl], d3[sl], self.v_lim, self.a_lim, self.j_lim,
                         self.kin.names, feed / ball_per_param)
            span = x[b] - x[a]
            if windows and _same(windows[-1][1], bud):
                prev_len, prev = windows[-1]
                windows[-1] = (prev_len + span, prev.weaker(bud))
            else:
                windows.append((span, bud))
        return windows, carry_out

    def time_run(self, geo: RunGeometry, carry: float | None, label: str,
                 feed: float | None = None
                 ) -> tuple[ChainProfile | SpeedLaw, RunParameter, float | None]:
        """A run's profile, the parameter it runs along, and the azimuth carry after it.

        It is timed along the ball's arc length by windows of constant limits
        (:func:`~sdit_path.timing.profile.plan_chain`); where something other than the
        feed caps the speed on a machine with rotary axes, and the axis path's windows
        (:class:`RunParameter`) would take less time at their speed caps than the ball's
        do, it is timed along the axis path too, and the quicker of the two is kept.
        Along the axis path the feed caps a speed that is not the ball's, and the cap
        follows ``ds/dsigma`` window by window: where the feed alone binds, the ball's
        arc length is as quick and cheaper to plan.  Where anything but the feed binds,
        the time-optimal speed law (:mod:`~sdit_path.timing.topp`) is sought from that
        plan and kept if it is quicker (unless the timer was made without it)."""
        feed = self.feed if feed is None else feed
        param = RunParameter(geo.length_mm)
        windows, carry_out = self.run_windows(geo, carry, param, feed=feed)
        prof = plan_chain(windows, label)
        if all(b.binding == "feed" for _, b in windows):
            return prof, param, carry_out
        if self._weights is not None:
            axis_path = self.parameter(geo, carry)
            other_windows = self.run_windows(geo, carry, axis_path, feed=feed)[0]
            if _cap_time(other_windows) < _cap_time(windows):
                other = plan_chain(other_windows, label)
                if other.duration_s < prof.duration_s:
                    prof, param = other, axis_path
        if self.optimal:
            law = self.speed_law(geo, carry, prof, param, feed)
            if law is not None and law.duration_s < prof.duration_s:
                return law, RunParameter(geo.length_mm), carry_out
        return prof, param, carry_out

    def run_jet(self, geo: RunGeometry, carry: float | None, edges: np.ndarray,
                points: int = 9, step_mm: float = 0.005, per_knot: int = 16) -> topp.Jet:
        """Axis derivatives along the ball's arc length at ``points`` evenly spaced
        points of every cell between ``edges`` (mm; its ends included), each from
        differences on the grid of its own knot interval of at most ``step_mm`` (as
        :meth:`run_windows` takes them), interpolated linearly; a point on a knot takes
        the side of its cell's middle (the third derivative jumps there)."""
        knots = _knots_along(geo, RunParameter(geo.length_mm))
        frac = np.linspace(0.0, 1.0, points)
        h = np.diff(edges)[:, None]
        where = edges[:-1, None] + h * frac[None, :]
        inward = where + 1e-9 * h * np.sign(0.5 - frac)[None, :]
        interval = np.clip(np.searchsorted(knots, inward, side="right") - 1, 0, len(knots) - 2)
        out = [np.zeros(where.shape + (len(self.v_lim),)) for _ in range(3)]
        for i in np.unique(interval):
            a, b = knots[i], knots[i + 1]
            n = max(per_knot, math.ceil((b - a) / step_mm))
            x = np.linspace(a, b, n + 1)
            q, _ = self.axis_values(geo.points(x), carry)
            derivs = _inside(*axis_derivatives(q, (b - a) / n))
            sel = interval == i
            for arr, d in zip(out, derivs):
                for ax in range(d.shape[1]):
                    arr[..., ax][sel] = np.interp(where[sel], x, d[:, ax])
        return topp.Jet(frac, *out)

    def speed_law(self, geo: RunGeometry, carry: float | None, prof: ChainProfile,
                  param: RunParameter, feed: float, samples: int = 20001,
                  margin_mm: float = 2.0) -> topp.SpeedLaw | None:
        """The time-optimal speed law of a run (:func:`~sdit_path.timing.topp.solve`),
        its first tangent at the windows' plan ``prof`` along ``param``, on coarse cells
        where that plan cruises at the feed (more than ``margin_mm`` from where it does
        not: a crest's speed-up and slow-down stay on fine cells).  A law found for
        an earlier run on the same cells (forwards or backwards: a pass and its way
        back, a mirror image, the table turning the same curve at another azimuth) is
        taken again if it keeps this run's axes within every limit at every point where
        the solver checks its own (:func:`~sdit_path.timing.topp.holds`)."""
        t = np.linspace(0.0, prof.duration_s, samples)
        sigma, v = prof.evaluate(t)[:2]
        s, speed = param.s(sigma), param.ds(sigma) * v
        edges = topp.cells(_knots_along(geo, RunParameter(geo.length_mm)),
                           _cruising(s, speed, feed, margin_mm))
        jet = self.run_jet(geo, carry, edges)
        key = (len(edges), float(feed))
        for found in self._laws.get(key, ()):
            for law in (found, found.reversed()):
                if (np.abs(law.s - edges).max() <= 1e-9 * edges[-1]
                        and topp.holds(law, jet, self.v_lim, self.a_lim, self.j_lim, feed)):
                    return law
        b_start = np.interp(edges, s, speed ** 2)
        law = topp.solve(edges, jet, self.v_lim, self.a_lim, self.j_lim, feed, b_start,
                         prof.limits)
        if law is not None:
            self._laws.setdefault(key, []).append(law)
        return law

    def line_limits(self, a: np.ndarray, b: np.ndarray, angles_from: dict, angles_to: dict
                    ) -> PathLimits:
        length = float(np.linalg.norm(b - a))
        t = np.linspace(0.0, 1.0, 33)
        pts = a + (b - a) * t[:, None]
        ang = {k: angles_from[k] + (angles_to[k] - angles_from[k]) * t for k in angles_from}
        q = self.kin.inverse(pts, ang)
        d1 = np.gradient(q, length / 32, axis=0, edge_order=2)
        zero = np.zeros_like(d1)
        bud = budget(d1, zero, zero, self.v_lim, self.a_lim, self.j_lim, self.kin.names, self.feed)
        return bud.limits(bud.v_cap)

    def time_layer(self, path: LayerPath) -> TimedLayer:
        items = []
        t = 0.0
        carry = None
        last_angles = None
        decimals = self.config.post.decimals
        for item in path.items:
            if isinstance(item, Dwell):
                # where the program puts the machine: the node as emitted (rounded)
                where = round_to_decimals(item.position_mm, decimals)
                items.append(TimedDwell(item.node_id, where, t, item.seconds))
                t += item.seconds
            elif isinstance(item, Run):
                geo = RunGeometry(item)
                # a sector re-planned at its own feed runs at it
                feed = (self.feed if item.feed_mm_per_min == self.config.test.feed_mm_per_min
                        else item.feed_mm_per_min / 60.0)
                prof, param, carry_out = self.time_run(geo, carry,
                                                       f"layer {path.layer}, {item.pieces[0].id}",
                                                       feed)
                items.append(TimedRun(geo, prof, t, carry, param))
                end = item.curve.control_points_mm[-1][None, :]
                last_angles = {k: float(v[0]) for k, v in self.schedule.angles(end, carry)[0].items()}
                carry = carry_out
                t += prof.duration_s
            elif isinstance(item, Remount):
                here = item.from_mm
                angles_here = last_angles or {k: float(v[0]) for k, v in
                                              self.schedule.angles(here[None, :], carry)[0].items()}
                target, carry = self.schedule.angles(item.to_mm[None, :], carry)
                angles_target = {k: float(v[0]) for k, v in target.items()}
                stops = [here] + list(item.via_mm) + [item.to_mm]
                for k, (a, b) in enumerate(zip(stops, stops[1:])):
                    # out with the old angles; they change on the way up; then the new
                    af = angles_here if k <= 1 else angles_target
                    at = angles_here if k == 0 else angles_target
                    lim = self.line_limits(np.asarray(a), np.asarray(b), af, at)
                    prof = plan_profile(float(np.linalg.norm(np.asarray(b) - a)), lim, "reposition")
                    items.append(TimedLine(np.asarray(a), np.asarray(b), af, at, prof, t))
                    t += prof.duration_s
                last_angles = angles_target
        return TimedLayer(path.layer, tuple(items), t, self.kin.names,
                          tuple(a.unit for a in self.kin.axes))


@dataclass(frozen=True, slots=True)
class Samples:
    """A sampled trajectory.  ``ball_mm : (n, 3)`` table frame; ``axes : (n, n_axes)``
    in mm and deg; ``segment`` and ``phase`` labels ``(n,)``."""

    t_s: np.ndarray
    ball_mm: np.ndarray
    axes: np.ndarray
    segment: np.ndarray
    phase: np.ndarray
    speed_mm_per_s: np.ndarray
    axis_names: tuple[str, ...]
    axis_units: tuple[str, ...]


def sample(timed: TimedLayer, timer: Timer, rate_hz: float = 1000.0) -> Samples:
    """The trajectory at ``rate_hz`` from time 0 to the end (inclusive)."""
    n = int(math.floor(timed.duration_s * rate_hz + 1e-9)) + 1
    t = np.arange(n) / rate_hz
    ball = np.zeros((n, 3))
    q = np.zeros((n, len(timed.axis_names)))
    segment = np.empty(n, dtype=object)
    phase = np.empty(n, dtype=object)
    speed = np.zeros(n)
    kin = timer.kin
    for k, item in enumerate(timed.items):
        dur = item.duration_s if isinstance(item, TimedDwell) else item.profile.duration_s
        last = k == len(timed.items) - 1
        sel = np.where((t >= item.start_s) & ((t <= item.start_s + dur) if last
                                               else (t < item.start_s + dur)))[0]
        if not sel.size:
            continue
        if isinstance(item, TimedDwell):
            p = np.broadcast_to(item.position_mm, (sel.size, 3))
            ball[sel] = p
            segment[sel] = item.node_id
            phase[sel] = "dwell"
            q[sel], _ = timer.axis_values(np.asarray(p), _carry_at(timed, k))
            continue
        s, v, _, _, ph = item.profile.evaluate(t[sel] - item.start_s)
        if isinstance(item, TimedLine):
            speed[sel] = v
            f = np.clip(s / max(item.profile.length_mm, 1e-12), 0.0, 1.0)
            p = item.a_mm + (item.b_mm - item.a_mm) * f[:, None]
            ang = {a: item.angles_from[a] + (item.angles_to[a] - item.angles_from[a]) * f
                   for a in item.angles_from}
            ball[sel] = p
            q[sel] = kin.inverse(p, ang)
            segment[sel] = "remount"
            phase[sel] = "reposition"
            continue
        geo = item.geometry
        speed[sel] = item.param.ds(s) * v  # the ball's speed (exactly v along s)
        s = item.param.s(s)
        u = geo.u(s)
        p = geo.curve.evaluate(u)
        ball[sel] = p
        q[sel], _ = timer.axis_values(p, item.carry_in)
        pieces = geo.run.pieces
        starts = np.array([pc.u_start for pc in pieces])
        idx = np.clip(np.searchsorted(starts, u, side="right") - 1, 0, len(pieces) - 1)
        segment[sel] = np.array([pc.id for pc in pieces], dtype=object)[idx]
        phase[sel] = np.array(PHASES, dtype=object)[ph]
    for i in kin.rotary:
        q[:, i] = np.degrees(q[:, i])
    return Samples(t, ball, q, segment, phase, speed, timed.axis_names, timed.axis_units)


def _carry_at(timed: TimedLayer, k: int) -> float | None:
    """The azimuth carry in force at item ``k`` (from the last run before it)."""
    for item in reversed(timed.items[:k]):
        if isinstance(item, TimedRun):
            return item.carry_in
    for item in timed.items[k:]:
        if isinstance(item, TimedRun):
            return item.carry_in
    return None


def axis_values_rad(traj: Samples, kin: Kinematics) -> np.ndarray:
    """Trajectory axis columns as internal values (mm, rad) in kinematics order."""
    q = np.zeros((len(traj.t_s), len(kin.names)))
    for col, name in enumerate(traj.axis_names):
        v = traj.axes[:, col]
        q[:, kin.index[name]] = np.radians(v) if kin.axes[kin.index[name]].is_rotary else v
    return q
