"""Where a signal lives: the segments where it is strongest, by phase of the motion,
near axis reversals or away from them, and its time windows (program time)."""

from __future__ import annotations

import math

import numpy as np

from ..reading.context import Context


def _windows(tau: np.ndarray, flag: np.ndarray, min_gap_s: float = 0.5, limit: int = 12):
    if not flag.any():
        return []
    order = np.argsort(tau)
    t, f = tau[order], flag[order]
    on = t[f]
    splits = np.flatnonzero(np.diff(on) > min_gap_s)
    starts = np.r_[on[0], on[splits + 1]]
    ends = np.r_[on[splits], on[-1]]
    wins = sorted(zip(starts, ends), key=lambda w: -(w[1] - w[0]))[:limit]
    return [[round(float(a), 3), round(float(b), 3)] for a, b in sorted(wins)]


def locate(ctx: Context, idx: np.ndarray, tau: np.ndarray, signal: np.ndarray,
           noise: float | None = None, detail: bool = False) -> dict:
    """Where ``signal`` lives: segments (RMS per segment, the strongest), phases,
    near axis reversals or away from them, and time windows (program time)."""
    seg = ctx.segment[idx]
    names, inv = np.unique(seg.astype(str), return_inverse=True)
    ssum = np.bincount(inv, signal * signal, len(names))
    cnt = np.bincount(inv, None, len(names))
    seg_rms = np.sqrt(ssum / np.maximum(cnt, 1))
    peak = float(seg_rms.max()) if len(seg_rms) else 0.0
    floor = (noise or 0.0) * 1.5
    strong = [(str(names[i]), float(seg_rms[i])) for i in np.argsort(-seg_rms)
              if seg_rms[i] >= max(0.5 * peak, floor) and seg_rms[i] > 0]
    out = {"segments": [s for s, _ in strong[:20]],
           "segment_rms_um": {s: round(v, 4) for s, v in strong[:20]}}
    ph = ctx.phase[idx].astype(str)
    out["phase_rms_um"] = {p: round(float(np.sqrt(np.mean(signal[ph == p] ** 2))), 4)
                           for p in ("accelerate", "cruise", "decelerate", "dwell") if (ph == p).any()}
    near = np.zeros(len(idx), dtype=bool)
    for j in ctx.linear:
        near |= ctx.since_reversal_s(idx, j) < 0.1
    out["reversal_rms_um"] = {
        "within_100ms_after_reversal": round(float(np.sqrt(np.mean(signal[near] ** 2))), 4) if near.any() else 0.0,
        "elsewhere": round(float(np.sqrt(np.mean(signal[~near] ** 2))), 4) if (~near).any() else 0.0}
    # time windows where the (50 ms smoothed) signal is above half its peak (and noise)
    order = np.argsort(tau)
    sm = np.abs(signal[order])
    k = 50
    if len(sm) > k:
        sm = np.convolve(sm, np.ones(k) / k, mode="same")
    thr = max(0.5 * float(sm.max()) if len(sm) else 0.0, 3.0 * (noise or 0.0) / math.sqrt(k))
    flag = np.zeros(len(tau), dtype=bool)
    flag[order] = sm >= thr
    out["time_windows_s"] = _windows(tau, flag)
    if detail:
        kind = np.where(ph == "dwell", "static nodes (dwell)",
                        np.where(np.char.find(seg.astype(str), ">") >= 0, "meridian transits",
                                 "layer segments"))
        out["by_part_rms_um"] = {k: round(float(np.sqrt(np.mean(signal[kind == k] ** 2))), 4)
                                 for k in ("layer segments", "meridian transits",
                                           "static nodes (dwell)") if (kind == k).any()}
    return out
