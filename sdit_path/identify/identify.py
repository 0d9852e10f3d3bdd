"""Honest identification: only what the data determine, with uncertainties.

Per trace (an experiment) the bar readings ``y`` are modelled as ``J theta + N n``:
``J`` the first-order sensitivities to the error parameters (columns scaled by their
prior magnitudes, so that a unit in any direction means "a typical error"), ``N`` the
set-up nuisances of that mounting (ball centring x, y, z and bar length), which are
always unknown.  Everything is accumulated as Gram matrices, so a full hemisphere at
1 kHz costs a few small matrices.  The nuisances are eliminated (Schur complement);
the eigen-decomposition of what remains gives the parameter combinations the data
see, each with its standard uncertainty ``sigma / sqrt(lambda)``.

* A combination is **determined** when its standard uncertainty is below half the
  prior magnitude; only those are reported as numbers, never more than the rank.
* A parameter is **individually identifiable** when it lies (to 1e-6) in the span of
  the determined combinations; otherwise it is reported as aliased.
* With ``prior=True`` every parameter gets a Tikhonov estimate and is labelled by its
  resolution-matrix diagonal: data-determined (> 0.9), prior-driven (< 0.1) or partly.
* For a parameter asked about that is not identifiable, candidate additional set-ups
  (a second pivot height, another tool length, moving rotary axes) are simulated and
  their combined information is tested: the answer is computed, not written.
* Observability indices (Borm & Menq O1, Nahvi & Hollerbach O4) of the determined
  subspace are given per layer and per segment, for experiment design.
"""

from __future__ import annotations

import dataclasses
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..config import Config
from ..errormodel.chain import actual_ball, sensitivities
from ..errormodel.model import ErrorModel, ModelOptions, build_model, prior_scale
from ..errors import ConfigError, RecordingError
from ..machine.kinematics import Kinematics
from ..machine.schedule import RotarySchedule
from ..plan.files import PlanFiles
from ..reading.trace import Trace
from ..timing.trajectory import axis_values_rad
from .figures import estimate as trade_figures, functionals
from .results import Identification

DETERMINED = 0.5  # standard uncertainty below this share of the prior magnitude


@dataclass
class Gram:
    """Accumulated normal equations of one experiment (scaled parameters ``x``)."""

    A: np.ndarray  # J^T J
    B: np.ndarray  # J^T N
    C: np.ndarray  # N^T N
    b: np.ndarray  # J^T y
    c: np.ndarray  # N^T y
    yy: float
    m: int
    segments: dict = field(default_factory=dict)  # id -> (J^T J, count)
    layers: dict = field(default_factory=dict)
    blocks: dict = field(default_factory=dict)  # second -> ([J N]^T [J N], [J N]^T y)
    segment_nuisances: dict = field(default_factory=dict)  # id -> (J^T N, N^T N)


#: Eigenvalues of the reduced normal matrix below this share of the scale of the normal
#: equations *before* the set-up nuisances are eliminated count as zero.  Eliminating
#: them (Schur complement) cancels terms of that size and leaves rounding noise of
#: ~1e-12 of it in directions the geometry cannot see at all; measured against the
#: largest eigenvalue *after* elimination instead, that noise passes as more determined
#: directions, and one segment shows a higher rank than the whole hemisphere (hard case:
#: test-part-rank).  A direction at 1e-9 of the scale (3e-5 of the best-seen
#: sensitivity, after prior scaling) cannot be determined anyway.
STRUCTURAL = 1e-9


def structural_scale(grams: list["Gram"]) -> float:
    """The scale of the normal equations before elimination: the largest eigenvalue of
    the parameter block, or of any experiment's nuisance block if that is larger."""
    big = max(float(np.linalg.eigvalsh(sum(g.A for g in grams)).max()),
              max(float(np.linalg.eigvalsh(g.C).max()) for g in grams))
    return max(big, 1e-300)


def structural_rank(grams: list["Gram"]) -> int:
    """How many parameter directions these experiments see at all (set-up nuisances
    eliminated); never more on part of the data than on the whole."""
    S, _, _, _ = _schur(grams)
    return int((np.linalg.eigvalsh(S) > structural_scale(grams) * STRUCTURAL).sum())


def _nuisance_columns(u: np.ndarray) -> np.ndarray:
    # centring: the pivot ball sits at pivot + d, the bar reads -u.d; bar length: +1
    return np.column_stack([-u, np.ones(len(u))])


def experiment_gram(plan: PlanFiles, program: str, trace: Trace | None, model: ErrorModel,
                    chunk: int = 200_000, segments: set[str] | None = None,
                    at: tuple[np.ndarray, np.ndarray] | None = None,
                    extra: np.ndarray | None = None, cache: dict | None = None,
                    observe: bool = True, blocks_s: float | None = None,
                    segment_nuisances: bool = False) -> Gram:
    """Gram matrices of one experiment.  With ``trace`` the readings come from it
    (matched to the trajectory by time); without, only the design (y = 0).  With
    ``segments``, only the samples of those segments (design studies of a part).

    With ``at = (theta, nuisances)`` (errors in um/urad; centring um and bar length um)
    the readings are corrected by what the exact error chain and bar geometry add to
    the first-order model there (a Gauss-Newton step with the Jacobian kept at the
    nominal poses): a 100 um error moves the bar by |e_perp|^2 / 2R beyond its
    first-order part, 0.05 um at R = 100 mm, and errors of Table 2's size bias the
    first-order estimates by many of their standard uncertainties.

    ``extra`` (trajectory samples x k): more nuisance columns of this experiment, such
    as what the diagnosis found in the recording (a servo mismatch, a backlash, a
    drift), estimated together with the geometry and eliminated with the set-up, so
    that the geometry is not read from what these explain.  ``cache`` (a dict kept by
    the caller for this experiment) keeps the sensitivities between calls on the same
    trace; ``observe=False`` skips the per-segment and per-layer blocks.  With
    ``blocks_s``, the normal equations of every ``blocks_s`` of the program are kept as
    well (for :func:`block_covariance`); with ``segment_nuisances``, each segment's
    J^T N and N^T N too (what it adds once the set-up is eliminated)."""
    cfg = plan.config
    kin = Kinematics(cfg.machine)
    traj = plan.trajectory(program)
    pivot = np.array(cfg.ballbar.pivot_mm)
    q = axis_values_rad(traj, kin)
    segment, phase = traj.segment, traj.phase
    y = np.zeros(len(q))
    valid = phase != "reposition"
    if trace is not None:
        rate = 1.0 / float(np.median(np.diff(traj.t_s)))
        idx = np.rint(trace.t_s * rate).astype(int)
        inside = (idx >= 0) & (idx < len(q))
        y_full = np.full(len(q), np.nan)
        y_full[idx[inside]] = trace.delta_l_um[inside]
        y = y_full
        # share of the program's seconds with a reading (the trace may be sampled
        # more sparsely than the trajectory)
        heard = np.unique(np.floor(trace.t_s[np.isfinite(trace.delta_l_um)]).astype(np.int64))
        program_s = np.unique(np.floor(traj.t_s[valid]).astype(np.int64))
        covered = float(np.isin(program_s, heard).mean()) if len(program_s) else 0.0
        if covered < 0.5:
            raise RecordingError(
                f"{program}: the trace holds readings for {covered:.0%} of the program's "
                f"{len(q) / rate:.1f} s; identification needs a recording of the whole program "
                f"(at least half of it)")
        valid &= np.isfinite(y)
    if segments is not None:
        valid &= np.isin(segment, list(segments))
    rows = np.flatnonzero(valid)
    scale = np.array([prior_scale(p) for p in model.parameters])
    n_p = len(model.parameters)
    n_n = 4 + (0 if extra is None else extra.shape[1])
    g = Gram(np.zeros((n_p, n_p)), np.zeros((n_p, n_n)), np.zeros((n_n, n_n)), np.zeros(n_p),
             np.zeros(n_n), 0.0, 0)
    for start in range(0, len(rows), chunk):
        sel = rows[start:start + chunk]
        key = (start, len(sel), int(sel[0]), int(sel[-1])) if len(sel) else None
        if cache is not None and (SENSITIVITIES, key) in cache:
            # the nominal poses do not move between Gauss-Newton steps
            J, d, u = cache[(SENSITIVITIES, key)]
        else:
            J = sensitivities(kin, model, q[sel], pivot) * scale
            p_nom = kin.forward(q[sel])
            d = np.linalg.norm(p_nom - pivot, axis=1)
            u = (p_nom - pivot) / d[:, None]
            if cache is not None and not cache.get(REMADE):
                cache[(SENSITIVITIES, key)] = (J, d, u)
        yy = y[sel] - (d - cfg.ballbar.bar_length_mm) * 1e3 if trace is not None else y[sel]
        N = _nuisance_columns(u)
        if at is not None and trace is not None:
            theta, nuis = at
            ball = actual_ball(kin, model, theta, q[sel])
            exact = (np.linalg.norm(ball - (pivot + nuis[:3] * 1e-3), axis=1) - d) * 1e3 + nuis[3]
            yy = yy - (exact - J @ (theta / scale) - N @ nuis[:4])
        if extra is not None:
            N = np.column_stack([N, extra[sel]])
        # the products of the sensitivities and the nuisance columns do not move between
        # Gauss-Newton steps either (only the corrected readings do): kept with them
        products = cache.get(("products", key)) if cache is not None else None
        if products is None:
            products = (J.T @ J, J.T @ N, N.T @ N)
            if cache is not None:
                cache[("products", key)] = products
        g.A += products[0]
        g.B += products[1]
        g.C += products[2]
        g.b += J.T @ yy
        g.c += N.T @ yy
        g.yy += float(yy @ yy)
        g.m += len(sel)
        if blocks_s and trace is not None and len(sel):
            spans = cache.get(("blocks", key, blocks_s)) if cache is not None else None
            if spans is None:
                bid = np.floor(traj.t_s[sel] / blocks_s).astype(np.int64)
                edges = np.flatnonzero(np.diff(bid)) + 1
                spans = []
                for a, b in zip(np.r_[0, edges], np.r_[edges, len(sel)]):
                    Wb = np.column_stack([J[a:b], N[a:b]])
                    spans.append((int(bid[a]), a, b, Wb.T @ Wb))
                if cache is not None:
                    cache[("blocks", key, blocks_s)] = spans
            for block, a, b, WWb in spans:
                WW, Wy = g.blocks.get(block, (0.0, 0.0))
                g.blocks[block] = (WW + WWb, Wy + np.concatenate([J[a:b].T @ yy[a:b],
                                                                  N[a:b].T @ yy[a:b]]))
        if not observe:
            continue
        names, inverse = np.unique(segment[sel], return_inverse=True)
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(len(names) + 1))
        ph = phase[sel]
        for i, sid in enumerate(names):
            rs = order[bounds[i]:bounds[i + 1]]
            if ph[rs[0]] == "dwell":
                continue
            Js = J[rs]
            a, n = g.segments.get(sid, (0.0, 0))
            g.segments[sid] = (a + Js.T @ Js, n + len(rs))
            if segment_nuisances:
                Ns = N[rs]
                b, c = g.segment_nuisances.get(sid, (0.0, 0.0))
                g.segment_nuisances[sid] = (b + Js.T @ Ns, c + Ns.T @ Ns)
        lay = program
        a, n = g.layers.get(lay, (0.0, 0))
        g.layers[lay] = (a + J.T @ J, n + len(sel))
    return g


#: the blocks (s of program time) over which the residual may be correlated: the
#: uncertainties hold for model errors that stay within a second (a reversal's spike, a
#: mode's ringing, a short stretch of unmodelled geometry)
BLOCK_S = 1.0


def block_covariance(grams: list[Gram], x: np.ndarray) -> np.ndarray | None:
    """Covariance of the scaled parameters ``x`` from the spread of each block's score
    (its share of the normal equations' right-hand side at the solution, the nuisances
    eliminated) instead of from the noise alone: the sandwich S^-1 (sum s_b s_b^T) S^-1
    with ``S`` the reduced normal matrix (pseudo-inverse).  White noise gives what the
    noise alone gives; a residual correlated within the blocks (what the model lacks)
    gives more.  None when the grams hold no blocks."""
    if not all(g.blocks for g in grams):
        return None
    S, _, _, m = _schur(grams)
    p = len(x)
    omega = np.zeros((p, p))
    n_blocks = 0
    for g in grams:
        Ci = np.linalg.pinv(g.C)
        n = Ci @ (g.c - g.B.T @ x)
        theta = np.r_[x, n]
        M = Ci @ g.B.T  # nuisances' response to the parameters
        for WW, Wy in g.blocks.values():
            t = Wy - WW @ theta
            sb = t[:p] - M.T @ t[p:]
            omega += np.outer(sb, sb)
            n_blocks += 1
    if n_blocks < 2 * p:
        return None  # too few blocks to estimate their spread
    Si = np.linalg.pinv(S, rcond=1e-12, hermitian=True)
    return Si @ omega @ Si * n_blocks / max(n_blocks - 1, 1)


def _schur(grams: list[Gram]) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Parameter block with every experiment's nuisances eliminated."""
    S = sum(g.A for g in grams)
    r = sum(g.b for g in grams)
    yy = 0.0
    m = 0
    for g in grams:
        Ci = np.linalg.pinv(g.C)
        S = S - g.B @ Ci @ g.B.T
        r = r - g.B @ Ci @ g.c
        yy += g.yy - g.c @ Ci @ g.c
        m += g.m
    return 0.5 * (S + S.T), r, yy, m


@dataclass(frozen=True, slots=True)
class Combination:
    """The estimated quantity ``sum coefficient_j * theta_j``, every term kept.

    ``coefficients``: (parameter, coefficient) pairs, normalised so that the term that
    contributes most at typical magnitudes has coefficient 1 (``estimate`` and ``std``
    are in its unit); ``typical``: each term's contribution at its parameter's typical
    magnitude (|coefficient| x prior magnitude), in that unit, same order, largest
    first.  The text may shorten the sum only by contribution, and says how much it
    left out: the estimate and its uncertainty belong to the whole direction."""

    coefficients: tuple[tuple[str, float], ...]
    typical: tuple[float, ...]
    estimate: float
    std: float
    unit: str

    def describe(self, max_terms: int = 6, share: float = 0.05) -> str:
        """Terms in order of contribution; stop after ``max_terms`` or once what is
        left contributes less than ``share`` of the leading term, and show the rest as
        ``+ ...`` with their combined typical contribution."""
        total = list(self.typical)
        n = len(self.coefficients)
        keep = 1
        while keep < min(n, max_terms) and sum(total[keep:]) > share * total[0]:
            keep += 1
        terms = " ".join(f"{'+' if c >= 0 else '-'} {abs(c):.3g}*{name}"
                         for name, c in self.coefficients[:keep])
        if keep < n:
            terms += (f" + ... ({n - keep} more term{'s' if n - keep > 1 else ''}, together "
                      f"up to {sum(total[keep:]):.2g} {self.unit} at typical magnitudes)")
        return f"{terms.lstrip('+ ')} = {self.estimate:.3f} +- {self.std:.3f} {self.unit}"


def _combination(model: ErrorModel, v: np.ndarray, est: float, std: float,
                 scale: np.ndarray) -> Combination:
    """``v . x`` with ``x = theta / scale``: ``sum (v_j / scale_j) theta_j``.  A term's
    contribution at typical magnitude is ``|v_j|``; the largest leads."""
    k = int(np.argmax(np.abs(v)))
    norm = v[k] / scale[k]
    coef = (v / scale) / norm
    typical = np.abs(coef) * scale
    # exact zeros of the direction (parameters it does not touch) are not terms
    order = [j for j in np.argsort(-typical, kind="stable") if typical[j] > 1e-12 * typical[k]]
    return Combination(tuple((model.parameters[j].name, float(coef[j])) for j in order),
                       tuple(float(typical[j]) for j in order),
                       float(est / norm), float(abs(std / norm)), model.parameters[k].unit)


def _observability(S_block: np.ndarray, Vd: np.ndarray, count: int) -> dict:
    if Vd.shape[1] == 0 or count == 0:
        return {"O1": 0.0, "O4": 0.0, "samples": count}
    M = Vd.T @ S_block @ Vd
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (M + M.T)), 0.0, None))
    L = len(sv)
    o1 = float(np.exp(np.mean(np.log(np.maximum(sv, 1e-300)))) / math.sqrt(count))
    o4 = float(sv.min() ** 2 / sv.max()) if sv.max() > 0 else 0.0
    return {"O1": o1, "O4": o4, "samples": count, "dimensions": L}


def _mapper(jobs: int, n: int):
    """``each(f)``: ``[f(0), ..., f(n - 1)]``, in ``jobs`` threads when more than one."""
    if jobs <= 1 or n <= 1:
        return lambda f: [f(k) for k in range(n)]

    def each(f):
        with ThreadPoolExecutor(min(jobs, n)) as pool:
            return list(pool.map(f, range(n)))
    return each


#: the exact chain's Gauss-Newton stops when a step, or what the steps' geometric decay
#: leaves to come, moves no determined combination by more than this share of its
#: standard uncertainty
_EXACT_STEP = 0.01
_EXACT_ITERATIONS = 4


def identification_model(plans: list[PlanFiles], options: ModelOptions
                         ) -> tuple[ErrorModel, dict]:
    """The error model :func:`identify` fits to experiments on these plans (their tested
    travel joined), and that travel."""
    travel = {}
    for plan in plans:
        for k, (lo, hi) in plan.tested_travel().items():
            a, b = travel.get(k, (lo, hi))
            travel[k] = (min(a, lo), max(b, hi))
    return build_model(plans[0].config.machine, travel, options), travel


#: the sensitivities kept between Gauss-Newton steps, every experiment's together; beyond
#: this they are made again at each step (the same numbers, a few seconds more: five
#: 5-minute layers at 1 kHz hold 350 MB of them)
KEPT_SENSITIVITIES_BYTES = 128 << 20
#: an experiment's cache: its sensitivities per chunk are kept under (SENSITIVITIES,
#: chunk), and REMADE says they are made again at each step instead
SENSITIVITIES, REMADE = "sensitivities", "sensitivities made again"


def first_gram(experiment: tuple[PlanFiles, str, Trace], model: ErrorModel,
               extra: np.ndarray | None = None) -> tuple[Gram, dict]:
    """An experiment's normal equations as :func:`identify` first makes them, and the
    sensitivities they were made from (for its Gauss-Newton steps): made ahead, where
    a core is free, and handed to it as ``prepared``."""
    cache: dict = {}
    return experiment_gram(*experiment, model, extra=extra, cache=cache), cache


def identify(experiments: list[tuple[PlanFiles, str, Trace]], options: ModelOptions,
             prior: bool = False, ask: tuple[str, ...] = (),
             extra: list[np.ndarray | None] | None = None,
             groups: list[list["ExtraGroup"]] | None = None, jobs: int = 1,
             prepared: dict[int, tuple[Gram, dict]] | None = None) -> Identification:
    """Identify from one or more traces.

    ``jobs``: threads over the experiments for their normal equations (numpy leaves the
    interpreter while it multiplies; each experiment's sums are made alone, in the same
    order, so the result does not depend on ``jobs``).

    ``extra``: per experiment, more nuisance columns on its trajectory samples (see
    :func:`experiment_gram`), or None; ``groups`` names them (per experiment, the
    :class:`ExtraGroup` of each effect's columns) for the aliasing report.
    ``prepared``: experiment index -> :func:`first_gram` of it (same model, same extra
    columns), made ahead; the result is the same as without."""
    extra = list(extra) if extra is not None else [None] * len(experiments)
    model, travel = identification_model([plan for plan, _, _ in experiments], options)
    for name in ask:
        if name not in model.names:
            raise ConfigError("--ask", f"{name} is not a parameter of this model; parameters: "
                                       f"{', '.join(model.names)}")
    scale = np.array([prior_scale(p) for p in model.parameters])
    prepared = prepared or {}
    for gram, _ in prepared.values():
        if gram.A.shape != (len(model.parameters),) * 2:
            raise ValueError("identify: a prepared gram of another model")
    caches = [prepared[k][1] if k in prepared else {} for k in range(len(experiments))]
    rows = sum(len(plan.trajectory(program).t_s) for plan, program, _ in experiments)
    if rows * len(model.parameters) * 8 > KEPT_SENSITIVITIES_BYTES:
        for cache in caches:
            for key in [k for k in cache if isinstance(k, tuple) and k[0] == SENSITIVITIES]:
                del cache[key]
            cache[REMADE] = True
    each = _mapper(jobs, len(experiments))
    grams = each(lambda k: prepared[k][0] if k in prepared else
                 experiment_gram(*experiments[k], model, extra=extra[k], cache=caches[k]))
    S, r, yy, m = _schur(grams)
    lam, V = np.linalg.eigh(S)
    order = np.argsort(lam)[::-1]
    lam, V = lam[order], V[:, order]
    structural = lam > structural_scale(grams) * STRUCTURAL
    rank = int(structural.sum())
    n_nuis = sum(len(g.c) for g in grams)
    dof = max(m - rank - n_nuis, 1)

    def solve(r, yy, determined=None):
        proj = V.T @ r
        rss = yy - float(np.sum(proj[structural] ** 2 / lam[structural]))
        sigma = math.sqrt(max(rss, 0.0) / dof)
        std = np.where(structural, sigma / np.sqrt(np.maximum(lam, 1e-300)), np.inf)
        if determined is None:
            determined = structural & (std < DETERMINED)
        est = np.where(determined, proj / np.maximum(lam, 1e-300), 0.0)
        return rss, sigma, std, determined, est, V[:, determined] @ est[determined]

    rss, sigma, std, determined, est, x_hat = solve(r, yy)
    # Gauss-Newton on the exact error chain from the first-order solution: the readings
    # are corrected by what the exact chain adds at the current estimate (the directions
    # the data do not determine held at zero), until a step moves no combination by
    # more than 1 % of its standard uncertainty, or until the steps, which shrink
    # geometrically (the Jacobian is kept at the nominal poses), leave less than that
    # to go: the rest of a geometric series, ``step * rate / (1 - rate)``
    steps = []
    remaining = math.inf
    for _ in range(_EXACT_ITERATIONS):
        nuis = [np.linalg.pinv(g.C) @ (g.c - g.B.T @ x_hat) for g in grams]
        corrected = each(lambda k: experiment_gram(*experiments[k], model,
                                                   at=(x_hat * scale, nuis[k]), extra=extra[k],
                                                   cache=caches[k], observe=False,
                                                   blocks_s=BLOCK_S))
        for g_new, g_old in zip(corrected, grams):
            g_new.segments, g_new.layers = g_old.segments, g_old.layers
        _, r_c, yy_c, _ = _schur(corrected)
        rss_c, sigma_c, std_c, _, est_c, x_c = solve(r_c, yy_c, determined)
        step = float(np.max(np.abs(est_c - est)[determined] / std_c[determined], initial=0.0))
        steps.append(step)
        rss, sigma, std, est, x_hat, grams, r = rss_c, sigma_c, std_c, est_c, x_c, corrected, r_c
        if step < _EXACT_STEP:
            remaining = step
            break
        rate = step / steps[-2] if len(steps) >= 2 and steps[-2] > 0 else 1.0
        if rate < 0.5 and step * rate / (1.0 - rate) < _EXACT_STEP:
            remaining = step * rate / (1.0 - rate)
            break
    Vd = V[:, determined]
    # the uncertainty that holds: the larger of what the noise alone gives and what the
    # blocks' spread gives (a model error correlated within a second, which the noise
    # alone does not cover: a reversal spike left in one recording puts combinations
    # several noise-only standard uncertainties off; hard case: analyse-s1-3)
    cov_d = np.diag(std[determined] ** 2)
    hac = block_covariance(grams, x_hat) if determined.any() else None
    if hac is not None:
        cov_b = Vd.T @ hac @ Vd
        sd_b = np.sqrt(np.maximum(np.diag(cov_b), 1e-300))
        # the blocks' covariance, each variance raised to the noise-only one where that
        # is larger (the correlations kept)
        up = np.maximum(std[determined] / sd_b, 1.0)
        cov_d = cov_b * np.outer(up, up)
        std = std.copy()
        std[determined] = np.sqrt(np.diag(cov_d))
    combos = [_combination(model, V[:, i], est[i], std[i], scale) for i in np.flatnonzero(determined)]
    # squareness and scale mismatch as a ballbar reads them, where the data determine them
    figures = trade_figures(functionals([(plan, prog) for plan, prog, _ in experiments], model,
                                        scale),
                            x_hat, Vd, cov_d, model.names)
    individually = []
    aliased = []
    for j, p in enumerate(model.parameters):
        e = np.zeros(len(model.parameters))
        e[j] = 1.0
        inside = float(np.sum((Vd.T @ e) ** 2))
        if inside > 1 - 1e-6:
            w = V[j, determined]
            var = max(float(np.sum(w ** 2 / lam[determined])) * sigma ** 2, float(w @ cov_d @ w))
            individually.append({"parameter": p.name, "estimate": float(x_hat[j] * scale[j]),
                                 "std": float(math.sqrt(var) * scale[j]), "unit": p.unit})
        else:
            aliased.append(p.name)
    # nuisances
    nuisances = []
    for (plan, prog, _), g in zip(experiments, grams):
        n_hat = np.linalg.pinv(g.C) @ (g.c - g.B.T @ x_hat)
        nuisances.append({"program": prog, "centring_um": [float(v) for v in n_hat[:3]],
                          "bar_length_um": float(n_hat[3]),
                          "extra": [float(v) for v in n_hat[4:]]})
    # observability of the determined subspace
    seg_obs, layer_obs = {}, {}
    for g in grams:
        for sid, (a, n) in g.segments.items():
            seg_obs[sid] = _observability(a, Vd, n)
        for lay, (a, n) in g.layers.items():
            layer_obs[lay] = _observability(a, Vd, n)
    report = {
        "model": {"parameters": len(model.parameters), "options": dataclasses.asdict(options),
                  "tested_travel_mm": {k: list(v) for k, v in travel.items()}},
        "samples": m, "experiments": [{"program": p} for _, p, _ in experiments],
        "noise_std_um": sigma, "residual_rms_um": math.sqrt(max(rss, 0.0) / max(m, 1)),
        "rank": rank, "determined": int(determined.sum()),
        "uncertainty": {"method": "the larger of the noise-only and the block-sandwich "
                                  "covariance (blocks of program time)",
                        "block_s": BLOCK_S, "blocks": hac is not None},
        "exact_chain": {"iterations": len(steps), "steps_in_std": steps,
                        "left_in_std": remaining if math.isfinite(remaining) else None,
                        "converged": remaining < _EXACT_STEP},
        "combinations": [{"terms": [{"parameter": n, "coefficient": c, "typical_contribution": t}
                                    for (n, c), t in zip(cb.coefficients, cb.typical)],
                          "estimate": cb.estimate, "std": cb.std, "unit": cb.unit,
                          "text": cb.describe()} for cb in combos],
        "identifiable_parameters": individually,
        "figures": figures,
        # the fitted model (minimum norm: what the data do not determine held at zero),
        # to simulate the readings it predicts; its values are not machine errors one by one
        "model_state": {p.name: float(v) for p, v in zip(model.parameters, x_hat * scale)},
        "not_individually_identifiable": aliased,
        "nuisances": nuisances,
        "observability": {"layers": layer_obs, "segments": seg_obs},
    }
    if groups:
        report["aliasing"] = _aliasing(grams, groups, V[:, determined], lam[determined], combos,
                                       [p for _, p, _ in experiments])
    if prior:
        report["prior_estimates"] = _prior(model, S, r, sigma, scale)
    if ask:
        report["asked"] = [_suggest(name, model, experiments, grams, sigma, individually)
                           for name in ask]
    return Identification.from_parts(**report)


@dataclass(frozen=True, slots=True)
class ExtraGroup:
    """One effect's extra nuisance columns in an experiment (``start:stop`` of its extra
    columns) and how they change in a repeat of the run: in the reverse direction they
    are multiplied by ``reverse`` (-1 for an effect odd in the velocity, +1 for an even
    one, None when it is not that simple); at half the feed by 0.5 ** ``feed_power``
    (None: not a power of the feed)."""

    name: str
    start: int
    stop: int
    reverse: int | None
    feed_power: float | None


#: an effect that makes a determined combination this much less certain (standard
#: uncertainty with it over without it) is reported as aliased with the geometry
ALIASED = 1.5


def _pair_schur(g: Gram, cols: np.ndarray, s: float) -> np.ndarray:
    """The parameter block of ``g``'s run and a second run of it in which the columns
    ``cols`` of the nuisance block (an effect of the machine: the same coefficients)
    read ``s`` times as much; the rest of the nuisance block (set-up, other effects)
    is new in the second run.  The same poses are assumed for both runs."""
    n = len(g.c)
    rest = np.setdiff1d(np.arange(n), cols)
    Brr, Bg = g.B[:, rest], g.B[:, cols]
    Crr, Crg, Cgg = g.C[np.ix_(rest, rest)], g.C[np.ix_(rest, cols)], g.C[np.ix_(cols, cols)]
    z = np.zeros_like(Crr)
    B = np.column_stack([Brr, Brr, Bg * (1.0 + s)])
    C = np.block([[Crr, z, Crg], [z, Crr, s * Crg], [Crg.T, s * Crg.T, (1.0 + s * s) * Cgg]])
    return 2.0 * g.A - B @ np.linalg.pinv(C) @ B.T


def _aliasing(grams: list[Gram], groups: list[list[ExtraGroup]], Vd: np.ndarray,
              lam_d: np.ndarray, combos: list[Combination], programs: list[str]) -> list:
    """Where an effect estimated with the geometry takes its certainty: per effect, the
    determined combinations whose standard uncertainty it multiplies by ``ALIASED`` or
    more, and what a second run would bring (computed on the same poses, the effect's
    coefficients shared by both runs): a plain repeat, the reverse direction, half the
    feed.  Only the separation, not the doubling of the data, is what a repeat lacks."""
    if Vd.shape[1] == 0:
        return []
    S_all = sum(g.A - g.B @ np.linalg.pinv(g.C) @ g.B.T for g in grams)

    def stds(S):
        Sd = Vd.T @ (0.5 * (S + S.T)) @ Vd
        return np.sqrt(np.maximum(np.diag(np.linalg.pinv(Sd)), 0.0))

    base = 1.0 / np.sqrt(lam_d)  # in units of sigma
    out = []
    for k, (g, gs) in enumerate(zip(grams, groups)):
        S_k = g.A - g.B @ np.linalg.pinv(g.C) @ g.B.T
        for grp in gs:
            cols = np.arange(4 + grp.start, 4 + grp.stop)
            keep = np.setdiff1d(np.arange(len(g.c)), cols)
            S_wo = g.A - g.B[:, keep] @ np.linalg.pinv(g.C[np.ix_(keep, keep)]) @ g.B[:, keep].T
            without = stds(S_all - S_k + S_wo)
            factor = base / np.maximum(without, 1e-300)
            hit = np.flatnonzero(factor >= ALIASED)
            if not len(hit):
                continue
            runs = {"repeated as it was": 1.0}
            if grp.reverse is not None:
                runs["repeated in the reverse direction"] = float(grp.reverse)
            if grp.feed_power:
                runs["repeated at half the feed"] = 0.5 ** grp.feed_power
            second = {text: stds(S_all - S_k + _pair_schur(g, cols, sc)) for text, sc in runs.items()}
            for i in hit:
                cb = combos[i]
                out.append({
                    "recording": k, "program": programs[k], "effect": grp.name,
                    "combination": cb.describe(), "std": cb.std,
                    "std_without_effect": cb.std / factor[i], "factor": float(factor[i]),
                    "second_run": [{"run": text, "std": float(cb.std * v[i] / base[i])}
                                   for text, v in second.items()],
                    "unit": cb.unit})
    return out


def _prior(model: ErrorModel, S: np.ndarray, r: np.ndarray, sigma: float, scale: np.ndarray) -> list:
    """Tikhonov estimates (prior: each parameter ~ its prior magnitude) with the
    resolution-matrix diagonal saying whether data or prior drive each number."""
    s2 = max(sigma, 1e-12) ** 2
    P = S / s2 + np.eye(len(r))
    cov = np.linalg.inv(P)
    x = cov @ (r / s2)
    R = cov @ (S / s2)
    out = []
    for j, p in enumerate(model.parameters):
        res = float(R[j, j])
        label = "data-determined" if res > 0.9 else "prior-driven" if res < 0.1 else "partly determined"
        out.append({"parameter": p.name, "estimate": float(x[j] * scale[j]),
                    "std": float(math.sqrt(cov[j, j]) * scale[j]), "unit": p.unit,
                    "resolution": res, "label": label})
    return out


def _candidate_poses(plan: PlanFiles, program: str, kind: str, config: Config):
    """Poses of the same table-frame path under a changed set-up: returns
    (kinematics, q, pivot, description)."""
    traj = plan.trajectory(program)
    kin = Kinematics(config.machine)
    pivot = np.array(config.ballbar.pivot_mm)
    pts = traj.ball_mm
    if kind == "pivot":
        shift = np.array([0.0, 0.0, 50.0])
        cfg = dataclasses.replace(config, ballbar=dataclasses.replace(
            config.ballbar, pivot_mm=tuple(pivot + shift)))
        sched = RotarySchedule(cfg, kin)
        angles, _ = sched.angles(pts + shift)
        return kin, kin.inverse(pts + shift, angles), pivot + shift, "a second pivot height (+50 mm)"
    if kind == "tool":
        machine = dataclasses.replace(config.machine, tool_length_mm=config.machine.tool_length_mm + 50.0)
        kin2 = Kinematics(machine)
        sched = RotarySchedule(config, kin2)
        angles, _ = sched.angles(pts)
        return kin2, kin2.inverse(pts, angles), pivot, "another tool length (+50 mm)"
    rot = config.test.rotary
    names = [a.name for a in config.machine.rotary_axes]
    moving = dataclasses.replace(rot, schedule="moving", tilt_axis=rot.tilt_axis or names[0],
                                 turn_axis=rot.turn_axis or names[-1],
                                 tilt_at_pole_rad=rot.tilt_at_pole_rad or math.radians(45.0))
    cfg = dataclasses.replace(config, test=dataclasses.replace(config.test, rotary=moving))
    angles, _ = RotarySchedule(cfg, kin).angles(pts)
    return kin, kin.inverse(pts, angles), pivot, "moving rotary axes"


def _suggest(name: str, model: ErrorModel, experiments, grams: list[Gram], sigma: float,
             individually: list) -> dict:
    if any(d["parameter"] == name for d in individually):
        return {"parameter": name, "identifiable": True, "needs": []}
    j = model.index(name)
    plan, program, _ = experiments[0]
    config = plan.config
    kinds = ["pivot", "tool"]
    if config.machine.rotary_axes and config.test.rotary.schedule == "locked":
        kinds.append("moving")
    results = []
    for kind in kinds:
        kin2, q, pivot, text = _candidate_poses(plan, program, kind, config)
        g = _design_gram(plan, program, model, kin2, q, pivot, step=10)
        S, _, _, _ = _schur(grams + [g])
        lam, V = np.linalg.eigh(S)
        keep = lam > structural_scale(grams + [g]) * STRUCTURAL
        std = np.where(keep, sigma / np.sqrt(np.maximum(lam, 1e-300)), np.inf)
        det = keep & (std < DETERMINED)
        Vd = V[:, det]
        inside = float(np.sum(Vd[j] ** 2))
        ok = inside > 1 - 1e-6
        var = float(np.sum(V[j, det] ** 2 / lam[det])) * sigma ** 2 if ok else float("inf")
        results.append({"set_up": text, "makes_identifiable": ok,
                        "std": (math.sqrt(var) * prior_scale(model.parameters[j])) if ok else None,
                        "share_in_determined_space": inside})
    return {"parameter": name, "identifiable": False, "needs": results}


def _design_gram(plan: PlanFiles, program: str, model: ErrorModel, kin: Kinematics,
                 q: np.ndarray, pivot: np.ndarray, step: int) -> Gram:
    """Design-only Gram of a candidate set-up, from every ``step``-th pose (weighted)."""
    traj = plan.trajectory(program)
    keep = (traj.phase != "reposition")
    idx = np.flatnonzero(keep)[::step]
    scale = np.array([prior_scale(p) for p in model.parameters])
    J = sensitivities(kin, model, q[idx], pivot) * scale
    p_nom = kin.forward(q[idx])
    u = (p_nom - pivot) / np.linalg.norm(p_nom - pivot, axis=1)[:, None]
    N = _nuisance_columns(u)
    w = float(step)
    n_p = J.shape[1]
    return Gram(w * J.T @ J, w * J.T @ N, w * N.T @ N, np.zeros(n_p), np.zeros(4), 0.0,
                int(len(idx) * step))
