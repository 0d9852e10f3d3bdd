"""Stepwise selection of the effects that explain a recording's gap.

Effects are added by forward selection: at each step every candidate searches its
nonlinear parameters on the current residual, the one that lowers the training
residual most is tried, and it is kept only when (1) an information criterion (BIC
with an effective sample count that accounts for the residual's correlation in time)
says the data support its parameters, and (2) the residual on held-out stretches
(:mod:`.heldout`) shrinks too.  Then what the full model no longer needs is dropped, a
finding taken early as a proxy is exchanged for a better one, and each finding's
nonlinear parameters are searched again and read back from the joint fit.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..reading.context import Context
from .columns import search_candidate
from .effects import ALIASED, MOUNTING, PRIOR_ORDER, Effect
from .fitting import serial_correlation, solve
from .heldout import Split, heldout_need
from .options import Options
from .results import FindingDraft

log = logging.getLogger(__name__)


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v))) if len(v) else 0.0


class Selection:
    """The selection on one split of one recording.  After :meth:`run`: ``findings``
    (ranked by importance, with their RMS before and after in that order), ``chosen``
    (their effect, nonlinear parameters and labels, in the same order) and, by the
    order they were found in, ``cols_tr`` and ``cols_ho`` (their columns on the fitted
    and held-out samples) and ``ranked`` (those indices, most important first)."""

    def __init__(self, ctx: Context, lib: list[Effect], split: Split, opt: Options, step,
                 pinned: dict | None = None):
        self.ctx, self.lib, self.split, self.opt, self.step = ctx, lib, split, opt, step
        self.pinned = pinned
        self.S_tr, self.S_ho = split.S_tr, split.S_ho
        self.y_tr, self.y_ho = split.y_tr, split.y_ho
        self.n_tr, self.n_ho = len(split.tr), len(split.ho)
        self.noise = split.noise_um
        self.chosen: list[tuple[Effect, dict, tuple]] = []
        self.findings: list[FindingDraft] = []
        self.cols_tr: list[np.ndarray] = []
        self.cols_ho: list[np.ndarray] = []
        self.ranked: list[int] = []
        # searches on the residual of a given set of columns are deterministic: the
        # exchange step meets the forward steps' residuals again (a finding's place tried
        # with the findings chosen before it), so they are kept, keyed by those columns
        self._searched: dict[tuple, dict] = {}
        self._alive: list[np.ndarray] = []  # the keys are ids: keep their arrays

    def run(self) -> "Selection":
        self.forward()
        keep = self.exchange(self.prune(range(len(self.chosen))))
        if self.polish(keep) | self.settle(keep):
            keep = self.prune(keep)
        self._rank(keep)
        return self

    # -- the pieces --------------------------------------------------------------------

    def candidate(self, eff: Effect, rest_cols: list[np.ndarray], r: np.ndarray):
        """:func:`.columns.search_candidate` on the fitted samples, kept per set of
        columns the residual ``r`` is left by."""
        key = tuple(id(c) for c in rest_cols)
        memo = self._searched.setdefault(key, {})
        if eff.name not in memo:
            memo[eff.name] = search_candidate(eff, self.ctx, self.S_tr, r, self.pinned)
        return memo[eff.name]

    def _take(self, f: FindingDraft, eff: Effect, nl: dict, labels, C_tr: np.ndarray,
              C_ho: np.ndarray, A_tr: np.ndarray, A_ho: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """A finding added: its columns kept; the fitted and held-out designs grown."""
        self.findings.append(f)
        self.chosen.append((eff, nl, labels))
        self.cols_tr.append(C_tr)
        self.cols_ho.append(C_ho)
        self._alive.append(C_tr)
        return np.column_stack([A_tr, C_tr]), np.column_stack([A_ho, C_ho])

    def _n_eff(self, r: np.ndarray) -> float:
        """The fitted samples counted as independent ones, by ``r``'s correlation."""
        rho = serial_correlation(r, self.S_tr.tau_s)
        return max(self.n_tr * (1 - rho) / (1 + rho), 10.0)

    def fit(self, keep) -> tuple[np.ndarray, np.ndarray]:
        """The residuals on the fitted and the held-out samples of the findings ``keep``
        fitted together on the fitted ones."""
        if not keep:
            return self.y_tr.copy(), self.y_ho.copy()
        A = np.column_stack([self.cols_tr[i] for i in keep])
        B = np.column_stack([self.cols_ho[i] for i in keep])
        beta = solve(A, self.y_tr)
        return self.y_tr - A @ beta, self.y_ho - B @ beta

    def forward(self) -> None:
        """Forward selection until no candidate passes or ``max_effects`` are in."""
        ctx, opt, noise = self.ctx, self.opt, self.noise
        y_tr, y_ho, S_ho = self.y_tr, self.y_ho, self.S_ho
        A_tr = np.zeros((self.n_tr, 0))
        A_ho = np.zeros((self.n_ho, 0))
        r_tr, r_ho = y_tr.copy(), y_ho.copy()
        while len(self.findings) < opt.max_effects:
            self.step(f"selection step {len(self.findings) + 1}")
            n_eff = self._n_eff(r_tr)
            rss0 = float(r_tr @ r_tr)
            q, _ = np.linalg.qr(A_tr) if A_tr.shape[1] else (np.zeros((self.n_tr, 0)), None)
            trials = []
            for eff in self.lib:
                if any(eff.name == c[0].name for c in self.chosen):
                    continue
                cand = self.candidate(eff, self.cols_tr, r_tr)
                if cand is None:
                    continue
                nl, C_tr, labels = cand
                Cp = C_tr - q @ (q.T @ C_tr)
                keep = np.sqrt((Cp * Cp).sum(0)) > 1e-9 * max(
                    1.0, float(np.sqrt((C_tr * C_tr).sum(0)).max()))
                if not keep.any():
                    continue
                coef = solve(Cp[:, keep], r_tr)
                fit = Cp[:, keep] @ coef
                gain = float(r_tr @ r_tr - (r_tr - fit) @ (r_tr - fit))
                trials.append((gain, eff, nl, C_tr, labels, int(keep.sum())))
            if not trials:
                break
            dbics = {id(t): n_eff * math.log(rss0 / max(rss0 - t[0], 1e-30))
                     - t[5] * math.log(n_eff) for t in trials}
            trials.sort(key=lambda t: -dbics[id(t)])
            # equal evidence (within the BIC margin): the more common effect first
            best = dbics[id(trials[0])]
            tied = sorted((t for t in trials if best - dbics[id(t)] < opt.bic_margin),
                          key=lambda t: PRIOR_ORDER.index(t[1].name))
            trials = tied + [t for t in trials if all(t is not u for u in tied)]
            if log.isEnabledFor(logging.DEBUG):
                log.debug("  candidates: %s", ", ".join(
                    f"{t[1].name} {dbics[id(t)]:.1f}" for t in trials[:6]))
            accepted = None
            for rank, (gain, eff, nl, C_tr, labels, p) in enumerate(trials):
                dbic = dbics[id(trials[rank])]
                if dbic < opt.bic_margin:
                    continue
                A1 = np.column_stack([A_tr, C_tr])
                beta = solve(A1, y_tr)
                C_ho, _ = eff.columns(ctx, S_ho, nl)
                B1 = np.column_stack([A_ho, C_ho])
                new_tr, new_ho = y_tr - A1 @ beta, y_ho - B1 @ beta
                if not eff.physical(beta[A_tr.shape[1]:]):
                    log.debug("%s: not physical", eff.name)
                    continue
                why = eff.implausible(eff.parameters(beta[A_tr.shape[1]:], labels, nl, ctx))
                if why:
                    log.debug("%s: implausible (%s)", eff.name, why)
                    continue
                mse_ho = float(np.mean(r_ho ** 2))
                need = heldout_need(opt, mse_ho, noise, C_ho)
                if mse_ho - float(np.mean(new_ho ** 2)) < need:
                    log.debug("%s %s: held-out MSE %.4g -> %.4g, needs a drop of %.3g", eff.name,
                              nl, mse_ho, float(np.mean(new_ho ** 2)), need)
                    continue
                accepted = (eff, nl, labels, C_tr, C_ho, beta, new_tr, new_ho, dbic, rank)
                break
            if accepted is None:
                joint = self._joint_mounting(trials, A_tr, A_ho, r_ho, rss0, n_eff)
                if joint is None:
                    break
                for eff, nl, labels, C_tr, C_ho, dbic in joint[0]:
                    A_tr, A_ho = self._take(
                        FindingDraft(eff.name, eff.title, {}, nl, labels, _rms(r_tr),
                                     _rms(joint[1]), _rms(r_ho), _rms(joint[2]), dbic),
                        eff, nl, labels, C_tr, C_ho, A_tr, A_ho)
                r_tr, r_ho = joint[1], joint[2]
                continue
            eff, nl, labels, C_tr, C_ho, beta, new_tr, new_ho, dbic, rank = accepted
            others = [t for t in trials if t[1] is not eff]
            ru = others[0] if others else None
            f = FindingDraft(eff.name, eff.title, {}, nl, labels, _rms(r_tr), _rms(new_tr),
                             _rms(r_ho), _rms(new_ho), dbic)
            if ru is not None:
                f.runner_up = ru[1].name
                f.runner_up_ratio = trials[rank][0] / max(ru[0], 1e-30)
            A_tr, A_ho = self._take(f, eff, nl, labels, C_tr, C_ho, A_tr, A_ho)
            r_tr, r_ho = new_tr, new_ho

    def _joint_mounting(self, trials, A_tr, A_ho, r_ho, rss0, n_eff, companions: int = 3):
        """When no single effect passes a forward step and no part of the mounting is in
        yet, its parts tried at once: a first geometry estimate that moves part of the
        centring into a constant (the two are not separable from geometry) leaves a gap
        neither part can take alone, each makes the held-out stretches worse, and the
        effect behind them is never reached (hard case: analyse-s2-1).  If they fail,
        with each of the ``companions`` best other candidates: a servo mismatch beside a
        centring of microns leaves a gap that the two take together, while each alone
        leaves too much for the residual's correlation to let either in, and nothing is
        found (hard case: blind-bad-SDIT_B-s2-3).  ``([(effect, nl, labels, C_tr, C_ho, dbic)
        ...], new_tr, new_ho)`` when the group passes the same tests a single effect
        must, else None.

        On a layer whose bar direction varies little the ball centres (seen as
        -u . shift) and the bar length (a constant) are far from orthogonal, so that
        either alone can fit the fitted stretches and miss the held-out ones."""
        if any(c[0].name in MOUNTING for c in self.chosen):
            return None
        parts = [next((t for t in trials if t[1].name == name), None) for name in MOUNTING]
        if any(t is None for t in parts):
            return None
        others = [t for t in trials if t[1].name not in MOUNTING][:companions]
        for extra in (None, *others):
            group = parts if extra is None else [*parts, extra]
            out = self._joint_group(group, A_tr, A_ho, r_ho, rss0, n_eff)
            if out is not None:
                return out
        return None

    def _joint_group(self, group, A_tr, A_ho, r_ho, rss0, n_eff):
        """The effects of ``group`` (trials) added at once, if together they pass the BIC
        margin, each is physical and plausible, and the held-out stretches improve as a
        single effect's must."""
        ctx, opt, y_tr, y_ho = self.ctx, self.opt, self.y_tr, self.y_ho
        C_tr = np.column_stack([t[3] for t in group])
        A1 = np.column_stack([A_tr, C_tr])
        beta = solve(A1, y_tr)
        new_tr = y_tr - A1 @ beta
        p = C_tr.shape[1]
        dbic = n_eff * math.log(rss0 / max(float(new_tr @ new_tr), 1e-30)) - p * math.log(n_eff)
        if dbic < opt.bic_margin:
            return None
        out, k = [], A_tr.shape[1]
        for _gain, eff, nl, C, labels, _p in group:
            coef = beta[k:k + C.shape[1]]
            if not eff.physical(coef) or eff.implausible(eff.parameters(coef, labels, nl, ctx)):
                return None
            out.append((eff, nl, labels, C, eff.columns(ctx, self.S_ho, nl)[0], dbic / len(group)))
            k += C.shape[1]
        C_ho = np.column_stack([o[4] for o in out])
        new_ho = y_ho - np.column_stack([A_ho, C_ho]) @ beta
        mse_ho = float(np.mean(r_ho ** 2))
        if mse_ho - float(np.mean(new_ho ** 2)) < heldout_need(opt, mse_ho, self.noise, C_ho):
            return None
        log.debug("%s together: BIC %+.1f, held-out MSE %.4g -> %.4g",
                  " and ".join(t[1].name for t in group), dbic, mse_ho, float(np.mean(new_ho ** 2)))
        return out, new_tr, new_ho

    def prune(self, keep) -> list[int]:
        """Backward elimination: drop what the full model no longer needs (the least
        needed first) until every finding passes both tests beside the others."""
        opt = self.opt
        keep = list(keep)
        while len(keep) > 1:
            full_tr, full_ho = self.fit(keep)
            n_eff = self._n_eff(full_tr)
            rss_full = float(full_tr @ full_tr)
            worst, worst_score = None, math.inf
            for i in keep:
                red_tr, red_ho = self.fit([k for k in keep if k != i])
                p = self.cols_tr[i].shape[1]
                dbic = (n_eff * math.log(float(red_tr @ red_tr) / max(rss_full, 1e-30))
                        - p * math.log(n_eff))
                mse_ho = float(np.mean(red_ho ** 2))
                need = heldout_need(opt, mse_ho, self.noise, self.cols_ho[i])
                ok = dbic >= opt.bic_margin and mse_ho - float(np.mean(full_ho ** 2)) >= need
                if not ok and dbic < worst_score:
                    worst, worst_score = i, dbic
            if worst is None:
                break
            keep.remove(worst)
        return keep

    def exchange(self, keep) -> list[int]:
        """Greedy forward selection can take a proxy early (a scale error standing in for
        a bar length plus part of a lag not yet in): with the others in, try each
        finding's place for every effect not chosen; take the best exchange that the
        information criterion prefers and held-out data do not refuse, until none."""
        ctx, opt, noise = self.ctx, self.opt, self.noise
        y_tr, y_ho, cols_tr, cols_ho = self.y_tr, self.y_ho, self.cols_tr, self.cols_ho
        n_tr = self.n_tr
        for _ in range(len(keep) + 1):
            full_tr, full_ho = self.fit(keep)
            n_eff = self._n_eff(full_tr)
            rss_full = float(full_tr @ full_tr)
            mse_full_ho = float(np.mean(full_ho ** 2))
            best = None
            names = {self.chosen[k][0].name for k in keep}
            for i in keep:
                rest = [k for k in keep if k != i]
                red_tr, _ = self.fit(rest)
                A_rest = (np.column_stack([cols_tr[k] for k in rest]) if rest
                          else np.zeros((n_tr, 0)))
                B_rest = (np.column_stack([cols_ho[k] for k in rest]) if rest
                          else np.zeros((self.n_ho, 0)))
                for eff in self.lib:
                    if eff.name in names:
                        continue
                    cand = self.candidate(eff, [cols_tr[k] for k in rest], red_tr)
                    if cand is None:
                        continue
                    nl, C_tr, labels = cand
                    A1 = np.column_stack([A_rest, C_tr])
                    beta = solve(A1, y_tr)
                    new_tr = y_tr - A1 @ beta
                    rss = float(new_tr @ new_tr)
                    dbic = (n_eff * math.log(rss_full / max(rss, 1e-30))
                            + (cols_tr[i].shape[1] - C_tr.shape[1]) * math.log(n_eff))
                    # fewer columns that lose less than a finding must bring (a bar
                    # length where a scale error of three columns holds a sliver more,
                    # far below the noise, which on a long recording the criterion
                    # still counts; hard case: blind-bad-SDIT_C-s1-26): the simpler one,
                    # whatever such a sliver does to the information criterion
                    # (and, the other way, more columns must bring that much)
                    extra = C_tr.shape[1] - cols_tr[i].shape[1]
                    C_ho = eff.columns(ctx, self.S_ho, nl)[0] if extra > 0 else None
                    if extra < 0:
                        ok = dbic > 0 or (rss - rss_full) / n_tr < heldout_need(
                            opt, rss / n_tr, noise, cols_ho[i])
                    elif extra > 0:
                        ok = dbic > 0 and (rss_full - rss) / n_tr >= heldout_need(
                            opt, rss_full / n_tr, noise, C_ho)
                    else:
                        ok = dbic > 0
                    score = (ok, dbic)
                    if not ok or (best is not None and score <= best[0]):
                        continue
                    coef = beta[A_rest.shape[1]:]
                    if not eff.physical(coef) or eff.implausible(
                            eff.parameters(coef, labels, nl, ctx)):
                        continue
                    if C_ho is None:
                        C_ho = eff.columns(ctx, self.S_ho, nl)[0]
                    new_ho = y_ho - np.column_stack([B_rest, C_ho]) @ beta
                    # held-out data refuse the exchange when the finding it replaces,
                    # added back, would pass their test: an equal fit with fewer
                    # columns (a bar length where a scale error stood in for it) must
                    # not lose to the held-out samples' noise
                    mse_new_ho = float(np.mean(new_ho ** 2))
                    if mse_new_ho - mse_full_ho >= heldout_need(opt, mse_new_ho, noise,
                                                                cols_ho[i]):
                        log.debug("exchange %s for %s: held-out MSE %.5g -> %.5g", eff.name,
                                  self.chosen[i][0].name, mse_full_ho, mse_new_ho)
                        continue
                    best = (score, i, eff, nl, labels, C_tr, C_ho)
            if best is None:
                return keep
            (_, dbic), i, eff, nl, labels, C_tr, C_ho = best
            log.debug("exchange: %s for %s (BIC %+.1f)", eff.name, self.chosen[i][0].name, dbic)
            old = self.findings[i]
            self.findings[i] = FindingDraft(eff.name, eff.title, {}, nl, labels, old.rms_before_um,
                                            old.rms_after_um, old.heldout_rms_before_um,
                                            old.heldout_rms_after_um, old.delta_bic + dbic)
            if dbic < 0 and frozenset({eff.name, old.effect}) in ALIASED:
                # taken as the simpler of two the criterion ranks the other way: the one
                # it replaces fits at least as well (a pair one feed cannot tell apart)
                self.findings[i].runner_up, self.findings[i].runner_up_ratio = old.effect, 1.0
            self.chosen[i] = (eff, nl, labels)
            cols_tr[i], cols_ho[i] = C_tr, C_ho
            self._alive.append(C_tr)
            keep = self.prune(keep)
        return keep

    def polish(self, keep) -> bool:
        """The forward steps searched each finding's nonlinear parameters on what the
        findings before it left: with all the others in, each is searched again and
        its new parameters kept when the fit improves on the fitted and the held-out
        samples.  A play operator's width searched before the bar length is in comes out
        short, and the ramp it misses after every reversal comes back as a reversal spike
        (hard case: test-play-sized-with-the-others).  True when something moved."""
        ctx, cols_tr, cols_ho, y_tr, y_ho = self.ctx, self.cols_tr, self.cols_ho, self.y_tr, self.y_ho
        moved = False
        for _ in range(2):
            changed = False
            full_tr, full_ho = self.fit(keep)
            for i in keep:
                eff, nl_old, _labels = self.chosen[i]
                rest = [k for k in keep if k != i]
                red_tr, _ = self.fit(rest)
                cand = self.candidate(eff, [cols_tr[k] for k in rest], red_tr)
                if cand is None or cand[0] == nl_old:
                    continue
                nl, C_tr, labels = cand
                A_rest = (np.column_stack([cols_tr[k] for k in rest]) if rest
                          else np.zeros((self.n_tr, 0)))
                A1 = np.column_stack([A_rest, C_tr])
                beta = solve(A1, y_tr)
                new_tr = y_tr - A1 @ beta
                if float(new_tr @ new_tr) >= float(full_tr @ full_tr):
                    continue
                coef = beta[A_rest.shape[1]:]
                if not eff.physical(coef) or eff.implausible(eff.parameters(coef, labels, nl, ctx)):
                    continue
                C_ho = eff.columns(ctx, self.S_ho, nl)[0]
                B_rest = (np.column_stack([cols_ho[k] for k in rest]) if rest
                          else np.zeros((self.n_ho, 0)))
                new_ho = y_ho - np.column_stack([B_rest, C_ho]) @ beta
                if float(np.mean(new_ho ** 2)) > float(np.mean(full_ho ** 2)):
                    continue
                log.debug("polish %s: %s -> %s", eff.name, nl_old, nl)
                self.chosen[i] = (eff, nl, labels)
                cols_tr[i], cols_ho[i] = C_tr, C_ho
                self._alive.append(C_tr)
                self.findings[i].nonlinear, self.findings[i].labels = nl, labels
                full_tr, full_ho = self.fit(keep)
                changed = moved = True
            if not changed:
                break
        return moved

    def settle(self, keep) -> bool:
        """Nonlinear parameters that the fitted coefficients fix (a servo mismatch's lag
        differences, which shape its own second order; a play's width and slack, which
        shape its columns) read back from the fit with every finding in, until they hold
        to 1 %: a search reads them on what the findings before it leave, without the
        others beside, and another finding (a mode's deflection) takes up what the
        difference leaves at the accelerations (hard case: blind-bad-SDIT_B-s1-37).  True
        when something moved."""
        ctx, cols_tr, cols_ho = self.ctx, self.cols_tr, self.cols_ho
        moved = False
        beta = None  # the joint fit, made again only after a finding's columns changed
        for _ in range(4):
            changed = False
            for i in keep:
                eff, nl_old, labels = self.chosen[i]
                if beta is None:
                    beta = solve(np.column_stack([cols_tr[k] for k in keep]), self.y_tr)
                at = sum(cols_tr[k].shape[1] for k in keep[:keep.index(i)])
                nl = eff.from_fit(nl_old, beta[at:at + cols_tr[i].shape[1]], labels)
                if nl is None or all(
                        abs(nl[k] - nl_old.get(k, 0.0)) <= 0.01 * max(abs(nl[k]), 1e-3)
                        for k in nl if isinstance(nl[k], float)):
                    continue
                # taken whatever the fit says: a column shaped with one value and
                # scaled to another is no machine's (a slack ramp shaped for one size and
                # scaled to several times it has the axis catch up faster than the command
                # moves; hard case: blind-bad-SDIT5_C-s1-38); the timing polished with
                # the model then moves to where the shape is right
                C_tr, labels_new = eff.columns(ctx, self.S_tr, nl)
                C_ho = eff.columns(ctx, self.S_ho, nl)[0]
                cols_tr[i], cols_ho[i] = C_tr, C_ho
                log.debug("settle %s: %s -> %s", eff.name, nl_old, nl)
                self.chosen[i] = (eff, nl, labels_new)
                self._alive.append(C_tr)
                self.findings[i].nonlinear, self.findings[i].labels = nl, labels_new
                changed = moved = True
                beta = None
            if not changed:
                break
        return moved

    def _rank(self, keep: list[int]) -> None:
        """Rank by importance (what the fit loses without it) and recount each finding's
        RMS before and after in that order."""
        if keep:
            full_tr, _ = self.fit(keep)
            loss = {i: float(self.fit([k for k in keep if k != i])[0]
                             @ self.fit([k for k in keep if k != i])[0])
                    - float(full_tr @ full_tr) for i in keep}
            keep.sort(key=lambda i: -loss[i])
        ranked = []
        before_tr, before_ho = self.y_tr, self.y_ho
        for n_in, i in enumerate(keep, start=1):
            after_tr, after_ho = self.fit(keep[:n_in])
            f = self.findings[i]
            f.rms_before_um, f.rms_after_um = _rms(before_tr), _rms(after_tr)
            f.heldout_rms_before_um, f.heldout_rms_after_um = _rms(before_ho), _rms(after_ho)
            before_tr, before_ho = after_tr, after_ho
            ranked.append(i)
        self.findings = [self.findings[i] for i in ranked]
        self.chosen = [self.chosen[i] for i in ranked]
        self.ranked = ranked
