"""The view every top-down picture uses (numpy only: no drawing here)."""

from __future__ import annotations

import numpy as np


def above_pivot(ball_mm: np.ndarray, pivot_mm) -> tuple[np.ndarray, np.ndarray]:
    """Ball positions ``(n, 3)`` seen from above the pivot, azimuthal equidistant: the
    distance from the centre is the angle from the pole (deg; 90 at the equator), the
    angle the azimuth (from +X, counter-clockwise seen from +Z)."""
    p = np.asarray(ball_mm, float) - np.asarray(pivot_mm, float)
    r = np.maximum(np.linalg.norm(p, axis=1), 1e-9)
    colat = 90.0 - np.degrees(np.arcsin(np.clip(p[:, 2] / r, -1.0, 1.0)))
    az = np.arctan2(p[:, 1], p[:, 0])
    return colat * np.cos(az), colat * np.sin(az)
