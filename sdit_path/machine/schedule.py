"""Rotary schedules: which angles the rotary axes take along the path.

``locked``: constant angles.  ``moving``: the turn axis (C) follows the bar's azimuth
in the table frame so that the bar keeps a fixed azimuth in the machine, and the tilt
axis (B) moves linearly with the bar's elevation.  Angles are continuous along a whole
program: the azimuth is unwrapped and every run starts on the branch where the
previous one ended, so C never unwinds.  Where the azimuth is undefined (the bar
vertical, at TOP) the last defined value is held (or the next one, at a start).
"""

from __future__ import annotations

import math

import numpy as np

from ..config import Config
from .kinematics import Kinematics

#: Horizontal component of the bar direction below which its azimuth is undefined.
POLE_EPS = 1e-9


class RotarySchedule:
    def __init__(self, config: Config, kinematics: Kinematics):
        self.rotary = config.test.rotary
        self.pivot = np.array(config.ballbar.pivot_mm)
        self.kin = kinematics
        self.names = tuple(kinematics.names[i] for i in kinematics.rotary)
        self._locked = dict(self.rotary.locked_rad)
        if self.rotary.schedule == "moving":
            turn = config.machine.axis(self.rotary.turn_axis)
            dz = turn.direction[2]
            if abs(dz) < 0.5:
                raise ValueError(f"turn axis {turn.name} must be near vertical with every axis at 0")
            self._turn_sign = 1.0 if dz > 0 else -1.0

    @property
    def moving(self) -> bool:
        return self.rotary.schedule == "moving"

    def angles(self, points_mm: np.ndarray, carry: float | None = None
               ) -> tuple[dict[str, np.ndarray], float | None]:
        """Rotary angles (rad) at ``points_mm (n, 3)`` (table frame), and the unwrapped
        azimuth to carry into the next call for continuity."""
        p = np.atleast_2d(points_mm)
        n = len(p)
        if not self.moving:
            return {k: np.full(n, v) for k, v in self._locked.items()}, carry
        r = self.rotary
        u = p - self.pivot
        u = u / np.linalg.norm(u, axis=1)[:, None]
        horizontal = np.hypot(u[:, 0], u[:, 1])
        elevation = np.arctan2(u[:, 2], horizontal)
        valid = horizontal > POLE_EPS
        phi = np.full(n, np.nan)
        if valid.any():
            raw = np.arctan2(u[valid, 1], u[valid, 0])
            unwrapped = np.unwrap(raw)
            if carry is not None:
                unwrapped += 2 * math.pi * round((carry - unwrapped[0]) / (2 * math.pi))
            phi[valid] = unwrapped
            # hold the last defined azimuth through the pole (the next one at the start)
            idx = np.where(valid, np.arange(n), -1)
            np.maximum.accumulate(idx, out=idx)
            first = int(np.argmax(valid))
            idx[idx < 0] = first
            phi = phi[idx]
        else:
            phi[:] = carry if carry is not None else r.hold_azimuth_rad
        turn = self._turn_sign * (r.hold_azimuth_rad - phi)
        tilt = r.tilt_at_equator_rad + (r.tilt_at_pole_rad - r.tilt_at_equator_rad) * (
            elevation / (math.pi / 2))
        out = {k: np.full(n, v) for k, v in self._locked.items()}
        out[r.turn_axis] = turn
        out[r.tilt_axis] = tilt
        return out, float(phi[-1])
