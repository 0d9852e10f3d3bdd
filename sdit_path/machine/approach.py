"""The operator's way to the bar and back: the moves a program makes before its first
dwell (the bar not yet mounted) and after its last (the bar taken off).

From wherever the machine stands the program first raises Z to the safe height, then
goes to the safe position (``post.safe_position_mm``, the ball centre in the table
frame; by default above the pivot, 50 mm over the sphere), turning the rotary axes to
the start node's angles up there; then over the start node at the safe height, and
down to it.  There it stops for the operator to mount the bar and start the
recording.  After the last dwell it stops again (stop the recording, take the bar
off), rises straight up to the safe height and returns to the safe position.

The first two moves leave from a place the plan does not know: they are not checked
(the program says so).  Every other leg is a straight line in the table frame with
the rotary axes at the start node's angles (for a machine-axis program, the linear
axes moving alone, which is the same line), sampled at ``check.pose_spacing_mm`` and
checked like the path: travel, and clearance between the tool's side and the table's
side with the bar not mounted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..arrays import frozen
from ..config import Config
from .kinematics import Kinematics
from .schedule import RotarySchedule

#: the default safe position: this far over the top of the sphere, above the pivot
CLEARANCE_OVER_SPHERE_MM = 50.0


@dataclass(frozen=True, slots=True)
class Leg:
    """One move of the operator sequence.  ``name`` says what it does;
    ``points_mm : (n, 3)`` the ball centre along it in the table frame (its first row
    the start, its last the end), ``q : (n, n_axes)`` the axis values there;
    ``checked``: whether its start is known (the first two moves leave from wherever
    the machine stands)."""

    name: str
    points_mm: np.ndarray
    q: np.ndarray
    checked: bool

    @property
    def end_mm(self) -> np.ndarray:
        return self.points_mm[-1]


@dataclass(frozen=True, slots=True)
class OperatorSequence:
    """The legs before the first dwell (``approach``) and after the last
    (``retract``), the safe height (table-frame Z) and the rotary angles they keep
    (name -> rad)."""

    approach: tuple[Leg, ...]
    retract: tuple[Leg, ...]
    safe_z_mm: float
    angles_rad: tuple[tuple[str, float], ...]


def safe_position(config: Config) -> np.ndarray:
    """``post.safe_position_mm``, or above the pivot 50 mm over the sphere."""
    if config.post.safe_position_mm is not None:
        return np.array(config.post.safe_position_mm, dtype=float)
    pivot = np.array(config.ballbar.pivot_mm, dtype=float)
    return pivot + np.array([0.0, 0.0, config.ballbar.bar_length_mm + CLEARANCE_OVER_SPHERE_MM])


def operator_sequence(config: Config, kin: Kinematics, start_mm: np.ndarray,
                      end_mm: np.ndarray, spacing_mm: float | None = None) -> OperatorSequence:
    """The legs for a program that starts its test at ``start_mm`` and ends it at
    ``end_mm`` (table frame; the same node for a layer program)."""
    spacing = spacing_mm or config.check.pose_spacing_mm
    schedule = RotarySchedule(config, kin)
    start = np.asarray(start_mm, dtype=float)
    end = np.asarray(end_mm, dtype=float)
    angles, _ = schedule.angles(start[None, :], None)
    end_angles, _ = schedule.angles(end[None, :], None)
    safe = safe_position(config)
    z = float(safe[2])

    def leg(name: str, a: np.ndarray, b: np.ndarray, ang, checked: bool = True) -> Leg:
        n = max(2, math.ceil(float(np.linalg.norm(b - a)) / spacing) + 1)
        pts = a[None, :] + np.linspace(0.0, 1.0, n)[:, None] * (b - a)[None, :]
        q = kin.inverse(pts, {k: np.full(n, v[0]) for k, v in ang.items()})
        return Leg(name, frozen(pts), frozen(q), checked)

    over_start = np.array([start[0], start[1], z])
    over_end = np.array([end[0], end[1], z])
    approach = (
        leg("Z up to the safe height, from wherever the machine stands", safe, safe, angles,
            checked=False),
        leg("to the safe position", safe, safe, angles, checked=False),
        leg("over the start node at the safe height", safe, over_start, angles),
        leg("down to the start node", over_start, start, angles),
    )
    retract = (
        leg("up from the end node to the safe height", end, over_end, end_angles),
        leg("to the safe position", over_end, safe, end_angles),
    )
    names = tuple(kin.names[i] for i in kin.rotary)
    return OperatorSequence(approach, retract, z,
                            tuple((n, float(angles[n][0])) for n in names if n in angles))
