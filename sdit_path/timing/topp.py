"""Time-optimal jerk-limited motion along a run, by sequential linear programming.

Along the ball's arc length ``s`` with ``b(s) = v^2`` (the squared path speed), the
path acceleration is ``b'/2`` and the path jerk ``sqrt(b) b''/2``, so every axis'

    velocity      q' sqrt(b)
    acceleration  q'' b + q' b'/2
    jerk          sqrt(b) (q''' b + 3/2 q'' b' + 1/2 q' b'')

is linear in ``(b, b', b'')`` up to the factor ``sqrt(b)`` of the jerk.  The jerk limit
``|q''' b + 3/2 q'' b' + 1/2 q' b''| <= J / sqrt(b)`` has a convex right-hand side, whose
tangent at the last iterate is below it: each linear programme (HiGHS) holds an inner
approximation of the true constraints, so every iterate is feasible, and the next
tangent is taken at it (the classic convexification of time-optimal path tracking
with jerk limits; Debrouwere et al. 2013).  Unlike the windows of
:mod:`~sdit_path.timing.profile`, which hold constant path limits in each window, the
speed here may change along a curve so that the path jerk cancels the curvature's
share of an axis' jerk: a crest that constant limits cross at one speed is crossed
faster, speeding up and slowing down over it.

``b`` is a C1 piecewise quadratic on cells that hold every knot of the spline (the
axis derivatives jump there); the constraints hold at both ends and the middle of
every cell, each with the derivatives on the cell's own side of a knot, with the
limits scaled by ``margin`` for what happens between.  The first and the last cell
are crossed with constant path jerk from and to rest (``b`` grows like ``s^(4/3)``
there, which no polynomial in ``s`` follows): ``b = 3/4 s b'`` at the end of the first
cell is linear, and a bound on ``b'`` there bounds that jerk.  The result is a
:class:`SpeedLaw`, evaluated exactly (position by Newton on the cell's time integral).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import coo_matrix

from ..arrays import frozen
from .limits import PathLimits

_GAUSS = np.polynomial.legendre.leggauss(8)


def _cell_time(b0, d0, c, x):
    """Time to cross ``[0, x]`` of cells with ``b = b0 + d0 y + c y^2 / 2`` (Gauss-Legendre
    on 1/sqrt(b), vectorised over cells)."""
    nodes, weights = _GAUSS
    y = 0.5 * x[..., None] * (nodes + 1.0)
    b = b0[..., None] + d0[..., None] * y + 0.5 * c[..., None] * y * y
    return 0.5 * x * (weights / np.sqrt(np.maximum(b, 1e-300))).sum(axis=-1)


@dataclass(frozen=True, slots=True)
class SpeedLaw:
    """Motion along ``s`` from rest to rest.  ``s : (m + 1,)`` cell edges (mm);
    ``b, d : (m + 1,)`` squared speed and its slope there; ``c : (m,)`` each cell's
    ``b''``; ``t : (m + 1,)`` when each edge is reached.  The first and last cells are
    crossed with constant jerk ``j_head`` and ``j_tail`` (mm/s^3) from and to rest.
    ``limits``: those of the windowed plan it replaces (what bound that plan)."""

    s: np.ndarray
    b: np.ndarray
    d: np.ndarray
    c: np.ndarray
    t: np.ndarray
    j_head: float
    j_tail: float
    limits: PathLimits | None = None

    @classmethod
    def build(cls, s: np.ndarray, b: np.ndarray, d: np.ndarray, c: np.ndarray,
              limits: PathLimits | None = None) -> SpeedLaw:
        h = np.diff(s)
        dt = np.empty(len(h))
        dt[1:-1] = _cell_time(b[1:-2], d[1:-2], c[1:-1], h[1:-1])
        dt[0] = np.sqrt(12.0 * h[0] / d[1])
        dt[-1] = np.sqrt(12.0 * h[-1] / -d[-2])
        j_head = 6.0 * h[0] / dt[0] ** 3
        j_tail = 6.0 * h[-1] / dt[-1] ** 3
        t = np.r_[0.0, np.cumsum(dt)]
        return cls(*(frozen(np.asarray(x, dtype=float)) for x in (s, b, d, c, t)),
                   float(j_head), float(j_tail), limits)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1])

    def reversed(self) -> SpeedLaw:
        """The same motion backwards in time along the path reversed (``s -> L - s``):
        b and b'' keep their values, the slope changes sign."""
        length = self.s[-1]
        return SpeedLaw(*(frozen(np.ascontiguousarray(x)) for x in
                          (length - self.s[::-1], self.b[::-1], -self.d[::-1], self.c[::-1],
                           self.t[-1] - self.t[::-1])),
                        self.j_tail, self.j_head, self.limits)

    @property
    def length_mm(self) -> float:
        return float(self.s[-1])

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(s, v, a, j, phase)`` at times ``t``: position, speed, acceleration and jerk
        along the path, and the phase (0 speeding up, 3 cruising, 6 slowing down)."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.c) - 1)
        s, v, a, j = self.state(k, t - self.t[k])
        eps = 1e-6 * max(1.0, float(np.abs(a).max()) if a.size else 1.0)
        phase = np.where(a > eps, 0, np.where(a < -eps, 6, 3))
        return s, v, a, j, phase

    def state(self, k: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, ...]:
        """Position, speed, acceleration and jerk ``tau`` after the start of cells ``k``
        (up to and including their ends: one-sided where the jerk jumps)."""
        k = np.asarray(k)
        tau = np.clip(np.asarray(tau, dtype=float), 0.0, self.t[k + 1] - self.t[k])
        m = len(self.c)
        s, v, a, j = (np.zeros(np.shape(tau)) for _ in range(4))
        head, tail = k == 0, k == m - 1
        inner = ~(head | tail)
        jh, jt = self.j_head, self.j_tail
        th = tau[head]
        s[head], v[head], a[head], j[head] = jh * th ** 3 / 6, jh * th ** 2 / 2, jh * th, jh
        r = self.t[-1] - self.t[-2] - tau[tail]  # time to the end
        s[tail] = self.s[-1] - jt * r ** 3 / 6
        v[tail], a[tail], j[tail] = jt * r ** 2 / 2, -jt * r, jt
        if inner.any():
            ki, ti = k[inner], tau[inner]
            b0, d0, c = self.b[ki], self.d[ki], self.c[ki]
            h = self.s[ki + 1] - self.s[ki]
            x = np.clip(ti * np.sqrt(b0), 0.0, h)
            for _ in range(30):  # Newton on T(x) = tau, T' = 1/sqrt(b): monotone
                bx = np.maximum(b0 + d0 * x + 0.5 * c * x * x, 1e-300)
                step = (_cell_time(b0, d0, c, x) - ti) * np.sqrt(bx)
                x = np.clip(x - step, 0.0, h)
                if np.abs(step).max(initial=0.0) < 1e-13:
                    break
            bx = np.maximum(b0 + d0 * x + 0.5 * c * x * x, 0.0)
            s[inner] = self.s[ki] + x
            v[inner] = np.sqrt(bx)
            a[inner] = 0.5 * (d0 + c * x)
            j[inner] = 0.5 * c * v[inner]
        return s, v, a, j


def cells(knots_mm: np.ndarray, coarse: np.ndarray | None = None, cell_mm: float = 0.1,
          coarse_mm: float = 0.5, most: int = 800, first_mm: float = 0.002,
          growth: float = 1.3) -> np.ndarray:
    """Cell edges along a run whose spline has knots at ``knots_mm`` (0 and the run's
    length first and last): every knot an edge, cells of at most ``cell_mm``, or
    ``coarse_mm`` inside the spans ``coarse : (k, 2)`` (mm; where the motion cruises at
    the feed), graded from ``first_mm`` at both ends by ``growth`` (a ramp from rest is
    short at a slow feed).  Where that would make more than about ``most`` cells, all
    grow alike (the programme's time grows faster than its size: a long curved run at a
    high feed would take minutes; it loses a little of its speed-up instead)."""
    length = float(knots_mm[-1])
    spans = np.zeros((0, 2)) if coarse is None else np.asarray(coarse, dtype=float)
    wide = float(np.sum(spans[:, 1] - spans[:, 0])) if len(spans) else 0.0
    grow = max(1.0, ((length - wide) / cell_mm + wide / coarse_mm) / most)
    cell_mm, coarse_mm = cell_mm * grow, coarse_mm * grow
    head = [0.0]
    step = first_mm
    while step < cell_mm and head[-1] + step < length / 4:
        head.append(head[-1] + step)
        step *= growth
    head = np.array(head)
    edge = head[-1]
    bounds = np.unique(np.concatenate([knots_mm, spans.ravel()]))
    bounds = bounds[(bounds >= 0.0) & (bounds <= length)]
    inner = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        mid = 0.5 * (a + b)
        cruise = np.any((spans[:, 0] <= mid) & (mid <= spans[:, 1]))
        size = coarse_mm if cruise else cell_mm
        inner.append(np.linspace(a, b, max(1, int(np.ceil((b - a) / size))) + 1))
    x = np.concatenate(inner)
    x = x[(x > edge) & (x < length - edge)]
    x = np.unique(np.concatenate([head, x, length - head[::-1]]))
    return x[np.r_[True, np.diff(x) > 1e-7]]


@dataclass(frozen=True, slots=True)
class Jet:
    """Axis derivatives along ``s`` at ``frac : (f,)`` of every cell (0 and 1 first and
    last: its ends), each on the cell's own side of a knot:
    ``q1, q2, q3 : (m, f, n_axes)``."""

    frac: np.ndarray
    q1: np.ndarray
    q2: np.ndarray
    q3: np.ndarray


def _head_tail_bound(h: float, jerk: float) -> float:
    """Largest |b'| at the inner end of a first or last cell of length ``h`` crossed
    with constant jerk up to ``jerk`` from or to rest."""
    return 2.0 * (6.0 * h) ** (1 / 3) * jerk ** (2 / 3)


class _Programme:
    """The linear programme of :func:`solve` over cells ``s``: variables ``b`` and ``d``
    at the m + 1 edges and ``c`` per cell; rows at chosen points of the inner cells."""

    def __init__(self, s: np.ndarray, jet: Jet, V: np.ndarray, A: np.ndarray, J: np.ndarray,
                 vmax: float):
        self.s, self.jet, self.V, self.A, self.J = s, jet, V, A, J
        self.h = h = np.diff(s)
        self.m = m = len(h)
        self.nb = nb = m + 1
        self.nvar = 2 * nb + m
        self.inner = np.arange(1, m - 1)
        # equalities: C1 continuity of the inner cells, and the head and tail ramps
        k = self.inner
        hk = h[k]
        n = len(k)
        rows = np.concatenate([np.repeat(np.arange(n), 4), np.repeat(np.arange(n, 2 * n), 3),
                               [2 * n, 2 * n, 2 * n + 1, 2 * n + 1]])
        cols = np.concatenate([np.column_stack([k + 1, k, nb + k, 2 * nb + k]).ravel(),
                               np.column_stack([nb + k + 1, nb + k, 2 * nb + k]).ravel(),
                               [1, nb + 1, m - 1, nb + m - 1]])
        vals = np.concatenate([np.column_stack([np.ones(n), -np.ones(n), -hk, -0.5 * hk * hk]
                                               ).ravel(),
                               np.column_stack([np.ones(n), -np.ones(n), -hk]).ravel(),
                               [1.0, -0.75 * h[0], 1.0, 0.75 * h[-1]]])
        self.A_eq = coo_matrix((vals, (rows, cols)), shape=(2 * n + 2, self.nvar)).tocsr()
        self.b_eq = np.zeros(2 * n + 2)
        # bounds: rest at both ends, the head and tail jerk, speed caps at the edges
        lo, up = np.full(self.nvar, -np.inf), np.full(self.nvar, np.inf)
        lo[:nb] = 0.0
        for i in (0, m):
            lo[i] = up[i] = lo[nb + i] = up[nb + i] = 0.0
        lo[2 * nb] = up[2 * nb] = lo[2 * nb + m - 1] = up[2 * nb + m - 1] = 0.0
        ends = [np.min(J / np.maximum(np.abs(jet.q1[i]).max(axis=0), 1e-12)) for i in (0, -1)]
        lo[nb + 1], up[nb + 1] = 0.0, _head_tail_bound(h[0], 0.9 * ends[0])
        lo[nb + m - 1], up[nb + m - 1] = -_head_tail_bound(h[-1], 0.9 * ends[1]), 0.0
        self.cap = np.minimum(np.min(V ** 2 / np.maximum(jet.q1 ** 2, 1e-300), axis=2),
                              vmax ** 2)  # (m, f): the largest b at each point
        up[k] = np.minimum(up[k], self.cap[k, 0])
        up[k + 1] = np.minimum(up[k + 1], self.cap[k, -1])
        self.bounds = np.column_stack([lo, up])

    def values(self, x: np.ndarray, cells: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, ...]:
        """(B, D, C) of the solution ``x`` at fraction index ``f`` of ``cells``."""
        y = self.h[cells] * self.jet.frac[f]
        b, d, c = x[cells], x[self.nb + cells], x[2 * self.nb + cells]
        return b + d * y + 0.5 * c * y * y, d + c * y, c

    def rows(self, x_bar: np.ndarray, cells: np.ndarray, f: np.ndarray
             ) -> tuple[list, list, list]:
        """Rows at fraction index ``f`` of ``cells``: the speed cap and b >= 0, every
        axis' acceleration, and its jerk under the tangent of J / sqrt(B) at the
        iterate ``x_bar``, both signs.  Returns coefficient blocks of (b_k, d_k, c_k),
        their cells and right-hand sides."""
        y = self.h[cells] * self.jet.frac[f]
        one, zero = np.ones(len(cells)), np.zeros(len(cells))
        B, D, C = (one, y, 0.5 * y * y), (zero, one, y), (zero, zero, one)
        Bbar = np.maximum(self.values(x_bar, cells, f)[0], 1e-9)
        blocks = [B, tuple(-v for v in B)]
        rhs = [self.cap[cells, f], zero]
        q1, q2, q3 = (q[cells, f] for q in (self.jet.q1, self.jet.q2, self.jet.q3))
        for ax in range(len(self.J)):
            a1, a2, a3 = q1[:, ax], q2[:, ax], q3[:, ax]
            acc = tuple(a2 * B[i] + 0.5 * a1 * D[i] for i in range(3))
            jerk = tuple(a3 * B[i] + 1.5 * a2 * D[i] + 0.5 * a1 * C[i] for i in range(3))
            slope = 0.5 * self.J[ax] / Bbar ** 1.5
            for sign in (1.0, -1.0):
                blocks.append(tuple(sign * v for v in acc))
                rhs.append(np.full(len(cells), self.A[ax]))
                blocks.append(tuple(sign * jerk[i] + slope * B[i] for i in range(3)))
                rhs.append(1.5 * self.J[ax] / np.sqrt(Bbar))
        return blocks, [cells] * len(blocks), rhs

    def solve(self, x_bar: np.ndarray, points: tuple[np.ndarray, np.ndarray],
              objective: np.ndarray) -> np.ndarray | None:
        blocks, cells, rhs = [], [], []
        cells_all, f_all = points
        for f in np.unique(f_all):
            sel = cells_all[f_all == f]
            bl, ce, rh = self.rows(x_bar, sel, np.full(len(sel), f))
            blocks += bl
            cells += ce
            rhs += rh
        vals = np.concatenate([np.column_stack(b).ravel() for b in blocks])
        cell = np.concatenate(cells)
        cols = np.column_stack([cell, self.nb + cell, 2 * self.nb + cell]).ravel()
        rows = np.repeat(np.arange(len(cell)), 3)
        A_ub = coo_matrix((vals, (rows, cols)), shape=(len(cell), self.nvar)).tocsr()
        res = linprog(objective, A_ub=A_ub, b_ub=np.concatenate(rhs), A_eq=self.A_eq,
                      b_eq=self.b_eq, bounds=self.bounds, method="highs-ds")
        return res.x if res.status == 0 else None

    def worst(self, x: np.ndarray, V: np.ndarray, A: np.ndarray, J: np.ndarray,
              feed: float) -> np.ndarray:
        """The largest ratio to the limits ``V, A, J`` and the feed at every point of
        every inner cell (infinite where b < 0): ``(n_inner, f)``."""
        nb = self.nb
        return _worst(self.s, x[:nb], x[nb:2 * nb], x[2 * nb:], self.jet, V, A, J, feed)

    def time_gradient(self, x: np.ndarray) -> np.ndarray:
        """Gradient of the time (Simpson on every inner cell, head and tail exact)."""
        nb, m, h, k = self.nb, self.m, self.h, self.inner
        b, d, c = x[k], x[nb + k], x[2 * nb + k]
        g = np.zeros(self.nvar)
        for w, f in ((1 / 6, 0.0), (4 / 6, 0.5), (1 / 6, 1.0)):
            y = h[k] * f
            B = np.maximum(b + d * y + 0.5 * c * y * y, 1e-9)
            gB = -0.5 * w * h[k] / B ** 1.5
            np.add.at(g, k, gB)
            np.add.at(g, nb + k, gB * y)
            np.add.at(g, 2 * nb + k, gB * 0.5 * y * y)
        g[nb + 1] += -0.5 * np.sqrt(12 * h[0]) * max(x[nb + 1], 1e-9) ** -1.5
        g[nb + m - 1] += 0.5 * np.sqrt(12 * h[-1]) * max(-x[nb + m - 1], 1e-9) ** -1.5
        return g


def _worst(s: np.ndarray, b: np.ndarray, d: np.ndarray, c: np.ndarray, jet: Jet,
           V: np.ndarray, A: np.ndarray, J: np.ndarray, feed: float) -> np.ndarray:
    """The largest ratio to the limits ``V, A, J`` and the feed at every point of
    every inner cell of the law ``(b, d, c)`` over cells ``s`` (infinite where b < 0):
    ``(m - 2, f)``."""
    k = np.arange(1, len(s) - 2)
    y = np.diff(s)[k, None] * jet.frac[None, :]
    B = b[k, None] + d[k, None] * y + 0.5 * c[k, None] * y * y
    D = d[k, None] + c[k, None] * y
    C = np.broadcast_to(c[k, None], B.shape)
    q1, q2, q3 = jet.q1[k], jet.q2[k], jet.q3[k]
    Bp = np.maximum(B, 0.0)[..., None]
    v = np.sqrt(Bp) * np.abs(q1) / V
    a = np.abs(q2 * Bp + 0.5 * q1 * D[..., None]) / A
    j = np.sqrt(Bp) * np.abs(q3 * Bp + 1.5 * q2 * D[..., None] + 0.5 * q1 * C[..., None]) / J
    r = np.maximum(np.maximum(v, a), j).max(axis=-1)
    r = np.maximum(r, np.sqrt(Bp[..., 0]) / feed)
    return np.maximum(r, np.where(B < -1e-9, np.inf, 0.0))


def holds(law: SpeedLaw, jet: Jet, v_lim: np.ndarray, a_lim: np.ndarray, j_lim: np.ndarray,
          feed: float, jerk_margin: float = 0.98) -> bool:
    """Does ``law`` (found for another run on the same cells) keep this run's axes
    within their limits at every point of ``jet``, and its first and last cells' jerk
    within ``jerk_margin`` of theirs?"""
    J = np.asarray(j_lim, dtype=float)
    if len(jet.q1) != len(law.c):
        return False
    for jerk, q in ((law.j_head, jet.q1[0]), (law.j_tail, jet.q1[-1])):
        if np.any(jerk * np.abs(q).max(axis=0) > 0.9 * jerk_margin * J * (1.0 + 1e-9)):
            return False
    r = _worst(law.s, law.b, law.d, law.c, jet, np.asarray(v_lim, dtype=float),
               np.asarray(a_lim, dtype=float), J, feed)
    return bool(np.all(r <= 1.0))


def solve(s: np.ndarray, jet: Jet, v_lim: np.ndarray, a_lim: np.ndarray, j_lim: np.ndarray,
          feed: float, b_start: np.ndarray, limits: PathLimits | None = None,
          margin: float = 0.99, jerk_margin: float = 0.98, feed_margin: float = 0.9995,
          iterations: int = 3, refinements: int = 6, tol: float = 1e-4) -> SpeedLaw | None:
    """The fastest :class:`SpeedLaw` over cells ``s : (m + 1,)`` (mm, m >= 3) under the
    axis limits (velocity and acceleration scaled by ``margin``, jerk by ``jerk_margin``:
    the third derivatives next to a knot rest on one-sided differences, which an exact
    check finds up to 1.5 % off on a crest) and the feed (mm/s, scaled by
    ``feed_margin``: between the points where it is held, ``b`` may bulge by a few
    1e-5), by sequential linear programmes, the first tangent taken at the squared
    speeds ``b_start : (m + 1,)`` (the windows' plan); stops after ``iterations`` or when
    one gains less than ``tol`` (relative; the third gains about 0.2 %, a fourth 1e-5).

    The rows hold at both ends of every cell (the speed caps also in its middle).  Every
    solution is then checked at all of ``jet.frac`` against the limits themselves; where
    a point inside a cell is over (a crest of a fraction of a millimetre turns the
    derivatives within one cell), rows are added there and the programme solved again,
    up to ``refinements`` times.  Only a solution within every limit at every point is
    returned; None if none was found (HiGHS failed, or the refinements ran out)."""
    V, A, J = (np.asarray(x, dtype=float) for x in (v_lim, a_lim, j_lim))
    prog = _Programme(s, jet, margin * V, margin * A, jerk_margin * J, feed_margin * feed)
    h, nb, m = prog.h, prog.nb, prog.m
    last = len(jet.frac) - 1
    mid = int(np.argmin(np.abs(jet.frac - 0.5)))
    k = prog.inner
    cells = np.concatenate([k, k, k])
    fracs = np.concatenate([np.zeros(len(k), int), np.full(len(k), last), np.full(len(k), mid)])
    # the first tangent: b of the given motion, slopes by differences, b'' per cell
    b0 = np.asarray(b_start, dtype=float).copy()
    b0[0] = b0[-1] = 0.0
    x_cur = np.zeros(prog.nvar)
    x_cur[:nb] = b0
    d0 = np.gradient(b0, s)
    d0[1], d0[m - 1] = max(d0[1], 1e-6), min(d0[m - 1], -1e-6)
    x_cur[nb:2 * nb] = d0
    x_cur[2 * nb:] = np.diff(d0) / h
    best, best_x = None, None
    refined = done = 0
    for _ in range(iterations + refinements):
        x = prog.solve(x_cur, (cells, fracs), prog.time_gradient(x_cur))
        if x is None:
            break
        over = prog.worst(x, V, A, J, feed) > 1.0
        if over.any():
            if refined == refinements:
                break
            refined += 1
            ci, fi = np.nonzero(over)
            cells, fracs = np.r_[cells, k[ci]], np.r_[fracs, fi]
            continue
        law = SpeedLaw.build(s, x[:nb], x[nb:2 * nb], x[2 * nb:], limits)
        gain = best is None or law.duration_s < best.duration_s * (1.0 - tol)
        if best is None or law.duration_s < best.duration_s:
            best, best_x = law, x
        done += 1
        if not gain or done == iterations:
            break
        x_cur = best_x
    return best
