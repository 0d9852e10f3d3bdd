"""Ambiguity and confidence: a finding the recording cannot tell from another (an
aliased pair, a mimic, a close runner-up) names both and the run that separates them;
confidence follows from how the finding generalises to held-out stretches, whether
anything else explains it as well, and whether its sizes are known."""

from __future__ import annotations

import numpy as np

from ..reading.context import Context
from .effects import ALIASED, PROGRAM_ALIASED
from .results import FindingDraft
from .where import locate


def merge_aliased(findings: list[FindingDraft], contribs: dict, ctx: Context, idx: np.ndarray,
                   tau: np.ndarray) -> list:
    """Two effects this recording cannot tell apart, both selected, are one finding:
    the first named, the other in ``ambiguous_with``, their joint contribution and
    both parameter sets (the other's prefixed with its name).  One of them selected
    and the other its mimic or a close runner-up: the finding names both as well."""
    for pair, how in ALIASED.items():
        both = [f for f in findings if f.effect in pair]
        if len(both) != 2:
            continue
        keep, drop = both
        joint = contribs[keep.effect] + contribs[drop.effect]
        keep.contribution_rms_um = float(np.sqrt(np.mean(joint * joint)))
        keep.where = locate(ctx, idx, tau, joint)
        keep.parameters = {**keep.parameters,
                           **{f"{drop.effect}.{k}": v for k, v in drop.parameters.items()}}
        keep.unseen = keep.unseen + [f"{drop.effect}.{k}" for k in drop.unseen]
        keep.uncertainty = {**keep.uncertainty,
                            **{f"{drop.effect}.{k}": v for k, v in drop.uncertainty.items()}}
        keep.undetermined = keep.undetermined + [f"{drop.effect}.{k}" for k in drop.undetermined]
        keep.heldout_rms_after_um = min(keep.heldout_rms_after_um, drop.heldout_rms_after_um)
        keep.rms_after_um = min(keep.rms_after_um, drop.rms_after_um)
        keep.ambiguous_with, keep.separate_by = [drop.effect], how
        keep.mimics = [m for m in keep.mimics if m["effect"] != drop.effect] + [
            {"effect": drop.effect, "r2": 1.0}]
        judge_confidence(keep)
        findings = [f for f in findings if f is not drop]
    return pair_ambiguity(findings)


def pair_ambiguity(findings: list) -> list:
    """One of an aliased pair selected, the other reproducing it (a listed mimic, or a
    runner-up with nearly the same evidence): the recording cannot tell them apart
    either, and the finding names both.  One of a pair only some programs tell apart
    selected, the other its runner-up with nearly the same evidence: this program does
    not, and the finding names both (a mimic alone does not: the two share part of
    their signal on every program)."""
    for f in findings:
        if f.ambiguous_with:
            continue
        for pair, how in ALIASED.items():
            if f.effect not in pair:
                continue
            other = next(e for e in pair if e != f.effect)
            if any(m["effect"] == other for m in f.mimics) or (
                    f.runner_up == other and f.runner_up_ratio < AMBIGUOUS_RATIO):
                f.ambiguous_with, f.separate_by = [other], how
                judge_confidence(f)
        for pair, how in PROGRAM_ALIASED.items():
            if (not f.ambiguous_with and {f.effect, f.runner_up} == pair
                    and f.runner_up_ratio < AMBIGUOUS_RATIO):
                f.ambiguous_with, f.separate_by = [f.runner_up], how
                judge_confidence(f)
    return findings


#: a runner-up of an aliased pair within this evidence ratio makes the finding ambiguous
AMBIGUOUS_RATIO = 1.1


def judge_confidence(f: FindingDraft) -> None:
    """high: it holds on held-out segments and nothing else explains it as well;
    medium: a mimic or a close runner-up, or weaker on held-out data; low: barely
    generalises."""
    ex_tr = f.rms_before_um ** 2 - f.rms_after_um ** 2
    ex_ho = f.heldout_rms_before_um ** 2 - f.heldout_rms_after_um ** 2
    generalises = ex_ho / ex_tr if ex_tr > 0 else 0.0
    # the README's rule: no mimic, no close runner-up, not ambiguous
    close = bool(f.mimics) or f.runner_up_ratio < 1.1 or bool(f.ambiguous_with)
    f.confidence = ("high" if generalises >= 0.5 and not close and not f.geometry_doubt
                    and not _size_unsure(f) else
                    "medium" if generalises >= 0.25 else "low")


def _size_unsure(f: FindingDraft) -> bool:
    """Every size the finding reports (its fitted parameters, not the searched ones)
    lies within 2 standard uncertainties of zero: a mode whose compliance is no larger
    than its uncertainty is not named with confidence, however much its columns take up
    (hard case: blind-bad-SDIT_B-s1-37)."""
    sizes = [k for k, v in f.parameters.items() if isinstance(v, float)
             and k not in f.nonlinear and k in f.uncertainty]
    return bool(sizes) and all(abs(f.parameters[k]) < 2.0 * f.uncertainty[k] for k in sizes)
