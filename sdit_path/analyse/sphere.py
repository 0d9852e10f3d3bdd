"""A layer's measured radial deviation and its figures, in the spirit of ISO 230-4
carried from the circle to the sphere.

* **Radial deviation**: the bar reading on the layer's test segments (dwells, transits
  and repositioning left out) less the least-squares ball centring and bar length
  offset over those samples: ``dR - (b + c . u)``, ``u`` the bar direction.
* **Maximum / minimum radial deviation** (``max_um``, ``min_um``): its extremes.
* **Sphericity range** (``range_um``): max - min, ISO 230-4's circular deviation G read
  over the layer's band of the sphere, both passes together.
* **Hysteresis** (``hysteresis_um``): the largest difference of the radial deviation
  between the forward and the reverse pass at the same point of the same segment (ISO
  230-4's circular hysteresis H), points matched by position to ``match_mm``;
  ``hysteresis_median_um`` the median of those differences.

Everything is read on program time: the recording as the analysis aligned it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.hemisphere import TEST_SEGMENT
from ..timing.trajectory import Samples



@dataclass(frozen=True, slots=True)
class LayerDeviation:
    """``azimuth_deg, elevation_deg, deviation_um : (n,)`` on the test segments (every
    ``stride``-th sample), ``reverse : (n,) bool`` (the second pass of its segment),
    and the figures (um) of the module docstring over every sample."""

    program: str
    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    deviation_um: np.ndarray
    reverse: np.ndarray
    max_um: float
    min_um: float
    range_um: float
    hysteresis_um: float | None
    hysteresis_median_um: float | None
    samples: int

    def figures(self) -> dict:
        return {"program": self.program, "max_um": self.max_um, "min_um": self.min_um,
                "range_um": self.range_um, "hysteresis_um": self.hysteresis_um,
                "hysteresis_median_um": self.hysteresis_median_um, "samples": self.samples}


def pass_of(traj: Samples) -> np.ndarray:
    """``(n,) int``: 0 on a segment's first run in the program, 1 on its second, ..."""
    seg = traj.segment
    out = np.zeros(len(seg), dtype=np.int8)
    if not len(seg):
        return out
    starts = np.r_[0, np.flatnonzero(seg[1:] != seg[:-1]) + 1, len(seg)]
    seen: dict[str, int] = {}
    for a, b in zip(starts[:-1], starts[1:]):
        k = seen.get(seg[a], 0)
        seen[seg[a]] = k + 1
        out[a:b] = min(k, 127)
    return out


def layer_deviation(program: str, traj: Samples, pivot_mm, t_s: np.ndarray,
                    delta_l_um: np.ndarray, match_mm: float = 0.2,
                    points: int = 6000) -> LayerDeviation | None:
    """The radial deviation of a recording on its program's time ``t_s`` (s) against the
    program's trajectory; None when no test segment holds a reading."""
    rate = 1.0 / float(np.median(np.diff(traj.t_s)))
    idx = np.rint(np.asarray(t_s) * rate).astype(np.int64)
    inside = (idx >= 0) & (idx < len(traj.t_s)) & np.isfinite(delta_l_um)
    idx, y = idx[inside], np.asarray(delta_l_um, float)[inside]
    test = np.array([bool(TEST_SEGMENT.match(s)) for s in traj.segment[idx]], dtype=bool)
    test &= (traj.phase[idx] != "dwell") & (traj.phase[idx] != "reposition")
    idx, y = idx[test], y[test]
    if len(idx) < 10:
        return None
    p = traj.ball_mm[idx] - np.asarray(pivot_mm, float)
    u = p / np.linalg.norm(p, axis=1)[:, None]
    A = np.column_stack([np.ones(len(u)), u])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    dev = y - A @ coef
    passes = pass_of(traj)[idx]
    hyst = _hysteresis(traj.ball_mm[idx], traj.segment[idx], passes, dev, match_mm)
    stride = max(1, len(idx) // points)
    keep = slice(None, None, stride)
    return LayerDeviation(
        program, np.degrees(np.arctan2(u[keep, 1], u[keep, 0])) % 360.0,
        np.degrees(np.arcsin(np.clip(u[keep, 2], -1.0, 1.0))), dev[keep],
        passes[keep] > 0, float(dev.max()), float(dev.min()), float(dev.max() - dev.min()),
        None if hyst is None else float(np.max(hyst)),
        None if hyst is None else float(np.median(hyst)), int(len(idx)))


def _hysteresis(ball: np.ndarray, segment: np.ndarray, passes: np.ndarray, dev: np.ndarray,
                match_mm: float) -> np.ndarray | None:
    """``|dev_forward - dev_reverse|`` at every reverse-pass point with a forward-pass
    point of the same segment within ``match_mm``; None when no segment has both."""
    diffs = []
    for sid in np.unique(segment):
        on = segment == sid
        fwd, rev = on & (passes == 0), on & (passes == 1)
        if not fwd.any() or not rev.any():
            continue
        dist, j = cKDTree(ball[fwd]).query(ball[rev], distance_upper_bound=match_mm)
        ok = np.isfinite(dist)
        if ok.any():
            diffs.append(np.abs(dev[rev][ok] - dev[fwd][j[ok]]))
    return np.concatenate(diffs) if diffs else None


def deviations(plan, traces: list[tuple[str, np.ndarray, np.ndarray]]
               ) -> dict[str, LayerDeviation]:
    """Per program, the radial deviation of its recording on program time (``t_s``,
    ``delta_l_um``) against the plan's trajectory of it (``plan``: PlanFiles)."""
    out = {}
    for program, t_s, y in traces:
        d = layer_deviation(program, plan.trajectory(program), plan.config.ballbar.pivot_mm,
                            t_s, y)
        if d is not None:
            out[program] = d
    return out
