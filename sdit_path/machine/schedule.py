"""Rotary schedules: which angles the rotary axes take along the path.

``locked``: constant angles.  ``moving``: the turn axis (C) follows the bar's azimuth
in the table frame so that the bar keeps a fixed azimuth in the machine, and the tilt
axis (B) moves linearly with the bar's elevation.  Angles are continuous along a whole
program: the azimuth is unwrapped and every run starts on the branch where the
previous one ended, so C never unwinds.  Where the azimuth is undefined (the bar
vertical, at TOP) the last defined value is held (or the next one, at a start).  A
sector's override may tilt away from the schedule over its patch (``tilt_offset_deg``,
see ``SectorCurve``).
"""

from __future__ import annotations

import math

import numpy as np

from ..config import Config
from ..geometry.hemisphere import track_names
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
        self._patches = _tilt_patches(config)
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
        if self._patches:
            tilt = tilt + self._tilt_offset(u, elevation)
        out = {k: np.full(n, v) for k, v in self._locked.items()}
        out[r.turn_axis] = turn
        out[r.tilt_axis] = tilt
        return out, float(phi[-1])

    def _tilt_offset(self, u: np.ndarray, elevation: np.ndarray) -> np.ndarray:
        """The sectors' tilt offsets (rad) at the bar directions ``u (n, 3)``: a bump
        ``offset sin^2(pi a) sin^2(pi e)`` over each patch (``a``, ``e`` the fractions
        of its azimuth and elevation spans), zero with zero slope on its boundary."""
        azimuth = np.mod(np.arctan2(u[:, 1], u[:, 0]), 2 * math.pi)
        out = np.zeros(len(u))
        for az0, width, lo, hi, offset in self._patches:
            a = np.mod(azimuth - az0, 2 * math.pi) / width
            e = (elevation - lo) / (hi - lo)
            inside = (a < 1.0) & (e > 0.0) & (e < 1.0)
            out[inside] += offset * (np.sin(math.pi * a[inside]) * np.sin(math.pi * e[inside])) ** 2
        return out


def _tilt_patches(config: Config) -> tuple[tuple[float, float, float, float, float], ...]:
    """(first azimuth, azimuth span, lower and upper elevation, tilt offset), radians, of
    every sector whose override sets a tilt offset.  The patches are those of the
    hemisphere's partition: a layer from its track to the next one (the cap bound for
    the top layer), a sector between two neighbouring nodes."""
    t = config.test
    elevations = [math.radians(e) for e in t.track_elevations_deg]
    bounds = elevations[1:] + [math.radians(t.curve.cap_elevation_deg)]
    width = 2 * math.pi / t.nodes_per_track
    names = track_names(len(elevations))
    out = []
    for o in t.curve.overrides:
        if o.tilt_offset_deg:
            layer = names.index(o.sector[0])
            sector = int(o.sector[1:])
            out.append(((sector - 1) * width, width, elevations[layer], bounds[layer],
                        math.radians(o.tilt_offset_deg)))
    return tuple(out)
