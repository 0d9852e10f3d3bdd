"""Small helpers for the numpy arrays inside frozen domain values."""

from __future__ import annotations

import numpy as np


def frozen(values, dtype=float) -> np.ndarray:
    """A read-only copy of ``values``: domain values never change after construction."""
    a = np.array(values, dtype=dtype)
    a.setflags(write=False)
    return a
