"""Controller-neutral NC programs: typed items, no text.

A post-processor is a pure function from a :class:`Program` to text.  Geometry that a
controller cannot run natively (LinuxCNC has no 3-D spline) is converted here, before
any post-processor sees it, so every post only formats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.nurbs import BSplineCurve


@dataclass(frozen=True, slots=True)
class Comment:
    text: str


@dataclass(frozen=True, slots=True)
class LinearMove:
    """Straight feed move.  ``point_mm : (3,) float`` in the program's frame;
    ``rotary_deg``: (axis, angle) words that go with it."""

    point_mm: np.ndarray
    feed_mm_per_min: float
    rotary_deg: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True, slots=True)
class AxisMove:
    """A straight feed move of the axes named in ``words`` (axis, value in mm or deg);
    the others keep their place (the operator sequence's first move: Z up)."""

    words: tuple[tuple[str, float], ...]
    feed_mm_per_min: float


@dataclass(frozen=True, slots=True)
class SplineMove:
    """One clamped B-spline from the current position (its first control point).

    ``labels`` marks where a named piece starts: ``(control point index, label)``; the
    index is the first control point whose Greville abscissa lies in the piece.
    """

    curve: BSplineCurve
    feed_mm_per_min: float
    knot_interval: float
    labels: tuple[tuple[int, str], ...]
    rotary_deg: tuple[tuple[str, np.ndarray], ...] = ()


@dataclass(frozen=True, slots=True)
class PolylineMove:
    """Chords.  ``points_mm : (k, 3) float`` excludes the current position;
    ``rotary_deg``: (axis, ``(k,)`` angles); ``inverse_time_per_min : (k,)`` when the
    feed is given per block in inverse time (G93), else None."""

    points_mm: np.ndarray
    feed_mm_per_min: float
    labels: tuple[tuple[int, str], ...]
    rotary_deg: tuple[tuple[str, np.ndarray], ...] = ()
    inverse_time_per_min: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class Dwell:
    seconds: float
    node_id: str


@dataclass(frozen=True, slots=True)
class ProgramStop:
    """An unconditional stop for the operator (M0), with what to do."""

    message: str


Item = Comment | LinearMove | AxisMove | SplineMove | PolylineMove | Dwell | ProgramStop


@dataclass(frozen=True, slots=True)
class Program:
    """One layer program for one controller.

    ``header`` lines are free text (sanitised by the post-processor);
    ``work_offset`` is the frame the coordinates are written in; ``tolerance_mm`` the
    radial tolerance the path representation was made to (controllers that blend
    corners are told to stay within it).  ``frame``: ``table`` (ball centre in the
    table frame), ``traori`` (the same, with the control's 5-axis transformation on and
    rotary words), ``tcpm`` (the same for chords: the control's tool centre point
    control keeps the ball on each straight chord of the table frame while the rotary
    axes turn) or ``machine`` (machine axis values).
    """

    name: str
    controller: str
    layer: str
    header: tuple[str, ...]
    work_offset: str
    decimals: int
    tolerance_mm: float
    frame: str
    items: tuple[Item, ...]
    #: the program's place in the plan (1, 2, ...), for controls that number programs
    number: int = 1
