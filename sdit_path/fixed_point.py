"""The fixed-point rule every number of an NC program is written with.

A program holds its coordinates as decimal text with ``post.decimals`` places; the
control reads that text, not our floats.  The spline fit, the timing and the
post-processors all work with the values as the control will read them, so the rule
lives below all three."""

from __future__ import annotations

import numpy as np


def round_to_decimals(values: np.ndarray, decimals: int) -> np.ndarray:
    """Round exactly as the post-processors print: via fixed-point text."""
    flat = [float(f"{v:.{decimals}f}") + 0.0 for v in np.asarray(values, dtype=float).ravel()]
    return np.array(flat).reshape(np.shape(values))
