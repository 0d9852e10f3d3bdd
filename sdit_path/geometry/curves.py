"""Exact identification curves on the sphere, before any NC representation.

The paper's construction: the tracks project to concentric circles in a plane; an
S-like planar curve is drawn in the ring between the two circles that bound a layer and
is lifted back onto the sphere.  Here the planar curve is a wave in polar form,

    rho(phi) = rho_lower - (rho_lower - rho_upper) * amplitude * g(s),
    s(phi)   = sin^2(pi * waves * phi / sector),

a smooth wave that leaves every static node (on the lower circle) tangentially, crests
on the upper circle mid-sector and returns to the next node.  A sector's override may
move the crest (``crest_at``, a fraction of the sector): the sector's azimuth fraction
``x`` is then warped to ``x + a x (1 - x)`` before the wave is taken, with ``a`` such
that a single wave crests there; the warp is smooth and monotone (|a| < 1), fixes the
nodes and keeps the zero slope there.  The sector's sub-segments
are its consecutive thirds (rising, crest, falling for the default three), so
consecutive segments join with a continuous tangent and each curve stays inside its
patch.  A wave per sub-segment would be tall and narrow in the upper layers (radius of
curvature below 1 mm at R 150), which no machine should be asked to follow.  Two lifts are offered:

* ``stereographic`` (default): inverse stereographic projection from the south pole.
  It is conformal and smooth over the whole upper hemisphere.
* ``vertical``: the paper's projection, z = sqrt(R^2 - rho^2).  It is singular on the
  equator; where the lower track is the equator the wave uses g(s) = s^2 there so that
  the lifted curve still leaves the equator with a horizontal tangent (g(s) = s would
  give a kink the machine must stop for).

Every curve maps a parameter ``t in [0, 1]`` to points ``(k, 3)`` in program
coordinates (mm).  These exact curves are what the NC representations are fitted to
and checked against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def projected_radius(elevation_rad: float, radius_mm: float, projection: str) -> float:
    """Radius of the circle a track at ``elevation_rad`` projects to."""
    if projection == "stereographic":
        return radius_mm * math.cos(elevation_rad) / (1.0 + math.sin(elevation_rad))
    return radius_mm * math.cos(elevation_rad)


def _radius_deficit(elevation_rad: float, radius_mm: float, projection: str) -> float:
    """``radius_mm - projected_radius`` computed without cancellation."""
    if projection == "stereographic":
        s = math.sin(elevation_rad)
        # R - R cos e / (1 + sin e) = R (1 + s - c) / (1 + s)
        return radius_mm * (2.0 * math.sin(elevation_rad / 2.0) ** 2 + s) / (1.0 + s)
    return 2.0 * radius_mm * math.sin(elevation_rad / 2.0) ** 2


@dataclass(frozen=True, slots=True)
class WaveCurve:
    """The S-like wave of one layer between azimuths ``phi_start_rad`` and ``phi_end_rad``.

    ``centre_mm : (3,) float``.  ``span_rad`` is the azimuth of one sector (node to
    node); the wave's phase is anchored at azimuth 0, so it is on the lower track at
    every node.
    """

    centre_mm: np.ndarray
    radius_mm: float
    lower_elevation_rad: float
    upper_elevation_rad: float
    amplitude: float
    waves: int
    span_rad: float
    projection: str
    phi_start_rad: float
    phi_end_rad: float
    crest_at: float = 0.5

    @property
    def squared_contact(self) -> bool:
        """True where the vertical lift meets the equator and needs g(s) = s^2."""
        return self.projection == "vertical" and self.lower_elevation_rad == 0.0

    def azimuth(self, t: np.ndarray) -> np.ndarray:
        return self.phi_start_rad + np.asarray(t, dtype=float) * (self.phi_end_rad - self.phi_start_rad)

    def _deficit(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Azimuth and ``R - rho`` of the planar curve at ``t``."""
        phi = self.azimuth(t)
        if self.crest_at == 0.5:
            s = np.sin(math.pi * self.waves * phi / self.span_rad) ** 2
        else:
            c = self.crest_at
            a = (0.5 - c) / (c * (1.0 - c))
            base = math.floor(min(self.phi_start_rad, self.phi_end_rad) / self.span_rad + 1e-9)
            x = phi / self.span_rad - base
            s = np.sin(math.pi * self.waves * (x + a * x * (1.0 - x))) ** 2
        g = s * s if self.squared_contact else s
        r = self.radius_mm
        d_lower = _radius_deficit(self.lower_elevation_rad, r, self.projection)
        d_upper = _radius_deficit(self.upper_elevation_rad, r, self.projection)
        return phi, d_lower + (d_upper - d_lower) * self.amplitude * g

    def planar(self, t: np.ndarray) -> np.ndarray:
        """The planar design curve ``(k, 2)``, relative to the pivot (mm)."""
        phi, deficit = self._deficit(t)
        rho = self.radius_mm - deficit
        return np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=-1)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        phi, deficit = self._deficit(t)
        r = self.radius_mm
        rho = r - deficit
        if self.projection == "stereographic":
            q = rho * rho
            scale = 2.0 * r * r / (r * r + q)
            x, y = scale * rho * np.cos(phi), scale * rho * np.sin(phi)
            # R (R^2 - rho^2) / (R^2 + rho^2), with R^2 - rho^2 = deficit (2R - deficit)
            z = r * deficit * (2.0 * r - deficit) / (r * r + q)
        else:
            x, y = rho * np.cos(phi), rho * np.sin(phi)
            z = np.sqrt(np.maximum(deficit * (2.0 * r - deficit), 0.0))
        return self.centre_mm + np.stack([x, y, z], axis=-1)


@dataclass(frozen=True, slots=True)
class MeridianCurve:
    """Great-circle arc along the meridian at ``azimuth_rad`` between two elevations."""

    centre_mm: np.ndarray
    radius_mm: float
    azimuth_rad: float
    elevation_start_rad: float
    elevation_end_rad: float

    def __call__(self, t: np.ndarray) -> np.ndarray:
        e = self.elevation_start_rad + np.asarray(t, dtype=float) * (
            self.elevation_end_rad - self.elevation_start_rad)
        ce = np.cos(e)
        return self.centre_mm + self.radius_mm * np.stack(
            [ce * math.cos(self.azimuth_rad), ce * math.sin(self.azimuth_rad), np.sin(e)], axis=-1)


@dataclass(frozen=True, slots=True)
class TrackCurve:
    """Arc along a track (a circle of constant elevation) between two azimuths: how a
    re-measure program goes from one node of a track to another without taking the bar
    off (the identification curves leave and reach every node along it)."""

    centre_mm: np.ndarray
    radius_mm: float
    elevation_rad: float
    azimuth_start_rad: float
    azimuth_end_rad: float

    def __call__(self, t: np.ndarray) -> np.ndarray:
        a = self.azimuth_start_rad + np.asarray(t, dtype=float) * (
            self.azimuth_end_rad - self.azimuth_start_rad)
        ce = math.cos(self.elevation_rad)
        return self.centre_mm + self.radius_mm * np.stack(
            [ce * np.cos(a), ce * np.sin(a), np.full_like(a, math.sin(self.elevation_rad))], axis=-1)


def tangent(curve, t: float, h: float = 1e-6) -> np.ndarray:
    """Unit tangent at ``t`` by central (or one-sided at the ends) differences."""
    a, b = max(0.0, t - h), min(1.0, t + h)
    d = curve(np.array([b]))[0] - curve(np.array([a]))[0]
    return d / np.linalg.norm(d)
