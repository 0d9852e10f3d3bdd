"""Machine poses along a layer path, at a path spacing no coarser than configured."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..arrays import frozen

from ..config import Config
from ..geometry.paths import LayerPath, Run
from .kinematics import Kinematics
from .schedule import RotarySchedule




@dataclass(frozen=True, slots=True)
class RunPoses:
    """Poses of one run.  ``u : (n,)`` curve parameter, ``s_mm : (n,)`` path length
    from the run start, ``points_mm : (n, 3)`` ball centre in the table frame,
    ``q : (n, n_axes)`` axis values (mm, rad), ``piece : (n,) int`` index of the
    run's piece each pose belongs to (a pose on a boundary belongs to both; it is
    listed with the piece that starts there)."""

    run: Run
    u: np.ndarray
    s_mm: np.ndarray
    points_mm: np.ndarray
    q: np.ndarray
    piece: np.ndarray


def sample_run(run: Run, spacing_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Curve parameters at path spacing <= ``spacing_mm`` and their piece indices.

    The fitted curves are parameterised by arc length to within a few per cent, so
    uniform parameter steps sized with a 20 % margin keep every chord under the
    spacing (checked by the tests)."""
    us, pieces = [], []
    for k, piece in enumerate(run.pieces):
        n = max(1, math.ceil(1.2 * piece.length_mm / spacing_mm))
        u = np.linspace(piece.u_start, piece.u_end, n + 1)
        if k < len(run.pieces) - 1:
            u = u[:-1]
        us.append(u)
        pieces.append(np.full(len(u), k))
    return np.concatenate(us), np.concatenate(pieces)


def layer_poses(path: LayerPath, config: Config, kinematics: Kinematics,
                spacing_mm: float | None = None) -> tuple[RunPoses, ...]:
    """Poses of every run of ``path``, with rotary angles continuous across runs."""
    spacing = spacing_mm or config.check.pose_spacing_mm
    schedule = RotarySchedule(config, kinematics)
    carry = None
    out = []
    for run in path.runs:
        u, piece = sample_run(run, spacing)
        points = run.curve.evaluate(u)
        angles, carry = schedule.angles(points, carry)
        q = kinematics.inverse(points, angles)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        out.append(RunPoses(run, frozen(u), frozen(s), frozen(points), frozen(q), frozen(piece)))
    return tuple(out)
