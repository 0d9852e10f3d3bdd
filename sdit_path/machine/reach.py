"""Reachability: every pose within travel and angle limits (with margins), and rotary
rates the axes can follow at the programmed feed (near a singularity of the schedule,
where the bar passes close to the turn axis, the turn axis would have to spin).

Results are values, one per piece (segment or transit), never exceptions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Config, Reader
from .kinematics import Kinematics
from .poses import RunPoses


@dataclass(frozen=True, slots=True)
class Violation:
    """Something that makes a piece infeasible.  ``kind``: ``travel``,
    ``rotary_rate`` or ``collision``.  Values are in the unit users read (mm, deg,
    deg/s); ``point_mm`` is the ball centre (table frame) where it is worst."""

    kind: str
    subject: str
    value: float
    limit: float
    overshoot: float
    unit: str
    point_mm: tuple[float, float, float]
    detail: str = ""

    def describe(self) -> str:
        at = "(" + ", ".join(f"{v:.3f}" for v in self.point_mm) + ") mm"
        if self.kind == "travel":
            return (f"{self.subject} {self.value:.3f} {self.unit} exceeds its limit {self.limit:g} "
                    f"{self.unit} by {self.overshoot:.3f} {self.unit} at ball {at}")
        if self.kind == "rotary_rate":
            return (f"{self.subject} would turn at {self.value:.1f} {self.unit} at the programmed "
                    f"feed, over its limit {self.limit:g} {self.unit} (near a singularity of the "
                    f"schedule) at ball {at}: the timed path slows to "
                    f"{100 * self.limit / self.value:.0f}% of the feed there")
        return (f"collision {self.subject}: clearance {round(self.value, 3) + 0.0:.3f} mm < "
                f"{self.limit:g} mm safety at ball {at}{self.detail}")


@dataclass(frozen=True, slots=True)
class PieceCheck:
    """Verdict for one piece (segment id or transit id) of one layer path."""

    piece_id: str
    kind: str
    violations: tuple[Violation, ...]
    min_clearance_mm: float | None = None
    clearance_pair: tuple[str, str] | None = None
    clearance_point_mm: tuple[float, float, float] | None = None
    warnings: tuple[Violation, ...] = ()

    @property
    def feasible(self) -> bool:
        return not self.violations


def point_tuple(p) -> tuple[float, float, float]:
    return tuple(round(float(x), 6) for x in p)


def reach_violations(poses: RunPoses, config: Config, kin: Kinematics) -> dict[int, list[Violation]]:
    """Travel and angle violations, and rotary-rate warnings, per piece index of one run.

    A rotary axis that would turn faster than its limit at the programmed feed is a
    warning (``kind == "rotary_rate"``), not an infeasibility: the control, and the
    timed trajectory, slow the path down there."""
    out: dict[int, list[Violation]] = {}
    margin_lin = config.check.travel_margin_mm
    margin_rot = config.check.angle_margin_rad
    feed = poses.run.feed_mm_per_min / 60.0
    q, pts, piece = poses.q, poses.points_mm, poses.piece
    ds = np.diff(poses.s_mm)
    for j, ax in enumerate(kin.axes):
        m = margin_rot if ax.is_rotary else margin_lin
        lo, hi = ax.travel[0] + m, ax.travel[1] - m
        for k in np.unique(piece):
            sel = np.where(piece == k)[0]
            v = q[sel, j]
            i_lo, i_hi = int(np.argmin(v)), int(np.argmax(v))
            for idx, over, limit in ((i_lo, lo - v[i_lo], lo), (i_hi, v[i_hi] - hi, hi)):
                if over > 1e-12:
                    out.setdefault(int(k), []).append(Violation(
                        "travel", ax.name, ax.to_display(v[idx]), ax.to_display(limit),
                        ax.to_display(over), ax.unit, point_tuple(pts[sel[idx]]),
                        f" (margin {ax.to_display(m):g} {ax.unit})" if m else ""))
        if ax.is_rotary and len(ds):
            rate = np.abs(np.diff(q[:, j])) / np.maximum(ds, 1e-12) * feed
            over = rate > ax.max_velocity * (1 + 1e-9)
            for k in np.unique(piece[1:][over]):
                sel = np.where(over & (piece[1:] == k))[0]
                w = sel[int(np.argmax(rate[sel]))]
                out.setdefault(int(k), []).append(Violation(
                    "rotary_rate", ax.name, np.degrees(rate[w]), np.degrees(ax.max_velocity),
                    np.degrees(rate[w] - ax.max_velocity), "deg/s", point_tuple(pts[w + 1])))
    return out


def check_pivot(config: Config) -> None:
    """The tool ball must be able to reach the pivot position itself (rotary axes at
    their locked angles): a pivot outside the travel is a config mistake, a
    :class:`~sdit_path.errors.ConfigError` naming the file, the line and the axis."""
    machine, ballbar, test = config.machine, config.ballbar, config.test
    kin = Kinematics(machine)  # the chain is the one source of truth
    angles = dict(test.rotary.locked_rad)
    q = kin.inverse([ballbar.pivot_mm], {n: [v] for n, v in angles.items()})
    for j, ax in enumerate(kin.axes):
        lo, hi = ax.travel
        v = float(q[0, j])
        if not lo - 1e-9 <= v <= hi + 1e-9:
            raise Reader(config.source, config.text).fail(
                "ballbar.pivot_mm",
                f"pivot {list(ballbar.pivot_mm)} mm needs {ax.name}={ax.to_display(v):.3f} "
                f"{ax.unit}, outside the {ax.name} travel [{ax.to_display(lo):g}, "
                f"{ax.to_display(hi):g}] {ax.unit} (machine.axes.{ax.name})")
