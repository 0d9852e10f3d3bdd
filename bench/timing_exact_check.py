"""Does our plan hold every limit at every instant?  An exact check of Timer.time_layer.

For every run of a layer the check walks the planned motion x(t) along the run's
parameter x (the ball's arc length, or a :class:`RunParameter`) and the path it maps
to, P(x) = C(u(s(x))), and takes the ratio of every axis' velocity, acceleration and
jerk to its limit, and of the ball's speed to the feed,

    dq/dt = q' x.,   d2q/dt2 = q'' x.^2 + q' x..,   d3q/dt3 = q''' x.^3 + 3 q'' x. x.. + q' x...

with no finite difference in time and none across a knot:

* x(t) and its derivatives come from the ruckig phases themselves (cubics in t with
  constant jerk), flattened out of the :class:`ChainProfile`; every phase is sampled
  up to and including both of its ends, so the jerk on either side of every phase
  boundary and of every join between windows is seen.  Position, speed and
  acceleration must be continuous over those joins; their jumps are reported.  A run
  timed by its optimal speed law (:class:`SpeedLaw`) is walked cell by cell the same
  way, each cell evaluated exactly (position by Newton on the cell's time integral,
  speed sqrt(b), acceleration b'/2, jerk sqrt(b) b''/2 on the cell's own side).
* P and its first three derivatives along x are exact: each knot interval of the
  fitted spline is one polynomial (Taylor coefficients at its midpoint), u(s) and
  s(sigma) are the planner's quintic interpolants (C4, differentiated analytically),
  chained by Faa di Bruno.  The knots of the spline are crossed at the times the
  profile reaches them (found by bisection on the phase cubics) and evaluated with the
  interval on each side: q''' one-sided, as it jumps there.
* The axis values are q = IK(P, schedule(P)) (``Timer.axis_values``).  Their
  derivatives along x are those of IK along the cubic Taylor polynomial of P at the
  sample, which has the same first three derivatives as P there; the five-point
  differences taken along that polynomial (h = 0.01 mm) are exact for the 3-axis
  machine's affine IK and are within ~1e-6 relative on the 5-axis one (the
  difference between h and 2h is printed with ``--accuracy``).

Samples: at least every 0.5 ms and every 0.005 mm within each phase, both ends of every
phase and knot interval, and a refinement around the worst sample of each limit on
each run (to ~1e-6 of a phase).  The rotary schedule's sector tilt patches (none in
the samples) would add C1 joins that are not treated as knots.

    python bench/timing_exact_check.py [CONFIG] [--feeds 600,2000,5000] [--layers A,B]
                                      [--json OUT] [--accuracy]
    python bench/timing_exact_check.py --rescore OUT
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import resource
import time
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from memory import peak_memory_line
from sweep import layers_at_feeds
from sdit_path.config import load_config
from sdit_path.timing.topp import SpeedLaw
from sdit_path.timing.trajectory import RunGeometry, RunParameter, TimedLine, TimedRun, Timer

KINDS = ("velocity", "acceleration", "jerk", "feed")


# ----------------------------------------------------------------------------- path


@dataclass(frozen=True, slots=True)
class PathJet:
    """Derivatives along a run's parameter x at n points.  ``q1, q2, q3 : (n, n_axes)``
    d^k q/dx^k (mm or rad per mm^k); ``speed : (n,)`` |dP/dx| (ball mm per mm of x);
    ``s : (n,)`` the ball's arc length."""

    q1: np.ndarray
    q2: np.ndarray
    q3: np.ndarray
    speed: np.ndarray
    s: np.ndarray


def _fdb(f1, f2, f3, g1, g2, g3):
    """Derivatives of f(g(x)) from f's at g(x) and g's at x (Faa di Bruno, to order 3);
    f's may carry trailing axes."""
    g1, g2, g3 = (np.asarray(g, dtype=float).reshape(-1, *([1] * (np.ndim(f1) - 1)))
                  for g in (g1, g2, g3))
    return f1 * g1, f2 * g1 ** 2 + f1 * g2, f3 * g1 ** 3 + 3.0 * f2 * g1 * g2 + f1 * g3


def _weights(offsets: np.ndarray) -> dict[int, np.ndarray]:
    """Finite-difference weights for derivatives 1..3 at 0 from values at ``offsets``
    (exact for polynomials of degree 4)."""
    v = np.vander(offsets.astype(float), increasing=True).T
    return {d: np.linalg.solve(v, np.eye(len(offsets))[d] * math.factorial(d)) for d in (1, 2, 3)}


#: by the stencil's shift: central, forward (from a run's start), backward (to its end)
_STENCILS = {k: _weights(k + np.arange(-2, 3)) for k in (0, 2, -2)}


class RunPath:
    """Exact derivatives of a run's axis values along its parameter (see module text).

    ``breaks : (m + 1,)`` are the parameter values of the spline's knots; piece ``i``
    is the polynomial of knot interval ``i``, evaluated (and continued past its ends)
    wherever the caller says, so one-sided derivatives at a knot are those of the piece
    on that side."""

    def __init__(self, timer: Timer, geo: RunGeometry, carry: float | None,
                 param: RunParameter | None = None, h_mm: float = 0.01, along_u: bool = False):
        self.timer, self.geo, self.carry, self.h = timer, geo, carry, h_mm
        self.param = param or RunParameter(geo.length_mm)
        self.along_u = along_u  # x = u - u_start: the spline's own parameter, no quintic
        curve = geo.curve
        self.rational = curve.weights is not None
        w = np.ones(len(curve.control_points_mm)) if curve.weights is None else curve.weights
        hom = np.hstack([curve.control_points_mm * w[:, None], w[:, None]])
        spline = BSpline(curve.knots, hom, curve.degree)
        self.u_knots = curve.interval_knots
        self.mid = 0.5 * (self.u_knots[:-1] + self.u_knots[1:])
        # Taylor coefficients at each interval's midpoint: exact for the whole piece
        self.taylor = np.stack([spline.derivative(k)(self.mid) / math.factorial(k) if k else
                                spline(self.mid) for k in range(curve.degree + 1)])
        self._u = [geo._u_of_s.derivative(k) for k in (1, 2, 3)]
        ident = self.param.identity
        self._s = None if ident else [self.param._s.derivative(k) for k in (1, 2, 3)]
        s_knots = np.clip(geo.s(self.u_knots), 0.0, geo.length_mm)
        s_knots[0], s_knots[-1] = 0.0, geo.length_mm
        self.s_knots = s_knots
        self.breaks = s_knots if ident else self.x_of_s(s_knots)
        self.length = self.param.length_mm
        if along_u:
            self.breaks = self.u_knots - self.u_knots[0]
            self.length = float(self.breaks[-1])

    @property
    def pieces(self) -> int:
        return len(self.mid)

    def x_of_s(self, s: np.ndarray) -> np.ndarray:
        """The parameter at the ball's arc lengths ``s`` (Newton on s(x))."""
        if self.param.identity:
            return np.asarray(s, dtype=float)
        length = self.param.length_mm
        grid = np.linspace(0.0, length, 20001)
        x = np.interp(s, self.param.s(grid), grid)
        for _ in range(8):
            x = np.clip(x - (self.param.s(x) - s) / self.param.ds(x), 0.0, length)
        return x

    def piece_at(self, x: np.ndarray) -> np.ndarray:
        """The piece containing ``x`` (the right one at a knot)."""
        return np.clip(np.searchsorted(self.breaks, x, side="right") - 1, 0, self.pieces - 1)

    def _curve(self, u: np.ndarray, piece: np.ndarray) -> list[np.ndarray]:
        """C, C', C'', C''' (each (n, 3)) of the pieces at ``u``."""
        d = u - self.mid[piece]
        deg = len(self.taylor) - 1
        hom = []
        for order in range(4):
            acc = np.zeros((len(u), self.taylor.shape[2]))
            for k in range(order, deg + 1):
                acc += (self.taylor[k][piece] * (math.factorial(k) / math.factorial(k - order))
                        * (d ** (k - order))[:, None])
            hom.append(acc)
        h0, h1, h2, h3 = hom
        w0, w1, w2, w3 = (h[:, 3:4] for h in hom)
        c0 = h0[:, :3] / w0
        if not self.rational:
            return [c0, h1[:, :3], h2[:, :3], h3[:, :3]]
        c1 = (h1[:, :3] - c0 * w1) / w0
        c2 = (h2[:, :3] - 2 * c1 * w1 - c0 * w2) / w0
        c3 = (h3[:, :3] - 3 * c2 * w1 - 3 * c1 * w2 - c0 * w3) / w0
        return [c0, c1, c2, c3]

    def points(self, x: np.ndarray, piece: np.ndarray) -> tuple[np.ndarray, ...]:
        """P and dP/dx, d2P/dx2, d3P/dx3 (each (n, 3)) and the ball's arc length."""
        x = np.asarray(x, dtype=float)
        if self.along_u:
            u = self.u_knots[0] + x
            c = self._curve(u, piece)
            return (*c, self.geo.s(u))
        if self.param.identity:
            s, sd = x, (np.ones_like(x), np.zeros_like(x), np.zeros_like(x))
        else:
            s = self.param.s(x)
            sd = tuple(f(x) for f in self._s)
        u = self.geo.u(s)
        # u(s)'s third derivative jumps at a knot as the curve's does: take it on the
        # piece's own side (a sample a rounding error past the knot would mix the
        # piece's C''' with the neighbour's u''')
        lo, hi = self.s_knots[piece], self.s_knots[piece + 1]
        inside = np.clip(s, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        ud = _fdb(*(f(inside) for f in self._u), *sd)
        c = self._curve(u, piece)
        return (c[0], *_fdb(c[1], c[2], c[3], *ud), s)

    def jet(self, x: np.ndarray, piece: np.ndarray) -> PathJet:
        """Derivatives of the axis values along x at ``x`` on pieces ``piece``."""
        x = np.asarray(x, dtype=float)
        p0, p1, p2, p3, s = self.points(x, piece)
        h = self.h
        # five offsets, central, or one-sided within 2h of a run's end (the schedule's
        # azimuth is undefined past the pole, where a run up the meridian ends)
        side = np.where(x < 2 * h, 2, np.where(x > self.length - 2 * h, -2, 0))
        m = side[:, None] + np.arange(-2, 3)[None, :]
        tau = h * m
        # the cubic Taylor polynomial of P at each sample, at those offsets
        pts = (p0[:, None] + p1[:, None] * tau[:, :, None]
               + p2[:, None] * (tau ** 2 / 2)[:, :, None]
               + p3[:, None] * (tau ** 3 / 6)[:, :, None])
        q = self._axes(pts.reshape(-1, 3)).reshape(len(x), 5, -1)
        f = q - q[:, 2:3]
        out = []
        for order in (1, 2, 3):
            w = np.stack([_STENCILS[k][order] for k in (0, 2, -2)])[(side // 2) % 3]
            out.append(np.einsum("nk,nka->na", w, f) / h ** order)
        return PathJet(*out, np.linalg.norm(p1, axis=1), s)

    def _axes(self, pts: np.ndarray, chunk: int = 200_000) -> np.ndarray:
        out = [self.timer.axis_values(pts[k:k + chunk], self.carry)[0]
               for k in range(0, len(pts), chunk)]
        return np.concatenate(out)


def limit_ratios(timer: Timer, jet: PathJet, xd: np.ndarray, xdd: np.ndarray,
                 xddd: np.ndarray, feed: float) -> dict[str, np.ndarray]:
    """|axis value derivative| / limit, ``(n, n_axes)`` per kind (``feed``: (n, 1))."""
    xd, xdd, xddd = (np.asarray(v, dtype=float)[:, None] for v in (xd, xdd, xddd))
    vel = jet.q1 * xd
    acc = jet.q2 * xd ** 2 + jet.q1 * xdd
    jerk = jet.q3 * xd ** 3 + 3.0 * jet.q2 * xd * xdd + jet.q1 * xddd
    return {"velocity": np.abs(vel) / timer.v_lim, "acceleration": np.abs(acc) / timer.a_lim,
            "jerk": np.abs(jerk) / timer.j_lim, "feed": jet.speed[:, None] * np.abs(xd) / feed}


# -------------------------------------------------------------------------- profile


@dataclass(frozen=True, slots=True)
class Phases:
    """A ChainProfile flattened into its constant-jerk phases, in time order:
    ``t0, dur, x0, v0, a0, j : (m,)``."""

    t0: np.ndarray
    dur: np.ndarray
    x0: np.ndarray
    v0: np.ndarray
    a0: np.ndarray
    j: np.ndarray

    @classmethod
    def of(cls, prof) -> "Phases":
        if isinstance(prof, SpeedLaw):
            return LawPhases(prof)
        rows = []
        for w, part in enumerate(prof.parts):
            for k in range(7):
                d = float(part.t0[k + 1] - part.t0[k])
                if d > 0.0:
                    rows.append((prof.t0[w] + part.t0[k], d, prof.s0[w] + part.p0[k],
                                 part.v0[k], part.a0[k], part.jerk[k]))
        return cls(*(np.array(c, dtype=float) for c in zip(*rows)))

    def state(self, k: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, ...]:
        """x, x., x.., x... of phases ``k`` at ``dt`` after their starts."""
        j, a0, v0 = self.j[k], self.a0[k], self.v0[k]
        return (self.x0[k] + v0 * dt + a0 * dt * dt / 2 + j * dt ** 3 / 6,
                v0 + a0 * dt + j * dt * dt / 2, a0 + j * dt, j)

    def joins(self) -> dict[str, float]:
        """Largest jumps of position, speed and acceleration from one phase to the next
        (and from rest at both ends)."""
        x, v, a, _ = self.state(np.arange(len(self.t0)), self.dur)
        end = np.array([x, v, a])
        start = np.array([self.x0, self.v0, self.a0])
        jumps = np.abs(end[:, :-1] - start[:, 1:])
        rest = np.abs(np.column_stack([start[:, 0], end[:, -1]]))  # (x, v, a) at both ends
        return {"position_mm": float(jumps[0].max(initial=0.0)),
                "speed_mm_per_s": float(max(jumps[1].max(initial=0.0), rest[1].max())),
                "acceleration_mm_per_s2": float(max(jumps[2].max(initial=0.0), rest[2].max()))}

    def time_at(self, x: np.ndarray, iterations: int = 80) -> np.ndarray:
        """First time at which the (non-decreasing) position reaches ``x``."""
        ends = self.state(np.arange(len(self.t0)), self.dur)[0]
        k = np.clip(np.searchsorted(ends, x, side="left"), 0, len(self.t0) - 1)
        lo, hi = np.zeros_like(x), self.dur[k].copy()
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            below = self.state(k, mid)[0] < x
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        return self.t0[k] + 0.5 * (lo + hi)


class LawPhases(Phases):
    """A :class:`SpeedLaw` as phases: its cells, each evaluated exactly on its own
    (the jerk is continuous inside a cell and jumps at its edges)."""

    def __init__(self, law: SpeedLaw):
        object.__setattr__(self, "law", law)
        t = np.asarray(law.t, dtype=float)
        s, v, a, _ = law.state(np.arange(len(t) - 1), np.zeros(len(t) - 1))
        for name, value in (("t0", t[:-1]), ("dur", np.diff(t)), ("x0", s), ("v0", v),
                            ("a0", a), ("j", np.zeros(len(t) - 1))):
            object.__setattr__(self, name, value)

    def state(self, k: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, ...]:
        k, dt = np.broadcast_arrays(np.asarray(k), np.asarray(dt, dtype=float))
        return self.law.state(k, dt)


# ---------------------------------------------------------------------------- check


@dataclass(frozen=True, slots=True)
class Worst:
    """The largest ratio of one limit kind and where: ``t_s`` from the start of the run
    (``layer_t_s`` from the start of the layer), ``s_mm`` along the ball's path."""

    kind: str
    ratio: float
    run: int
    label: str
    axis: str
    t_s: float
    layer_t_s: float
    s_mm: float
    at_knot: str

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def run_label(timed: TimedRun) -> str:
    ids = [p.id for p in timed.geometry.run.pieces]
    return ids[0] if len(ids) == 1 else f"{ids[0]}..{ids[-1]}"


def run_feed(timed: TimedRun) -> float:
    """The feed the run is planned at (mm/s)."""
    return timed.geometry.run.feed_mm_per_min / 60.0


class PlanCheck:
    """The exact check of one timed run (see module text)."""

    def __init__(self, timer: Timer, timed: TimedRun, dt_s: float = 5e-4, dx_mm: float = 0.005):
        self.timer, self.timed = timer, timed
        self.path = RunPath(timer, timed.geometry, timed.carry_in, timed.param)
        self.phases = Phases.of(timed.profile)
        self.feed = run_feed(timed)
        ph = self.phases
        # sub-intervals: every phase, cut where the profile crosses a knot
        knots_t = ph.time_at(self.path.breaks[1:-1])
        edges = np.unique(np.concatenate([ph.t0, ph.t0 + ph.dur, knots_t]))
        self.knot_t = knots_t
        lo, hi = edges[:-1], edges[1:]
        keep = hi - lo > 1e-12
        self.lo, self.hi = lo[keep], hi[keep]
        mid = 0.5 * (self.lo + self.hi)
        self.phase = np.clip(np.searchsorted(ph.t0, mid, side="right") - 1, 0, len(ph.t0) - 1)
        xm = ph.state(self.phase, mid - ph.t0[self.phase])[0]
        self.piece = self.path.piece_at(xm)
        xa = ph.state(self.phase, self.lo - ph.t0[self.phase])[0]
        xb = ph.state(self.phase, self.hi - ph.t0[self.phase])[0]
        self.count = np.maximum(3, np.maximum(np.ceil((self.hi - self.lo) / dt_s),
                                              np.ceil((xb - xa) / dx_mm))).astype(int) + 1

    def ratios(self, iv: np.ndarray, t: np.ndarray) -> tuple[dict, PathJet]:
        """Ratios at times ``t`` within sub-intervals ``iv`` (ends included as one-sided)."""
        k = self.phase[iv]
        x, xd, xdd, xddd = self.phases.state(k, t - self.phases.t0[k])
        x = np.clip(x, 0.0, self.path.param.length_mm)
        jet = self.path.jet(x, self.piece[iv])
        return limit_ratios(self.timer, jet, xd, xdd, xddd, self.feed), jet

    def worst(self, chunk: int = 40_000) -> dict[str, tuple[float, int, float, float]]:
        """Per kind: (ratio, axis index, t, s) at the largest ratio of the run."""
        iv = np.repeat(np.arange(len(self.lo)), self.count)
        first = np.repeat(np.cumsum(self.count) - self.count, self.count)
        frac = (np.arange(len(iv)) - first) / (self.count[iv] - 1)
        t = self.lo[iv] + (self.hi[iv] - self.lo[iv]) * frac
        best: dict[str, tuple] = {}
        for a in range(0, len(t), chunk):
            sl = slice(a, a + chunk)
            r, jet = self.ratios(iv[sl], t[sl])
            for kind, m in r.items():
                i, ax = np.unravel_index(np.argmax(m), m.shape)
                if kind not in best or m[i, ax] > best[kind][0]:
                    best[kind] = (float(m[i, ax]), int(ax), float(t[sl][i]), int(iv[sl][i]),
                                  float(jet.s[i]))
        return {kind: self._refine(kind, *b) for kind, b in best.items()}

    def _refine(self, kind: str, ratio: float, ax: int, t: float, iv: int, s: float,
                rounds: int = 4) -> tuple[float, int, float, float]:
        lo, hi = self.lo[iv], self.hi[iv]
        width = (hi - lo) / (self.count[iv] - 1)
        for _ in range(rounds):
            ts = np.clip(t + width * np.linspace(-1.0, 1.0, 41), lo, hi)
            r, jet = self.ratios(np.full(len(ts), iv), ts)
            m = r[kind]
            i, a = np.unravel_index(np.argmax(m), m.shape)
            if m[i, a] >= ratio:
                ratio, ax, t, s = float(m[i, a]), int(a), float(ts[i]), float(jet.s[i])
            width /= 20.0
        return ratio, ax, t, s

    def near_knot(self, t: float, tol: float = 1e-7) -> str:
        """``knot``, ``segment join`` (a knot where two pieces of the run meet) or ``""``."""
        if not self.knot_t.size or np.min(np.abs(self.knot_t - t)) > tol:
            return ""
        u = self.path.u_knots[1 + int(np.argmin(np.abs(self.knot_t - t)))]
        joins = [p.u_start for p in self.timed.geometry.run.pieces[1:]]
        return "segment join" if np.min(np.abs(np.subtract(joins, u)), initial=1.0) < 1e-9 else "knot"


@dataclass(frozen=True, slots=True)
class RunCheck:
    """The exact check of one run: the worst ratio per kind, the largest jumps at the
    joins of its phases, and what it is timed along (``ball`` or ``axis path``)."""

    run: int
    label: str
    along: str
    worst: dict
    joins: dict

    def to_json(self) -> dict:
        return {"run": self.run, "label": self.label, "along": self.along, "joins": self.joins,
                "worst": {k: w.to_json() for k, w in self.worst.items()}}


def check_run(timer: Timer, timed: TimedRun, n: int) -> RunCheck:
    chk = PlanCheck(timer, timed)
    names = timer.kin.names
    worst = {kind: Worst(kind, ratio, n, run_label(timed), "ball" if kind == "feed" else names[ax],
                         t, timed.start_s + t, s, chk.near_knot(t))
             for kind, (ratio, ax, t, s) in chk.worst().items()}
    return RunCheck(n, run_label(timed), "ball" if timed.param.identity else "axis path", worst,
                    chk.phases.joins())


def check_layer(timer: Timer, timed_layer, runs_limit: int = 0) -> list[RunCheck]:
    runs = [i for i in timed_layer.items if isinstance(i, TimedRun)]
    if any(isinstance(i, TimedLine) for i in timed_layer.items):
        raise NotImplementedError("repositioning moves (TimedLine) are not checked here")
    if runs_limit:
        runs = runs[:runs_limit]
    return [check_run(timer, r, n) for n, r in enumerate(runs)]


def worst_of(checks: list[RunCheck], kind: str) -> Worst | None:
    found = [c.worst[kind] for c in checks]
    return max(found, key=lambda w: w.ratio) if found else None


def describe(w: Worst, name: str) -> str:
    return (f"      {name:<22} {w.ratio:9.5f}  {w.axis:<4} run {w.run:2d} ({w.label}) "
            f"t {w.t_s:8.5f} s in the run, s {w.s_mm:8.3f} mm"
            + (f"  at a {w.at_knot}" if w.at_knot else ""))


def accuracy(timer: Timer, timed: TimedRun, n: int = 2000) -> float:
    """Largest change of the jerk ratio between h = 0.01 and 0.02 mm on one run."""
    chk = PlanCheck(timer, timed)
    t = np.linspace(0.0, timed.profile.duration_s, n)
    iv = np.clip(np.searchsorted(chk.lo, t, side="right") - 1, 0, len(chk.lo) - 1)
    a = chk.ratios(iv, t)[0]["jerk"]
    chk.path.h = 0.02
    b = chk.ratios(iv, t)[0]["jerk"]
    return float(np.abs(a - b).max())


def peak_mb() -> float:
    """This process's peak resident memory so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--feeds", default="600,2000,5000")
    ap.add_argument("--layers", default="", help="only these layers, e.g. D,E (default: all)")
    ap.add_argument("--runs", type=int, default=0, help="only the first N runs of a layer")
    ap.add_argument("--rescore", default="", help="print the summary of a --json file again")
    ap.add_argument("--json", default="", help="write the results here")
    ap.add_argument("--accuracy", action="store_true",
                    help="print the jerk ratio's change from h to 2h on each layer's first run")
    args = ap.parse_args()
    if args.rescore:
        with open(args.rescore) as fh:
            summary(json.load(fh))
        return
    base = load_config(args.config)
    print(f"timing_exact_check: {base.source}; largest ratio to its limit over every instant "
          f"of our plan (exact derivatives, one-sided at knots and joins)")
    out, started = [], time.perf_counter()
    for feed, _, timer, path in layers_at_feeds(base, args.feeds, args.layers):
        t0 = time.perf_counter()
        timed = timer.time_layer(path)
        checks = check_layer(timer, timed, args.runs)
        took = time.perf_counter() - t0
        jumps = {k: max(c.joins[k] for c in checks) for k in checks[0].joins}
        print(f"  F{feed:<5g} layer {path.layer} ({took:5.1f} s, {peak_mb():.0f} MB peak)  "
              f"joins: largest jump of speed {jumps['speed_mm_per_s']:.1e} mm/s, "
              f"acceleration {jumps['acceleration_mm_per_s2']:.1e} mm/s^2")
        for kind in KINDS:
            print(describe(worst_of(checks, kind), kind))
        for along in ("ball", "axis path"):
            some = [c for c in checks if c.along == along]
            if some and len(some) < len(checks):
                print(describe(worst_of(some, "jerk"), f"jerk, along {along} ({len(some)})"))
        top = [max(w.ratio for w in c.worst.values()) for c in checks]
        print(f"      runs over a limit by more than 1e-4: {sum(r > 1 + 1e-4 for r in top)}, "
              f"by more than 1 %: {sum(r > 1.01 for r in top)}, of {len(checks)}")
        if args.accuracy:
            first = next(i for i in timed.items if isinstance(i, TimedRun))
            print(f"      jerk ratio change from h = 0.01 to 0.02 mm on run 0: "
                  f"{accuracy(timer, first):.1e}")
        out.append({"feed_mm_per_min": feed, "layer": path.layer, "seconds": took,
                    "runs": [c.to_json() for c in checks]})
    print(f"total {time.perf_counter() - started:.0f} s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"config": str(base.source), "layers": out}, fh, indent=1)


def summary(data: dict) -> None:
    """Per layer and feed of a ``--json`` file: the largest ratio to its limit of each
    kind over every instant of the plan, and the runs over a limit."""
    print(f"{data['config']}: largest ratio to the limit over every instant (exact)")
    print(f"  {'feed':<6} {'layer':<5}" + "".join(f"{k:>13}" for k in KINDS)
          + f"{'runs over 1e-4':>16}")
    for la in data["layers"]:
        worst = {k: max(r["worst"][k]["ratio"] for r in la["runs"]) for k in KINDS}
        over = sum(max(w["ratio"] for w in r["worst"].values()) > 1 + 1e-4 for r in la["runs"])
        print(f"  F{la['feed_mm_per_min']:<5g} {la['layer']:<5}"
              + "".join(f"{worst[k]:13.5f}" for k in KINDS) + f"{over:>10d} of {len(la['runs'])}")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
