"""A ballbar recording as every stage reads it: times and readings, with the program's
labels where the recording carries them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class Trace:
    """``t_s, delta_l_um : (n,)`` (NaN = dropout); ``segment, phase : (n,) or (0,)``
    labels from the trajectory where the recording has them; ``header``: its
    ``# key: value`` lines."""

    t_s: np.ndarray
    delta_l_um: np.ndarray
    segment: np.ndarray
    phase: np.ndarray
    header: dict


#: a reading is judged still on its means over blocks this long (s): a steady
#: vibration of the structure (tens of Hz) averages out of them, a motion does not
STILL_BLOCK_S = 0.05


def block_means(t: np.ndarray, y: np.ndarray, block_s: float = STILL_BLOCK_S
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (block centres), means and sample counts of ``y`` over consecutive blocks of
    ``block_s`` (finite samples only; empty blocks left out)."""
    ok = np.isfinite(y)
    t, y = np.asarray(t, float)[ok], np.asarray(y, float)[ok]
    if len(t) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    k = np.floor((t - t[0]) / block_s).astype(np.int64)
    n = np.bincount(k).astype(float)
    s = np.bincount(k, weights=y)
    keep = n > 0
    centre = t[0] + (np.arange(len(n)) + 0.5) * block_s
    return centre[keep], s[keep] / n[keep], n[keep]


def standstill_floor(t: np.ndarray, y: np.ndarray, noise_um: float,
                     window_s: float = 0.5) -> float:
    """The spread (um) of 50 ms means that a standstill shows in this recording: what the
    noise leaves of them, or, where more, the spread of the quietest tenth of its
    ``window_s`` windows (a steady vibration that the means do not wholly average out
    lifts every window alike, the standstills included)."""
    tb, yb, counts = block_means(t, y)
    if len(tb) < 20:
        return noise_um
    per = noise_um / np.sqrt(max(float(np.median(counts)), 1.0))
    k = np.searchsorted(tb, np.arange(tb[0], tb[-1], window_s))
    spread = [float(np.std(yb[a:b])) for a, b in zip(k[:-1], k[1:]) if b - a >= 5]
    return float(max(per, np.percentile(spread, 10))) if spread else float(per)
