"""Clamped (rational) B-splines: evaluation, fitting to exact curves, radial checks.

Evaluation is vectorised with :class:`scipy.interpolate.BSpline`; geomdl serves only
as an exchange type and an independent cross-check in the tests (it is pure Python
and far slower).

The fit used for NC output is a clamped B-spline of degree 2 or 3 with *uniform*
interior knots (so every interpretation of the 840D ``PL`` word reads the same), end
points fixed on the static nodes and end derivatives fixed from the exact curve, so
that consecutive runs meet with a continuous tangent.  Pieces (segments) start and end
on knots.  The number of knot intervals grows until the radial deviation from the
sphere, measured on the control points *as they will be emitted* (rounded to the
emitted decimals), is within tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import scipy.sparse.linalg as spla
from scipy.interpolate import BSpline, CubicSpline

from ..arrays import frozen
from ..errors import PlanError
from ..fixed_point import round_to_decimals




@dataclass(frozen=True, slots=True)
class BSplineCurve:
    """Clamped B-spline, rational when ``weights`` is given.

    ``knots : (n + degree + 1,) float``, ``control_points_mm : (n, 3) float``,
    ``weights : (n,) float`` or None.
    """

    degree: int
    knots: np.ndarray
    control_points_mm: np.ndarray
    weights: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "knots", frozen(self.knots))
        object.__setattr__(self, "control_points_mm", frozen(self.control_points_mm))
        if self.weights is not None:
            object.__setattr__(self, "weights", frozen(self.weights))

    @property
    def domain(self) -> tuple[float, float]:
        return float(self.knots[self.degree]), float(self.knots[-self.degree - 1])

    @property
    def interval_knots(self) -> np.ndarray:
        """The distinct knots bounding non-empty intervals, ``(m + 1,)``."""
        return np.unique(self.knots[self.degree:-self.degree])

    def evaluate(self, u: np.ndarray) -> np.ndarray:
        """Points ``(k, 3)`` at parameters ``u : (k,)`` inside the domain."""
        u = np.asarray(u, dtype=float)
        if self.weights is None:
            return BSpline(self.knots, self.control_points_mm, self.degree, extrapolate=False)(u)
        w = self.weights[:, None]
        hom = BSpline(self.knots, np.hstack([self.control_points_mm * w, w]), self.degree,
                      extrapolate=False)(u)
        return hom[:, :3] / hom[:, 3:4]

    def to_geomdl(self):
        """A :class:`geomdl.NURBS.Curve` for exchange (geomdl rescales knots to [0, 1]);
        geomdl is an optional dependency (``pip install sdit-path[exchange]``)."""
        try:
            from geomdl import NURBS
        except ImportError:
            raise ImportError("BSplineCurve.to_geomdl needs geomdl: pip install "
                              "'sdit-path[exchange]'") from None

        curve = NURBS.Curve()
        curve.degree = self.degree
        w = np.ones(len(self.control_points_mm)) if self.weights is None else self.weights
        curve.ctrlptsw = [[*(p * wi).tolist(), float(wi)] for p, wi in zip(self.control_points_mm, w)]
        a, b = self.domain
        curve.knotvector = ((self.knots - a) / (b - a)).tolist()
        return curve

    @classmethod
    def from_geomdl(cls, curve) -> "BSplineCurve":
        """From a geomdl B-spline or NURBS curve (its [0, 1] knot vector is kept)."""
        pw = np.array(curve.ctrlptsw if hasattr(curve, "ctrlptsw") else
                      [[*p, 1.0] for p in curve.ctrlpts], dtype=float)
        w = pw[:, -1]
        rational = not np.allclose(w, 1.0)
        return cls(curve.degree, np.array(curve.knotvector, dtype=float), pw[:, :-1] / w[:, None],
                   w if rational else None)

    def reversed(self) -> "BSplineCurve":
        """The same curve traversed backwards, on the mirrored knot vector."""
        a, b = self.domain
        knots = (a + b) - self.knots[::-1]
        w = None if self.weights is None else self.weights[::-1]
        return BSplineCurve(self.degree, knots, self.control_points_mm[::-1], w)


def radial_deviation(curve: BSplineCurve, centre_mm: np.ndarray, radius_mm: float,
                     u: np.ndarray) -> np.ndarray:
    """Signed distance from the sphere (mm) at parameters ``u``: ``|C(u) - c| - R``."""
    p = curve.evaluate(u) - centre_mm
    return np.linalg.norm(p, axis=1) - radius_mm


def max_radial_deviation(curve: BSplineCurve, centre_mm: np.ndarray, radius_mm: float,
                         ranges: list[tuple[float, float]] | None = None,
                         samples_per_interval: int = 32) -> list[float]:
    """Largest ``|radial deviation|`` (mm) on each parameter range (default: whole curve).

    Every knot interval is sampled densely and then refined around its worst sample,
    which resolves the maximum of these smooth error functions to well under 1 %.
    """
    knots = curve.interval_knots
    g = samples_per_interval
    frac = np.linspace(0.0, 1.0, g + 1)
    a, b = knots[:-1], knots[1:]
    u = (a[:, None] + (b - a)[:, None] * frac[None, :])
    dev = np.abs(radial_deviation(curve, centre_mm, radius_mm, u.ravel())).reshape(u.shape)
    worst = np.argmax(dev, axis=1)
    h = (b - a) / g
    local = np.linspace(-1.0, 1.0, 21)
    u2 = np.clip(u[np.arange(len(a)), worst][:, None] + h[:, None] * local[None, :],
                 a[:, None], b[:, None])
    dev2 = np.abs(radial_deviation(curve, centre_mm, radius_mm, u2.ravel())).reshape(u2.shape)
    per_interval = np.maximum(dev.max(axis=1), dev2.max(axis=1))
    if ranges is None:
        ranges = [curve.domain]
    out = []
    for lo, hi in ranges:
        sel = (a >= lo - 1e-12) & (b <= hi + 1e-12)
        out.append(float(per_interval[sel].max()) if sel.any() else 0.0)
    return out


# ------------------------------------------------------------------------------ fitting


def rounded_on_sphere(curve: BSplineCurve, centre_mm: np.ndarray, radius_mm: float,
                      decimals: int, sweeps: int = 4, per_interval: int = 8) -> BSplineCurve:
    """``curve`` with its control points on the ``decimals`` grid (the ends kept as
    they are), each inner one chosen among the 27 grid neighbours of its rounding so
    that the curve where it acts keeps nearest the sphere (greedy sweeps, four): a
    control that reads 4 decimals then keeps a cubic a few hundredths of a micrometre
    from the sphere where plain rounding leaves up to 0.09 um.  Rational curves are
    rounded plainly."""
    from scipy.interpolate import BSpline

    from ..fixed_point import round_to_decimals

    ctrl = round_to_decimals(curve.control_points_mm, decimals)
    ctrl[0], ctrl[-1] = curve.control_points_mm[0], curve.control_points_mm[-1]
    if curve.weights is not None or len(ctrl) < 3:
        return BSplineCurve(curve.degree, curve.knots, ctrl, curve.weights)
    knots = curve.interval_knots
    frac = np.linspace(0.0, 1.0, per_interval, endpoint=False)
    u = np.r_[(knots[:-1, None] + np.diff(knots)[:, None] * frac[None, :]).ravel(), knots[-1]]
    B = BSpline.design_matrix(u, curve.knots, curve.degree)
    Bc, Br = B.tocsc(), B.tocsr()
    step = 10.0 ** (-decimals)
    neigh = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)],
                     float) * step
    for _ in range(sweeps):
        for j in range(1, len(ctrl) - 1):
            lo, hi = Bc.indptr[j], Bc.indptr[j + 1]
            rows, w = Bc.indices[lo:hi], Bc.data[lo:hi]
            others = Br[rows] @ ctrl - w[:, None] * ctrl[j]
            base = np.round(ctrl[j] / step) * step
            cand = base[None, :] + neigh
            pts = others[None, :, :] + w[None, :, None] * cand[:, None, :]
            err = np.abs(np.linalg.norm(pts - centre_mm, axis=2) - radius_mm).max(axis=1)
            ctrl[j] = cand[int(np.argmin(err))]
    inner = round_to_decimals(ctrl[1:-1], decimals)
    ctrl[1:-1] = inner
    return BSplineCurve(curve.degree, curve.knots, ctrl, None)


@dataclass(frozen=True, slots=True)
class FittedRun:
    """A fitted chain of pieces.  ``piece_ranges`` are parameter ranges on ``curve``."""

    curve: BSplineCurve
    piece_ranges: tuple[tuple[float, float], ...]
    piece_lengths_mm: tuple[float, ...]
    piece_max_deviation_mm: tuple[float, ...]


class _Piece:
    """Arc-length reparameterisation of one exact curve."""

    def __init__(self, curve, samples: int = 2001):
        t = np.linspace(0.0, 1.0, samples)
        p = curve(t)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        self.curve = curve
        self.length = float(s[-1])
        self._t_of_sigma = CubicSpline(s / s[-1], t)
        d0 = p[1] - p[0]
        d1 = p[-1] - p[-2]
        # one-sided differences are O(h) accurate; refine with a tiny symmetric stencil
        self.tangent_start = _unit(curve(np.array([1e-7]))[0] - curve(np.array([0.0]))[0], d0)
        self.tangent_end = _unit(curve(np.array([1.0]))[0] - curve(np.array([1.0 - 1e-7]))[0], d1)

    def at(self, sigma: np.ndarray) -> np.ndarray:
        t = np.clip(self._t_of_sigma(np.clip(sigma, 0.0, 1.0)), 0.0, 1.0)
        return self.curve(t)


def _unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    if n == 0.0:
        v, n = fallback, np.linalg.norm(fallback)
    return v / n


def _fit_once(pieces: list[_Piece], degree: int, counts: list[int], start: np.ndarray,
              end: np.ndarray, samples_per_interval: int = 10) -> tuple[BSplineCurve, list]:
    total = sum(counts)
    p = degree
    knots = np.concatenate([np.zeros(p), np.arange(total + 1, dtype=float), np.full(p, float(total))])
    n = total + p
    # sample parameters and exact targets
    us, targets, ranges = [], [], []
    offset = 0
    for piece, m in zip(pieces, counts):
        k = m * samples_per_interval
        sigma = (np.arange(k) + 0.5) / k
        us.append(offset + sigma * m)
        targets.append(piece.at(sigma))
        ranges.append((float(offset), float(offset + m)))
        offset += m
    u = np.concatenate(us)
    target = np.vstack(targets)
    q = np.zeros((n, 3))
    q[0], q[-1] = start, end
    q[1] = start + pieces[0].tangent_start * pieces[0].length / (counts[0] * p)
    q[-2] = end - pieces[-1].tangent_end * pieces[-1].length / (counts[-1] * p)
    fixed = [0, 1, n - 2, n - 1]
    free = np.arange(2, n - 2)
    if free.size:
        B = BSpline.design_matrix(u, knots, p).tocsc()
        rhs = target - B[:, fixed] @ q[fixed]
        Bf = B[:, free]
        A = (Bf.T @ Bf).tocsc()
        q[free] = spla.spsolve(A, Bf.T @ rhs)
    return BSplineCurve(p, knots, q), ranges


def fit_run(exact_curves: list, centre_mm: np.ndarray, radius_mm: float, start_mm: np.ndarray,
            end_mm: np.ndarray, *, degree: int = 3, tolerance_mm: float = 1e-5,
            decimals: int = 6, label: str = "run", max_intervals: int = 20000) -> FittedRun:
    """Fit one clamped uniform B-spline to a chain of exact sphere curves.

    The chain starts at ``start_mm`` and ends at ``end_mm`` (both emitted exactly as
    rounded here).  Raises :class:`PlanError` when the tolerance cannot be met, which
    happens only when ``decimals`` is too coarse for it.
    """
    pieces = [_Piece(c) for c in exact_curves]
    start = round_to_decimals(start_mm, decimals)
    end = round_to_decimals(end_mm, decimals)
    rounding = 0.5 * 10.0 ** (-decimals) * math.sqrt(3.0)
    if rounding >= tolerance_mm:
        raise PlanError(
            f"{label}: post.decimals = {decimals} rounds coordinates by up to "
            f"{rounding * 1e3:.4f} um, more than the radial tolerance "
            f"{tolerance_mm * 1e3:g} um; raise post.decimals or post.spline_tolerance_um")
    fit_target = tolerance_mm - rounding
    longest = max(pc.length for pc in pieces)
    # initial interval length: ~4 mm at R 150 for cubics, scaled as error ~ h^(p+1) / R^p
    h0 = (4.0 if degree == 3 else 1.0) * (radius_mm / 150.0) ** (degree / (degree + 1.0))
    h0 *= (fit_target / 5e-6) ** (1.0 / (degree + 1))
    m = max(2, math.ceil(longest / h0))
    for _ in range(12):
        counts = [max(1, round(m * pc.length / longest)) for pc in pieces]
        if sum(counts) < 2:
            counts[-1] += 2 - sum(counts)
        if sum(counts) > max_intervals:
            break
        curve, ranges = _fit_once(pieces, degree, counts, start, end)
        rounded = BSplineCurve(degree, curve.knots,
                               round_to_decimals(curve.control_points_mm, decimals))
        devs = max_radial_deviation(rounded, centre_mm, radius_mm, ranges)
        worst = max(devs)
        if worst <= tolerance_mm:
            return FittedRun(rounded, tuple(ranges), tuple(pc.length for pc in pieces),
                             tuple(devs))
        # error ~ h^(degree+1): scale the interval count, with a margin
        factor = (worst / fit_target) ** (1.0 / (degree + 1)) * 1.1
        m = max(m + 1, math.ceil(m * min(factor, 4.0)))
    raise PlanError(f"{label}: could not fit the curve within {tolerance_mm * 1e3:g} um radial "
                    f"deviation (best {worst * 1e3:.4f} um); check post.decimals")
