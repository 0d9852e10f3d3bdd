"""The held-out design: which stretches of the program the fit never sees, and how
much an effect must improve them to count as more than chance."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..reading.context import Context, nearest_samples
from .align import Alignment
from .effects import Samples, linear_axes
from .fitting import noise_estimate
from .options import Options


def stretch_numbers(ctx: Context) -> np.ndarray:
    """Stretch number of every grid sample: a new stretch at every label change."""
    seg = ctx.segment
    change = np.r_[True, seg[1:] != seg[:-1]]
    return np.cumsum(change) - 1


def held_stretches(ctx: Context, every: int) -> np.ndarray:
    """Which stretches (numbered as ``stretch_numbers``) are held out: one in ``every`` of each
    kind, a kind being the dwells, the transfers, or a sub-segment's place in its sector
    on one pass (``D3-2`` on its first run, on its second ...).  Taking every n-th stretch
    of the program instead locks to the program's period: with two sub-segments a sector,
    every n = 3 holds out every descending half, and the fit sees the ball only rise, so
    that a play reversing with the motion cannot be told from the set-up.  The kinds are
    staggered so that one sector is not held out whole."""
    seg = ctx.segment
    starts = np.flatnonzero(np.diff(stretch_numbers(ctx), prepend=-1))
    held = np.zeros(len(starts), dtype=bool)
    runs: dict[str, int] = {}
    count: dict[tuple, int] = {}
    stagger: dict[tuple, int] = {}
    for u, i in enumerate(starts):
        label = str(seg[i])
        if ctx.phase[i] == "dwell":
            kind: tuple = ("dwell",)
        elif ">" in label:
            kind = ("transfer",)
        else:
            kind = ("segment", label.rsplit("-", 1)[-1], runs.get(label, 0))
        runs[label] = runs.get(label, 0) + 1
        j = count.get(kind, 0)
        count[kind] = j + 1
        k = stagger.setdefault(kind, len(stagger))
        held[u] = (j + k) % every == every - 1
    return _balance_reversals(ctx, held, every)


def _balance_reversals(ctx: Context, held: np.ndarray, every: int) -> np.ndarray:
    """Each linear axis's reversals split between the fitted and the held-out stretches,
    about one in ``every`` held out, at least one on each side.  An axis that reverses
    a few times only, each time at the same place of a sector (SDIT_B's X reverses
    three times, every sixth sector, at sub-segment 3), can have them all held out, and
    an effect that acts only there (a reversal spike) is then invisible to the fit
    (hard case: blind-bad-SDIT_B-s1-22).
    The rarest axis first; a stretch balanced for one axis is not moved for another."""
    held = held.copy()
    units = stretch_numbers(ctx)
    events = []
    for j in linear_axes(ctx):
        t_rev = np.asarray(ctx.reversal_times[j], float)
        # the stretch an event acts in: just after the reversal (a pulse, a play's step)
        at = np.minimum(np.searchsorted(ctx.t_s, t_rev + 0.01), ctx.n - 1)
        us = list(dict.fromkeys(int(u) for u in units[at]))
        if len(us) >= 2:
            events.append(us)
    locked: set[int] = set()
    for us in sorted(events, key=len):
        want = min(max(1, round(len(us) / every)), len(us) - 1)
        free = [u for u in us if u not in locked]
        now = sum(held[u] for u in us)
        if now > want:
            for u in [u for u in free if held[u]][:now - want]:
                held[u] = False
        elif now < want:
            spare = [u for u in free if not held[u]]
            for u in spare[every - 1::every][:want - now] or spare[:want - now]:
                held[u] = True
        locked.update(us)
    return held


def block_choice(candidates: np.ndarray, quota: int, rng, block: int = 500) -> np.ndarray:
    if len(candidates) <= quota:
        return candidates
    nb = int(math.ceil(len(candidates) / block))
    pick = np.sort(rng.choice(nb, max(1, quota // block), replace=False))
    out = (pick[:, None] * block + np.arange(block)[None, :]).ravel()
    return candidates[out[out < len(candidates)]]


def support(C: np.ndarray) -> float:
    """Share of samples an effect acts on (any column above 10 % of its peak, where
    the effect is more than its own tail): a local effect (stick-slip near reversals, a
    mode rung by the starts and stops) must explain its own samples, not the whole
    trace, to pass the noise threshold.  Counted at 1 % of its peak, a mode's deflection
    with the slow accelerations along the curves takes in many times the samples it
    acts on, and a mode whose deflection is a fraction of a micron is refused
    (hard case: blind-typical-SDIT_C-s1-10)."""
    if C.size == 0:
        return 1.0
    peak = np.abs(C).max(axis=0)
    active = (np.abs(C) > 0.1 * np.where(peak > 0, peak, np.inf)).any(axis=1)
    return float(active.mean())


#: the least held-out drop, in noise variances summed over the held-out samples, that
#: counts as more than chance whatever the effect's support
HELDOUT_CHI2 = 25.0


def heldout_need(opt: "Options", mse_ho: float, noise: float, C_ho: np.ndarray) -> float:
    """The held-out MSE drop an effect acting through ``C_ho`` must bring: its size
    where it acts, both parts in proportion to the share of samples it acts on (a mode
    ringing after each start and stop must explain its own samples, not the whole
    trace), and never less than :data:`HELDOUT_CHI2` noise variances over the held-out
    samples (the floor a local effect's tiny share would otherwise take to nothing)."""
    practical = max(opt.min_heldout_gain * mse_ho, (opt.min_effect_noise * noise) ** 2)
    return max(practical * support(C_ho), HELDOUT_CHI2 * noise ** 2 / max(len(C_ho), 1))


@dataclass(frozen=True, slots=True)
class Split:
    """One recording at one timing, split into fitted and held-out samples.  ``sel``:
    the recording's samples inside the program (finite); ``tau``, ``idx``: their
    program time and nearest trajectory sample; ``gap``: their reading minus the
    expected one; ``held``: which are held out; ``tr``, ``ho``: the positions in ``sel``
    of the samples fitted and held out (a seeded choice of 0.5 s blocks);
    ``S_tr``, ``S_ho``, ``y_tr``, ``y_ho``: those samples and their gap; ``noise_um``: the
    gap's sensor noise; ``dropouts``: the recording's empty readings."""

    sel: np.ndarray
    tau: np.ndarray
    idx: np.ndarray
    gap: np.ndarray
    held: np.ndarray
    tr: np.ndarray
    ho: np.ndarray
    S_tr: Samples
    S_ho: Samples
    y_tr: np.ndarray
    y_ho: np.ndarray
    noise_um: float
    dropouts: int


def split_recording(ctx: Context, expected: np.ndarray, t_m: np.ndarray, y: np.ndarray,
                    al: Alignment, opt: Options) -> Split:
    """The recording ``(t_m, y)`` at the timing ``al`` split by :func:`held_stretches`
    (``expected``: the expected reading on the trajectory grid)."""
    tau_all = al.program_time(t_m)
    T = ctx.t_s[-1]
    ok = np.isfinite(y) & (tau_all >= ctx.t_s[0]) & (tau_all <= T)
    sel = np.flatnonzero(ok)
    tau = tau_all[sel]
    idx = nearest_samples(ctx, tau)
    gap = y[sel] - np.interp(tau, ctx.t_s, expected)
    held = held_stretches(ctx, opt.heldout_every)[stretch_numbers(ctx)[idx]]
    rng = np.random.default_rng(0)
    tr = block_choice(np.flatnonzero(~held), opt.max_fit_samples, rng)
    ho = block_choice(np.flatnonzero(held), opt.max_fit_samples // 2, rng)
    return Split(sel, tau, idx, gap, held, tr, ho, Samples(idx[tr], tau[tr]),
                 Samples(idx[ho], tau[ho]), gap[tr], gap[ho], noise_estimate(gap, tau),
                 int((~np.isfinite(y)).sum()))
