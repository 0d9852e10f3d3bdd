"""How fast could a jerk-limited motion run these paths?  A feasible reference, beside our plan.

For every run the time-optimal path parametrisation under the limits our planner
obeys (every axis |v| <= V_i, |a| <= A_i, |j| <= J_i through the exact path
q = IK(C(u)) with the Timer's rotary schedule; the ball's speed <= the run's feed;
rest to rest) is transcribed and solved by IPOPT (casadi), then checked densely with
exact derivatives and made strictly feasible.  The result is a trajectory, not an
estimate: its duration is an upper bound on the optimum, so plan / reference is a
lower bound on what a better planner could win (the transcription's own loss is
about 0.05 % on a wave crest: halving the cells to 0.05 mm gains 0.03 %).

Transcription.  Along x = u - u_start (the spline's own parameter, so that the path is
exactly one polynomial per knot interval and no arc-length interpolant enters), on a
fixed grid of nodes that holds every knot (cells of at most ``--cell`` mm of ball
path, graded down to 2 um at both ends so that the short ramps of slow feeds are
resolved), each cell is crossed with constant path jerk in a time of its own, as
ruckig's phases are.  Variables: speed and acceleration at the nodes, jerk and
duration of each cell; the dynamics of each cell are exact (position, speed and
acceleration at its end).  Constraints: the axis acceleration q'' v^2 + q' a at every
node; the axis jerk q''' v^3 + 3 q'' v a + q' j at both ends of every cell, with q'''
taken on the cell's own side of a knot; the axis and ball speeds at every node and,
through the middle Bernstein coefficient of the cell's speed (a quadratic in time),
inside every cell.  Objective: the sum of the durations.  IPOPT starts from our plan
(the same optimum is reached from plans slowed 1.5 and 3 times).

Re-check and repair.  The profile is evaluated on every cell (both ends and interior
points in time, then refined around the worst cells) with the derivatives of
``timing_exact_check.RunPath`` (exact path polynomials; IK differenced along the
path's cubic Taylor polynomial), and time is stretched uniformly by the smallest
factor k that brings every ratio to <= 1 (speeds scale by 1/k, accelerations 1/k^2,
jerks 1/k^3; k < 1 where the solution left room).  A second, denser check of the
stretched profile gives the ratio printed as "ref limit".  Each cell's cubic starts
from its own node's state; the mismatch at the next node (the solver's tolerance) is
kept in the JSON output.

A run and its reverse (the same curve backwards) have the same optimum (reversed in
time), and runs recur across layers: each shape is solved once per feed and its
profile (mirrored where reversed) checked again on every run it serves.

    python bench/timing_optimum.py [CONFIG] [--feeds 600,2000,5000] [--layers A,B]
                                   [--runs N] [--json OUT] [--cell 0.1]
    python bench/timing_optimum.py --rescore OUT
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from memory import peak_memory_line
from sweep import layers_at_feeds
from sdit_path.config import load_config
from sdit_path.timing.trajectory import RunGeometry, TimedRun, Timer
from timing_exact_check import (KINDS, Phases, RunPath, limit_ratios, peak_mb, run_feed,
                                run_label)

log = logging.getLogger("timing_optimum")
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)


# -------------------------------------------------------------------------- profile


@dataclass(frozen=True, slots=True)
class JerkProfile:
    """Motion along x in cells of constant jerk: ``x, v, a : (n + 1,)`` position, speed
    and acceleration at the nodes; ``jerk, tau : (n,)`` each cell's jerk and duration.
    Each cell is the cubic from its start node's state."""

    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    jerk: np.ndarray
    tau: np.ndarray

    @property
    def cells(self) -> int:
        return len(self.tau)

    @property
    def duration_s(self) -> float:
        return float(self.tau.sum())

    def state(self, cell: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, ...]:
        """x, speed, acceleration and jerk ``dt`` after the start of cells ``cell``."""
        v, a, j = self.v[cell], self.a[cell], self.jerk[cell]
        return (self.x[cell] + v * dt + a * dt * dt / 2 + j * dt ** 3 / 6,
                v + a * dt + j * dt * dt / 2, a + j * dt, j)

    def joins(self) -> dict[str, float]:
        """Largest mismatch between a cell's end and the next node (the solver's
        tolerance): position, speed, acceleration."""
        cell = np.arange(self.cells)
        x, v, a, _ = self.state(cell, self.tau)
        return {"position_mm": float(np.abs(x - self.x[1:]).max()),
                "speed_per_s": float(np.abs(v - self.v[1:]).max()),
                "acceleration_per_s2": float(np.abs(a - self.a[1:]).max())}

    def valid(self) -> bool:
        """Positive cell durations and no backward motion inside a cell."""
        v, a, j, tau = self.v[:-1], self.a[:-1], self.jerk, self.tau
        with np.errstate(divide="ignore", invalid="ignore"):
            at = np.where(j > 0, -a / j, -1.0)  # where the speed has its minimum
        inside = (at > 0) & (at < tau)
        low = v + a * at + j * at * at / 2
        return bool(np.all(tau > 0) and np.all(self.v >= -1e-9) and np.all(low[inside] >= -1e-9))

    def scaled(self, k: float) -> "JerkProfile":
        """The same path k times slower."""
        return JerkProfile(self.x, self.v / k, self.a / k ** 2, self.jerk / k ** 3, self.tau * k)

    def mirrored(self) -> "JerkProfile":
        """The reverse run's profile (the same motion backwards in time)."""
        return JerkProfile(self.x[-1] - self.x[::-1], self.v[::-1].copy(), -self.a[::-1],
                           self.jerk[::-1].copy(), self.tau[::-1].copy())


# ---------------------------------------------------------------------------- grid


def grid(path: RunPath, cell_mm: float, first_mm: float = 0.002, growth: float = 1.3
         ) -> np.ndarray:
    """Nodes along x: every knot, at most ``cell_mm`` of ball path apart, graded from
    ``first_mm`` at both ends."""
    br = path.breaks
    mm_per_x = np.diff(path.geo.s(path.u_knots)) / np.diff(br)
    nodes = [br]
    for i in range(len(br) - 1):
        m = max(2, math.ceil((br[i + 1] - br[i]) * mm_per_x[i] / cell_mm))
        nodes.append(np.linspace(br[i], br[i + 1], m + 1)[1:-1])
    steps, d = [], first_mm
    while d < cell_mm:
        steps.append(d)
        d *= growth
    zone = np.cumsum(steps)  # mm from either end
    length = br[-1]
    x = np.unique(np.concatenate(nodes))
    ends = zone[-1] / np.array([mm_per_x[0], mm_per_x[-1]])
    x = x[(x > ends[0]) & (x < length - ends[1])]
    knots_in = br[(br <= ends[0]) | (br >= length - ends[1])]
    x = np.unique(np.concatenate([x, zone / mm_per_x[0], length - zone / mm_per_x[-1],
                                  knots_in, [0.0, length]]))
    keep = np.concatenate([[True], np.diff(x) > 1e-9 * max(1.0, length)])
    return x[keep]


# ----------------------------------------------------------------------------- NLP


@dataclass(frozen=True, slots=True)
class Motion:
    """A motion sampled in time: ``t, x, v, a : (m,)`` (a start for the solver)."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray


class Transcription:
    """The time-optimal parametrisation of one run as an NLP: a fixed grid of nodes
    along x, each cell crossed with constant jerk in a time of its own (see the module
    text)."""

    def __init__(self, timer: Timer, path: RunPath, feed: float, cell_mm: float):
        self.timer, self.path, self.feed = timer, path, feed
        x = grid(path, cell_mm)
        self.x = x
        piece = path.piece_at(0.5 * (x[:-1] + x[1:]))
        start = path.jet(x[:-1], piece)   # each cell's start, on its own piece
        end = path.jet(x[1:], piece)      # each cell's end
        self.q1 = np.vstack([start.q1, end.q1[-1:]])
        self.q2 = np.vstack([start.q2, end.q2[-1:]])
        self.q3_start, self.q3_end = start.q3, end.q3
        speed = np.append(start.speed, end.speed[-1])
        with np.errstate(divide="ignore"):
            self.cap = np.minimum(feed / speed, np.min(
                timer.v_lim / np.maximum(np.abs(self.q1), 1e-300), axis=1))

    def initial(self, motion: Motion) -> tuple[np.ndarray, ...]:
        """Node speeds, accelerations, cell jerks and durations of ``motion``."""
        x = self.x
        t = np.interp(x, motion.x, motion.t)
        t[-1] = motion.t[-1]
        tau = np.maximum(np.diff(t), 1e-6 * motion.t[-1] / len(x))
        v = np.minimum(np.interp(x, motion.x, motion.v), self.cap)
        a = np.interp(x, motion.x, motion.a)
        v[0] = v[-1] = a[0] = a[-1] = 0.0
        return v, a, np.diff(a) / tau, tau

    def solve(self, motion: Motion, tol: float = 1e-9, max_iter: int = 3000
              ) -> tuple[JerkProfile, str]:
        timer, x = self.timer, self.x
        n = len(x) - 1
        h = np.diff(x)
        v0, a0, j0, tau0 = self.initial(motion)
        q1a = np.maximum(np.abs(self.q1), 1e-12)
        vs = float(self.cap.max())
        as_ = float(np.max(np.min(timer.a_lim / q1a, axis=1)))
        js = float(np.max(np.min(timer.j_lim / q1a, axis=1)))
        ts = float(tau0.sum()) / n
        vv, av = ca.SX.sym("v", n - 1), ca.SX.sym("a", n - 1)
        jv, tv = ca.SX.sym("j", n), ca.SX.sym("tau", n)
        zero = ca.SX.zeros(1)
        v = ca.vertcat(zero, vv * vs, zero)
        a = ca.vertcat(zero, av * as_, zero)
        j, tau = jv * js, tv * ts
        dm = lambda arr: ca.DM(np.asarray(arr, dtype=float))  # noqa: E731
        vk, vk1, ak, ak1 = v[:n], v[1:], a[:n], a[1:]
        g, lbg, ubg = [], [], []

        def rows(expr, lo, up):
            g.append(expr)
            lbg.append(np.broadcast_to(lo, (expr.shape[0],)))
            ubg.append(np.broadcast_to(up, (expr.shape[0],)))

        rows((vk * tau + ak * tau ** 2 / 2 + j * tau ** 3 / 6) / dm(h) - 1.0, 0.0, 0.0)
        rows((vk + ak * tau + j * tau ** 2 / 2 - vk1) / vs, 0.0, 0.0)
        rows((ak + j * tau - ak1) / as_, 0.0, 0.0)
        # the speed inside a cell is a quadratic in time; its middle Bernstein coefficient
        # bounds it (with the ends), so that it cannot bulge past the cap between nodes
        rows((vk + ak * tau / 2) / dm(np.minimum(self.cap[:-1], self.cap[1:])), 0.0, 1.0)
        inner = list(range(1, n))
        for i in range(len(timer.v_lim)):
            q1, q2 = self.q1[:, i], self.q2[:, i]
            if max(np.abs(q1).max(), np.abs(q2).max(), np.abs(self.q3_start[:, i]).max()) < 1e-12:
                continue  # an axis that does not move on this run
            A, J = timer.a_lim[i], timer.j_lim[i]
            rows((dm(q2[inner]) * v[inner] ** 2 + dm(q1[inner]) * a[inner]) / A, -1.0, 1.0)
            rows((dm(self.q3_start[:, i]) * vk ** 3 + 3.0 * dm(q2[:n]) * vk * ak
                  + dm(q1[:n]) * j) / J, -1.0, 1.0)
            rows((dm(self.q3_end[:, i]) * vk1 ** 3 + 3.0 * dm(q2[1:]) * vk1 * ak1
                  + dm(q1[1:]) * j) / J, -1.0, 1.0)
        nlp = {"x": ca.vertcat(vv, av, jv, tv), "f": ca.sum1(tv) / n, "g": ca.vertcat(*g)}
        opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes",
                "ipopt.tol": tol, "ipopt.constr_viol_tol": 1e-10, "ipopt.max_iter": max_iter,
                "ipopt.acceptable_tol": 1e-6, "ipopt.mu_strategy": "adaptive"}
        solver = ca.nlpsol("tpp", "ipopt", nlp, opts)
        cap = self.cap[1:n] / vs
        z0 = np.concatenate([v0[1:n] / vs, a0[1:n] / as_, j0 / js, tau0 / ts])
        free, nodes_free = np.full(n, np.inf), np.full(n - 1, np.inf)
        res = solver(x0=z0,
                     lbx=np.concatenate([np.zeros(n - 1), -nodes_free, -free, np.full(n, 1e-6)]),
                     ubx=np.concatenate([cap, nodes_free, free, free]),
                     lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
        status = solver.stats()["return_status"]
        z = np.asarray(res["x"]).ravel()
        m = n - 1
        prof = JerkProfile(x.copy(), np.concatenate([[0.0], z[:m] * vs, [0.0]]),
                           np.concatenate([[0.0], z[m:2 * m] * as_, [0.0]]),
                           z[2 * m:2 * m + n] * js, z[2 * m + n:] * ts)
        return prof, status


# ---------------------------------------------------------------------------- check


def profile_ratios(timer: Timer, path: RunPath, prof: JerkProfile, feed: float,
                   per_cell: int = 6, refine: int = 8, fine: int = 201) -> dict[str, float]:
    """The largest ratio of each kind over the profile: every cell sampled in time at
    ``per_cell`` points (both ends included), then the ``refine`` worst cells of each
    kind at ``fine`` points."""
    n = prof.cells
    piece = path.piece_at(0.5 * (prof.x[:-1] + prof.x[1:]))

    def sample(cells: np.ndarray, k: int) -> dict[str, np.ndarray]:
        cell = np.repeat(cells, k)
        dt = np.tile(np.linspace(0.0, 1.0, k), len(cells)) * prof.tau[cell]
        x, v, a, j = prof.state(cell, dt)
        jet = path.jet(np.clip(x, 0.0, path.length), piece[cell])
        r = limit_ratios(timer, jet, v, a, j, feed)
        return {kind: m.max(axis=1).reshape(len(cells), k).max(axis=1) for kind, m in r.items()}

    chunk = max(1, 40_000 // per_cell)
    parts = [sample(np.arange(a, min(a + chunk, n)), per_cell) for a in range(0, n, chunk)]
    out = {}
    for kind in KINDS:
        m = np.concatenate([p[kind] for p in parts])
        top = np.argsort(m)[-refine:]
        out[kind] = float(max(m.max(), sample(top, fine)[kind].max()))
    return out


def stretch_for(ratios: dict[str, float]) -> float:
    """The uniform time stretch that brings every ratio to 1."""
    return max(ratios["velocity"], ratios["feed"], math.sqrt(ratios["acceleration"]),
               math.cbrt(ratios["jerk"]))


def feasible(timer: Timer, path: RunPath, prof: JerkProfile, feed: float
             ) -> tuple[JerkProfile, float, dict[str, float]]:
    """The profile stretched (or shrunk) to its limits; the stretch and the ratios of a
    second, denser check."""
    k = stretch_for(profile_ratios(timer, path, prof, feed)) * (1.0 + 1e-9)
    total = k
    prof = prof.scaled(k)
    for _ in range(3):
        after = profile_ratios(timer, path, prof, feed, per_cell=11, refine=16)
        k = stretch_for(after)
        if k <= 1.0:
            return prof, total, after
        prof = prof.scaled(k * (1.0 + 1e-9))
        total *= k * (1.0 + 1e-9)
    return prof, total, after


# -------------------------------------------------------------------------- warm start


def plan_motion(timed: TimedRun, path: RunPath, samples: int = 20000) -> Motion:
    """Our plan's motion along x = u - u_start."""
    ph = Phases.of(timed.profile)
    t = np.linspace(0.0, timed.profile.duration_s, samples)
    k = np.clip(np.searchsorted(ph.t0, t, side="right") - 1, 0, len(ph.t0) - 1)
    y, yd, ydd, _ = ph.state(k, t - ph.t0[k])
    param, geo = timed.param, timed.geometry
    y = np.clip(y, 0.0, param.length_mm)
    if param.identity:
        s, sd, sdd = y, yd, ydd
    else:
        s1, s2 = param.ds(y), param._s.derivative(2)(y)
        s, sd, sdd = param.s(y), s1 * yd, s2 * yd ** 2 + s1 * ydd
    u1, u2 = geo._u_of_s.derivative(1)(s), geo._u_of_s.derivative(2)(s)
    x = np.maximum.accumulate(geo.u(s) - path.u_knots[0])
    return Motion(t, x, u1 * sd, u2 * sd ** 2 + u1 * sdd)


# ----------------------------------------------------------------------------- runs


@dataclass(frozen=True, slots=True)
class Reference:
    """One run's reference: its duration, the plan's, the solver's status, the time
    stretch of the repair and the ratios after it."""

    label: str
    plan_s: float
    reference_s: float
    status: str
    stretch: float
    ratios: dict
    cells: int
    shared: bool
    joins: dict

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def shape_key(geo: RunGeometry, feed: float) -> tuple[str, bool]:
    """A key shared by a run and its reverse (the same curve backwards) at one feed,
    and whether this run is the reversed one of the pair."""
    def digest(curve) -> str:
        parts = [np.round(curve.knots - curve.knots[0], 9), np.round(curve.control_points_mm, 9)]
        if curve.weights is not None:
            parts.append(np.round(curve.weights, 12))
        return hashlib.sha1(b"".join(p.tobytes() for p in parts)
                            + repr((curve.degree, round(feed, 9))).encode()).hexdigest()
    fwd, rev = digest(geo.curve), digest(geo.curve.reversed())
    return min(fwd, rev), rev < fwd


class Optimiser:
    """References of the runs of one config at one feed; each shape solved once."""

    def __init__(self, timer: Timer, cell_mm: float):
        self.timer, self.cell_mm = timer, cell_mm
        self.solved: dict[str, tuple[JerkProfile, bool, str]] = {}

    def reference(self, timed: TimedRun) -> Reference:
        timer, geo = self.timer, timed.geometry
        feed = run_feed(timed)
        path = RunPath(timer, geo, timed.carry_in, along_u=True)
        key, reversed_ = shape_key(geo, feed)
        shared = key in self.solved
        if shared:
            prof, was_reversed, status = self.solved[key]
            if was_reversed != reversed_:
                prof = prof.mirrored()
        else:
            tr = Transcription(timer, path, feed, self.cell_mm)
            prof, status = tr.solve(plan_motion(timed, path))
            if not prof.valid():
                log.warning("%s: the solution stops inside a cell", run_label(timed))
        prof, stretch, after = feasible(timer, path, prof, feed)
        if not shared:
            self.solved[key] = (prof, reversed_, status)
        return Reference(run_label(timed), timed.profile.duration_s, prof.duration_s, status,
                         stretch, after, prof.cells, shared, prof.joins())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--feeds", default="600,2000,5000")
    ap.add_argument("--layers", default="", help="only these layers, e.g. D,E (default: all)")
    ap.add_argument("--runs", type=int, default=0, help="only the first N runs of a layer")
    ap.add_argument("--cell", type=float, default=0.1, help="largest cell, mm of ball path")
    ap.add_argument("--rescore", default="", help="print the summary of a --json file again")
    ap.add_argument("--json", default="", help="write every run's figures here")
    args = ap.parse_args()
    if args.rescore:
        with open(args.rescore) as fh:
            summary(json.load(fh))
        return
    base = load_config(args.config)
    print(f"timing_optimum: {base.source}; motion time of our plan against a strictly "
          f"feasible jerk-limited reference (IPOPT, cells <= {args.cell:g} mm, re-checked "
          f"exactly, stretched to its limits)")
    print(f"  {'feed':<6} {'layer':<5} {'plan s':>8} {'ref s':>8} {'ratio':>6}  "
          f"{'worst run':>22}  {'ref limit':>9}  {'solved':>6} {'time':>6} {'peak':>7}")
    out, started = [], time.perf_counter()
    optimisers: dict[float, Optimiser] = {}
    for feed, _, timer, path in layers_at_feeds(base, args.feeds, args.layers):
        opt = optimisers.setdefault(feed, Optimiser(timer, args.cell))
        t0 = time.perf_counter()
        timed = timer.time_layer(path)
        runs = [i for i in timed.items if isinstance(i, TimedRun)]
        if args.runs:
            runs = runs[:args.runs]
        refs = [opt.reference(r) for r in runs]
        took = time.perf_counter() - t0
        plan = sum(r.plan_s for r in refs)
        ref = sum(r.reference_s for r in refs)
        worst = max(range(len(refs)), key=lambda k: refs[k].plan_s / refs[k].reference_s)
        limit = max(max(r.ratios.values()) for r in refs)
        solved = sum(not r.shared for r in refs)
        bad = [r.status for r in refs if not r.shared and r.status != "Solve_Succeeded"]
        w = refs[worst]
        print(f"  F{feed:<5g} {path.layer:<5} {plan:8.2f} {ref:8.2f} {plan / ref:6.3f}  "
              f"{w.plan_s / w.reference_s:6.3f} run {worst:2d} {w.label:<11}  "
              f"{limit:9.6f}  {solved:3d}/{len(refs):<2d} {took:5.0f}s {peak_mb():4.0f} MB"
              + (f"  solver: {', '.join(sorted(set(bad)))}" if bad else ""))
        out.append({"feed_mm_per_min": feed, "layer": path.layer, "plan_s": plan,
                    "reference_s": ref, "seconds": took,
                    "runs": [r.to_json() for r in refs]})
    print(f"total {time.perf_counter() - started:.0f} s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"config": str(base.source), "cell_mm": args.cell, "layers": out}, fh,
                      indent=1)


def summary(data: dict) -> None:
    """Per layer and feed of a ``--json`` file: our plan, the reference, their ratio and
    the worst run's."""
    print(f"{data['config']}: motion time of our plan / the jerk-limited reference")
    print(f"  {'feed':<6} {'layer':<5} {'plan s':>8} {'ref s':>8} {'ratio':>6}  {'worst run':>20}")
    for la in data["layers"]:
        runs = la["runs"]
        w = max(runs, key=lambda r: r["plan_s"] / r["reference_s"])
        print(f"  F{la['feed_mm_per_min']:<5g} {la['layer']:<5} {la['plan_s']:8.2f} "
              f"{la['reference_s']:8.2f} {la['plan_s'] / la['reference_s']:6.3f}  "
              f"{w['plan_s'] / w['reference_s']:6.3f} {w['label']:<13}")


if __name__ == "__main__":
    main()
    print(peak_memory_line())
