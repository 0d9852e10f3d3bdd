"""Reading emitted programs back, the way a controller would.

``read_sinumerik`` rebuilds every BSPLINE from its words alone (control points as
printed, ``SD``, ``PW``, ``PL``), starting at the position reached by the previous
block, so the round trip emit -> read -> evaluate measures what the machine runs.
``read_polyline`` does the same for straight moves (any controller whose blocks are
``G1 X Y Z`` with modal coordinates).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..geometry.nurbs import BSplineCurve
from .words import words


@dataclass(frozen=True, slots=True)
class ReadProgram:
    """``splines``: every BSPLINE as a curve (X Y Z); ``spline_rotary``: for each, the
    rotary words per control point (axis -> ``(n,)`` deg, the first being the value
    before the spline); ``dwells``: ``(line, seconds, xyz)``; ``points_mm : (k, 3)``
    every programmed end point in order; ``traori``: TRAORI was switched on."""

    splines: tuple[BSplineCurve, ...]
    dwells: tuple[tuple[int, float, tuple[float, ...]], ...]
    points_mm: np.ndarray
    spline_rotary: tuple[dict[str, np.ndarray], ...] = ()
    traori: bool = False


def _knots(degree: int, intervals: list[float]) -> np.ndarray:
    inner = np.concatenate([[0.0], np.cumsum(intervals)])
    return np.concatenate([np.full(degree, inner[0]), inner, np.full(degree, inner[-1])])


def read_sinumerik(text: str) -> ReadProgram:
    pos = [np.nan, np.nan, np.nan]
    rot: dict[str, float] = {}
    splines, dwells, points, rotary = [], [], [], []
    spline: dict | None = None
    modal_g = "G0"
    traori = False

    def close() -> None:
        nonlocal spline
        if spline is None:
            return
        q = np.array(spline["points"])
        deg = spline["degree"]
        n_int = len(q) - deg
        # the lint guarantees one PL value per curve, so every reading agrees
        pl = float(spline["pl"][0]) if spline["pl"] else 1.0
        w = np.array(spline["w"]) if any(x != 1.0 for x in spline["w"]) else None
        splines.append(BSplineCurve(deg, _knots(deg, [pl] * n_int), q, w))
        rotary.append({k: np.array(v) for k, v in spline["rot"].items()})
        spline = None

    for lineno, raw in enumerate(text.splitlines(), start=1):
        code = raw.split(";", 1)[0].strip()
        if not code:
            continue
        ws, _ = words(code)
        addr = [f"{a}{v}" if a == "G" else a for a, _, v in ws]
        vals = {a: float(v) for a, _, v in ws if v and a != "G"}
        traori = traori or "TRAORI" in addr
        if "G4" in addr:
            dwells.append((lineno, vals.get("F", float("nan")), tuple(pos)))
            continue
        motion = [a for a in addr if a in ("G0", "G1", "G2", "G3", "BSPLINE", "CIP")]
        if motion:
            if motion[-1] != "BSPLINE" or modal_g != "BSPLINE":
                close()
            if motion[-1] == "BSPLINE" and spline is None:
                spline = {"points": [list(pos)], "w": [1.0], "pl": [], "degree": 3,
                          "rot": {k: [v] for k, v in rot.items()}}
            modal_g = motion[-1]
        if spline is not None and "SD" in vals:
            spline["degree"] = int(vals["SD"])
        new = [vals.get(k, p) for k, p in zip("XYZ", pos)]
        for k in "ABC":
            if k in vals:
                rot[k] = vals[k]
        if any(k in vals for k in "XYZ"):
            if spline is not None:
                for k, v in rot.items():
                    spline["rot"].setdefault(k, []).append(v)
                spline["points"].append(new)
                spline["w"].append(vals.get("PW", 1.0))
                if "PL" in vals:
                    spline["pl"].append(vals["PL"])
            pos = new
            points.append(new)
    close()
    return ReadProgram(tuple(splines), tuple(dwells), np.array(points), tuple(rotary), traori)


def read_polyline(text: str) -> np.ndarray:
    """Every programmed ``X Y Z`` end point ``(k, 3)`` of a G-code program with
    ``( )`` or ``;`` comments and modal coordinates (LinuxCNC, Fanuc style)."""
    pos = [np.nan, np.nan, np.nan]
    points = []
    for raw in text.splitlines():
        code = re.sub(r"\([^)]*\)", " ", raw).split(";", 1)[0].strip()
        if not code or code == "%":
            continue
        ws, _ = words(code.upper())
        vals = {a: float(v) for a, _, v in ws if v and a in "XYZ"}
        if vals:
            pos = [vals.get(k, p) for k, p in zip("XYZ", pos)]
            points.append(pos)
    return np.array(points)
