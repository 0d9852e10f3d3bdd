"""Reading the selected findings out: the final fit on every sample (fitted and held
out), each finding's parameters with their standard uncertainties (never more numbers
than the recording's rank), its contribution and where it lives, the effects that
mimic it, whether smooth geometry beyond the library would explain the held-out data
better, and what is left unexplained."""

from __future__ import annotations

import math

import numpy as np

from ..reading.context import Context
from .align import Alignment
from .ambiguity import ALIASED, judge_confidence, merge_aliased
from .effects import GEOMETRIC, Effect, GeometryBeyond, Samples
from .fitting import GAIN_STD, at_rest_check, covariance, noise_estimate, residual_variance, \
    searched_std, seen_parameters, solve
from .heldout import Split
from .options import Options
from .results import Explanation
from .selection import Selection
from .where import locate


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v))) if len(v) else 0.0


def read_out(ctx: Context, lib: list[Effect], split: Split, selection: Selection,
             al: Alignment, opt: Options, mimic_library: list[Effect] | None = None,
             geometry: GeometryBeyond | None = None, opened: dict | None = None
             ) -> Explanation:
    """The explanation of the recording at the timing ``al`` by what ``selection``
    chose (run on ``split``): parameters and contributions from the final fit on every
    sample; ``mimic_library``: the effects tried as mimics (default ``lib``);
    ``geometry``: the smooth geometry beyond the library the geometric findings are
    checked against (None: not checked); ``opened``: effect -> parameter -> the
    standard uncertainty its timing parameter's profile with the timing leaves it
    (the timing parameter's own uncertainty is at least that, the others' take it in
    in quadrature)."""
    tr, ho, idx, tau, gap, held = split.tr, split.ho, split.idx, split.tau, split.gap, split.held
    S_tr, S_ho, y_tr, y_ho = split.S_tr, split.S_ho, split.y_tr, split.y_ho
    chosen, findings, ranked = selection.chosen, selection.findings, selection.ranked
    cols_tr, cols_ho = selection.cols_tr, selection.cols_ho
    sel = split.sel
    # final fit on all fitted + held-out samples: parameters and contributions
    allsel = np.sort(np.r_[tr, ho])
    S_all = Samples(idx[allsel], tau[allsel])
    blocks, slices = [], []
    for eff, nl, labels in chosen:
        C, _ = eff.columns(ctx, S_all, nl)
        slices.append(slice(sum(b.shape[1] for b in blocks), sum(b.shape[1] for b in blocks) + C.shape[1]))
        blocks.append(C)
    y_all = gap[allsel]
    if blocks:
        A = np.column_stack(blocks)
        beta = solve(A, y_all)
        fitted = A @ beta
    else:
        beta, fitted = np.zeros(0), np.zeros(len(allsel))
    resid = y_all - fitted
    noise = noise_estimate(resid, tau[allsel])
    cov = (covariance(A, resid, tau[allsel]) + GAIN_STD ** 2 * np.outer(beta, beta)
           if blocks else np.zeros((0, 0)))
    if blocks:
        at_rest_check(ctx, A, beta, cov, y_all, idx[allsel], tau[allsel],
                       [sl for (eff, _, _), sl in zip(chosen, slices)
                        if not eff.time_locked])
    var_all = residual_variance(resid, tau[allsel])
    series_idx = idx[allsel]
    contribs = {}
    for f, (eff, nl, labels), sl in zip(findings, chosen, slices):
        contrib = blocks[slices.index(sl)] @ beta[sl]
        contribs[f.effect] = contrib
        f.parameters, f.unseen, f.uncertainty, f.undetermined = seen_parameters(
            eff, blocks[slices.index(sl)], beta[sl], labels, nl, ctx, cov[sl, sl])
        searched = [k for k, v in f.parameters.items() if isinstance(v, float)
                    and k not in f.uncertainty and isinstance(nl.get(k), float)]
        if searched:
            std, lost, spill = searched_std(eff, nl, searched, labels, ctx, S_all,
                                             np.delete(A, np.arange(A.shape[1])[sl], axis=1),
                                             y_all, var_all)
            for k, v in spill.items():
                if k in f.uncertainty:
                    f.uncertainty[k] = math.sqrt(f.uncertainty[k] ** 2 + v)
            f.uncertainty.update(std)
            f.undetermined += lost
            f.parameters = {k: v for k, v in f.parameters.items() if k not in lost}
        # the profile with the timing (a common lag, the start and the lag differences
        # moving together) reads what one timing cannot: what it leaves open counts
        timing_key = eff.timing_parameter[0] if eff.timing_parameter else None
        for k, v in (opened or {}).get(f.effect, {}).items():
            if k not in f.uncertainty or k not in f.parameters:
                continue
            f.uncertainty[k] = (max(f.uncertainty[k], v) if k == timing_key
                                else math.hypot(f.uncertainty[k], v))
        f.contribution_rms_um = _rms(contrib)
        f.where = locate(ctx, series_idx, tau[allsel], contrib)
        # mimics: which other effects reproduce this finding's own signal
        sig = contrib[np.isin(allsel, tr)]
        tot = float(sig @ sig)
        for other in mimic_library or lib:
            if other.name == eff.name or tot <= 0:
                continue
            try:
                nl2 = other.search(ctx, S_tr, sig)
            except (ValueError, np.linalg.LinAlgError):
                nl2 = None
            if nl2 is None:
                continue
            C2, labels2 = other.columns(ctx, S_tr, nl2)
            if C2.shape[1] == 0:
                continue
            c2 = solve(C2, sig)
            if not other.physical(c2) or other.implausible(other.parameters(c2, labels2, nl2, ctx)):
                continue  # only with parameters no machine has: not a mimic
            r2 = 1.0 - float(((sig - C2 @ c2) ** 2).sum()) / tot
            if r2 >= opt.mimic_r2:
                f.mimics.append({"effect": other.name, "r2": round(r2, 4)})
        f.mimics.sort(key=lambda m: -m["r2"])
        for pair, how in ALIASED.items():
            if f.effect in pair:
                other = next(iter(pair - {f.effect}))
                if any(m["effect"] == other for m in f.mimics):
                    f.ambiguous_with = [other]
                    f.separate_by = how
        judge_confidence(f)
    findings = merge_aliased(findings, contribs, ctx, series_idx, tau[allsel])
    gap_rms = _rms(gap)
    un_rms = _rms(resid)
    unexplained = {"rms_um": un_rms, "noise_um": noise,
                   "significant": bool(un_rms > 1.25 * noise and un_rms - noise > 0.05),
                   "where": locate(ctx, series_idx, tau[allsel], resid, noise=noise)}
    # would smooth geometry outside the library fit the held-out data better than the
    # geometric findings do?  Then they may only stand in for it: say so.
    geo_doubt = None
    if geometry is not None and any(f.effect in GEOMETRIC for f in findings):
        G_tr, _ = geometry.columns(ctx, S_tr, {})
        G_ho, _ = geometry.columns(ctx, S_ho, {})
        A_tr = np.column_stack([cols_tr[j] for j in ranked] + [G_tr]) if G_tr.shape[1] else None
        if A_tr is not None:
            A_ho = np.column_stack([cols_ho[j] for j in ranked] + [G_ho])
            beta = solve(A_tr, y_tr)
            with_geo = float(np.mean((y_ho - A_ho @ beta) ** 2))
            base_ho = findings[-1].heldout_rms_after_um ** 2 if findings else float(np.mean(y_ho ** 2))
            gain = base_ho - with_geo
            if gain > max(0.1 * base_ho, (opt.min_effect_noise * noise) ** 2):
                geo_doubt = math.sqrt(gain)
                for f in findings:
                    if f.effect in GEOMETRIC:
                        f.geometry_doubt = True
                        judge_confidence(f)
    unexplained["geometry_beyond_library_um"] = geo_doubt
    if geo_doubt is not None:
        unexplained["significant"] = True
        unexplained["note"] = ("smooth position-locked geometry outside the library (straightness "
                               "or angular errors) explains held-out data better than the "
                               "geometric findings: identify it with sdit-path identify")
    gap_info = {"rms_um": gap_rms, "max_abs_um": float(np.max(np.abs(gap))) if len(gap) else 0.0,
                "where": locate(ctx, idx, tau, gap, noise=noise, detail=True)}
    return Explanation("", al, gap_info, findings, unexplained, noise,
                       {"in_program": int(len(sel)), "fitted": int(len(tr)), "heldout": int(len(ho)),
                      "dropouts": split.dropouts},
                       {"tau": tau[allsel], "gap": y_all, "fitted": fitted, "residual": resid,
                      "idx": series_idx, "held": held[allsel]})
