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
