"""Reading the selected findings out: the final fit on every sample (fitted and held
out), each finding's parameters with their standard uncertainties (never more numbers
than the recording's rank), its contribution and where it lives, the effects that
mimic it, whether smooth geometry beyond the library would explain the held-out data
better, and what is left unexplained."""

from __future__ import annotations

import math

import numpy as np

from ..reading.context import Context, nearest_samples
from .align import Alignment
from .ambiguity import ALIASED, judge_confidence, merge_aliased
from .effects import GEOMETRIC, Effect, GeometryBeyond, Samples
from .fitting import GAIN_STD, at_rest_check, covariance, noise_estimate, residual_variance, \
    searched_std, seen_parameters, solve
from .heldout import Split
from .options import Options
from .results import Explanation, FindingDraft, ProfileOpen
from .selection import Selection
from .where import locate


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v))) if len(v) else 0.0


def _profile_open(f: FindingDraft, key: str, prof: ProfileOpen) -> None:
    """``f``'s uncertainties widened by what the profile of its timing parameter
    ``key`` with the timing (a common lag, the start and the lag differences moving
    together) leaves open: a timing (one fit) cannot read that."""
    if key in f.uncertainty and key in f.parameters:
        f.uncertainty[key] = max(f.uncertainty[key], prof.std.get(key, 0.0))
        open_key = f.uncertainty[key]
    else:
        open_key = prof.std.get(key, 0.0)
    for k in f.uncertainty:
        if k == key or k not in f.parameters:
            continue
        along = max(prof.std.get(k, 0.0), abs(prof.slope.get(k, 0.0)) * open_key)
        f.uncertainty[k] = math.hypot(f.uncertainty[k], along)


#: the steps (s, ppm) at most at which the findings are fitted again with the timing
#: moved: a slope there times the timing's stated uncertainty is what that carries
TIMING_STEP_S, TIMING_STEP_PPM = 0.002, 5.0


def _timing_spill(ctx: Context, chosen: list, slices: list, expected: np.ndarray,
                  tau: np.ndarray, gap: np.ndarray, al: Alignment) -> list[dict]:
    """Per finding of ``chosen`` (its columns at ``slices`` of the final fit), parameter
    -> the variance the recording's timing carries into it: the findings fitted again
    on the same samples (program times ``tau``, readings less the expected one ``gap``)
    with the start, then the clock, moved each way by their standard uncertainty (at
    most :data:`TIMING_STEP_S`, :data:`TIMING_STEP_PPM`: a slope, times the
    uncertainty), the change squared.  Fitted at one timing, a parameter's covariance is
    what it has at that timing; on a slow program the start is known to milliseconds
    and a lag difference moves with it by several of those uncertainties (hard case:
    the memory benchmark's one-hour recording, lag Z-X 0.0027 ms per ms of start)."""
    out: list[dict] = [{} for _ in chosen]
    if not chosen:
        return out
    t0, T = float(ctx.t_s[0]), float(ctx.t_s[-1])
    t_m = al.measured_time(tau)
    reading = gap + np.interp(tau, ctx.t_s, expected)
    for std, most, move in ((al.offset_std_s, TIMING_STEP_S, (1.0, 0.0)),
                            (al.clock_std_ppm, TIMING_STEP_PPM, (0.0, 1.0))):
        if not (math.isfinite(std) and std > 0.0):
            continue
        h = min(std, most)
        found = []
        for sign in (1.0, -1.0):
            off = al.offset_s + sign * h * move[0]
            ppm = al.clock_ppm + sign * h * move[1]
            tt = np.clip((t_m - off) / (1.0 + ppm * 1e-6), t0, T)
            S = Samples(nearest_samples(ctx, tt), tt)
            A = np.column_stack([eff.columns(ctx, S, nl)[0] for eff, nl, _ in chosen])
            beta = solve(A, reading - np.interp(tt, ctx.t_s, expected))
            with np.errstate(invalid="ignore", divide="ignore"):
                found.append([eff.parameters(beta[sl], labels, nl, ctx)
                              for (eff, nl, labels), sl in zip(chosen, slices)])
        for k, (up, down) in enumerate(zip(*found)):
            for name, a in up.items():
                b = down.get(name)
                if isinstance(a, float) and isinstance(b, float) and math.isfinite(a - b):
                    change = abs(a - b) / (2.0 * h) * std
                    out[k][name] = out[k].get(name, 0.0) + change * change
    return out


def read_out(ctx: Context, lib: list[Effect], split: Split, selection: Selection,
             al: Alignment, opt: Options, mimic_library: list[Effect] | None = None,
             geometry: GeometryBeyond | None = None, opened: dict | None = None,
             expected: np.ndarray | None = None) -> Explanation:
    """The explanation of the recording at the timing ``al`` by what ``selection``
    chose (run on ``split``): parameters and contributions from the final fit on every
    sample; ``mimic_library``: the effects tried as mimics (default ``lib``);
    ``geometry``: the smooth geometry beyond the library the geometric findings are
    checked against (None: not checked); ``opened``: effect -> what its timing
    parameter's profile with the timing leaves open (:class:`.results.ProfileOpen`:
    the timing parameter's uncertainty is at least what the profile says, and the
    finding's other parameters take in, in quadrature, the larger of what they move by
    along the profile and their slope along it times that uncertainty); ``expected``:
    the reading the model expects on the trajectory grid (given, the findings'
    parameters take in what the timing's uncertainty carries into them,
    :func:`_timing_spill`)."""
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
    timed = (_timing_spill(ctx, chosen, slices, expected, tau[allsel], y_all, al)
             if expected is not None else [{} for _ in chosen])
    for f, (eff, nl, labels), sl, carried in zip(findings, chosen, slices, timed):
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
        for k, v in carried.items():
            if k in f.uncertainty and k in f.parameters:
                f.uncertainty[k] = math.sqrt(f.uncertainty[k] ** 2 + v)
        prof = (opened or {}).get(f.effect)
        if prof is not None and eff.timing_parameter:
            _profile_open(f, eff.timing_parameter[0], prof)
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
