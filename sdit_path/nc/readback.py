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
from ..program_marks import TEST_BEGINS, TEST_ENDS
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


@dataclass(frozen=True, slots=True)
class ReadMoves:
    """A chord or NURBS program read back word by word, as its control reads it.

    ``axes``: the axis letters it programs (X Y Z, then any of A B C); ``points :
    (k, m)`` every straight move's end pose in that order (modal: an axis a block
    leaves out keeps its value), ``lines : (k,)`` their program lines, ``feeds : (k,)``
    the F in effect (mm/min, or 1/min where ``inverse_time``); ``dwells``: ``(line,
    seconds, index of the pose it is made at)``; ``stops``: the lines of program stops
    (M0, M00); ``splines``: ``(index of the pose it starts from, curve over X Y Z,
    the F of its first block)``, the pose after it being its end."""

    axes: tuple[str, ...]
    points: np.ndarray
    lines: np.ndarray
    feeds: np.ndarray
    inverse_time: np.ndarray
    dwells: tuple[tuple[int, float, int], ...]
    stops: tuple[int, ...]
    splines: tuple[tuple[int, BSplineCurve, float], ...] = ()
    #: the test's poses: ``points[test_from:test_to + 1]`` (the pose it starts from to
    #: its last); before and after, the operator's way to the bar and back
    test_from: int = 0
    test_to: int = -1

    @property
    def test(self) -> slice:
        return slice(self.test_from, self.test_to + 1 if self.test_to >= 0 else len(self.points))


_AXIS_ORDER = "XYZABC"


class _Moves:
    def __init__(self):
        self.pos: dict[str, float] = {}
        self.rows: list[dict[str, float]] = []
        self.lines: list[int] = []
        self.feeds: list[float] = []
        self.inverse: list[bool] = []
        self.dwells: list[tuple[int, float, int]] = []
        self.stops: list[int] = []
        self.splines: list[tuple[int, BSplineCurve, float]] = []
        self.feed = float("nan")
        self.inverse_time = False
        self.test_from, self.test_to = 0, -1

    def mark(self, raw: str) -> None:
        """Where the comments that frame the test fall among the poses."""
        low = raw.lower()
        if TEST_BEGINS in low:
            self.test_from = max(len(self.rows) - 1, 0)
        if TEST_ENDS in low:
            self.test_to = len(self.rows) - 1

    def move(self, lineno: int, vals: dict[str, float]) -> None:
        self.pos.update({a: v for a, v in vals.items() if a in _AXIS_ORDER})
        self.rows.append(dict(self.pos))
        self.lines.append(lineno)
        self.feeds.append(self.feed)
        self.inverse.append(self.inverse_time)

    def done(self) -> ReadMoves:
        axes = tuple(a for a in _AXIS_ORDER if any(a in r for r in self.rows))
        pts = np.array([[r.get(a, np.nan) for a in axes] for r in self.rows]).reshape(-1, len(axes))
        return ReadMoves(axes, pts, np.array(self.lines, int), np.array(self.feeds),
                         np.array(self.inverse, bool), tuple(self.dwells), tuple(self.stops),
                         tuple(self.splines), self.test_from, self.test_to)


def read_iso(text: str) -> ReadMoves:
    """A FANUC or Haas program (``G01`` chords, ``G06.2`` NURBS, ``G04 X`` seconds,
    ``G04 P`` milliseconds or, with a decimal point, seconds as Haas reads it)."""
    m = _Moves()
    nurbs: dict | None = None

    def close() -> None:
        nonlocal nurbs
        if nurbs is None:
            return
        rank, pts, knots, w = nurbs["rank"], nurbs["points"], nurbs["knots"], nurbs["w"]
        weights = np.array(w) if any(x != 1.0 for x in w) else None
        curve = BSplineCurve(rank - 1, np.array(knots), np.array(pts), weights)
        m.splines.append((nurbs["from"], curve, nurbs["feed"]))
        end = dict(zip("XYZ", pts[-1]))
        end.update(nurbs["rot"])
        m.move(nurbs["line"], end)
        nurbs = None

    for lineno, raw in enumerate(text.splitlines(), start=1):
        m.mark(raw)
        code = re.sub(r"\([^)]*\)", " ", raw).strip().upper()
        if not code or code == "%" or code.startswith("O"):
            continue
        ws, _ = words(code)
        g = [float(v) for a, _, v in ws if a == "G" and v]
        vals = {a: float(v) for a, _, v in ws if v and a != "G"}
        if "F" in vals and 6.2 not in g and nurbs is None:
            m.feed = vals["F"]
        if 93.0 in g:
            m.inverse_time = True
        if 94.0 in g:
            m.inverse_time = False
        if nurbs is not None and not g:
            if set(vals) == {"K"}:
                nurbs["knots"].append(vals["K"])
            else:
                nurbs["knots"].append(vals["K"])
                nurbs["points"].append([vals.get(a, p) for a, p in zip("XYZ", nurbs["points"][-1])])
                nurbs["w"].append(vals.get("R", 1.0))
                for a in "ABC":
                    if a in vals:
                        nurbs["rot"][a] = vals[a]
                nurbs["line"] = lineno
            continue
        close()
        if 6.2 in g:
            start = [vals.get(a, m.pos.get(a, np.nan)) for a in "XYZ"]
            nurbs = {"rank": int(vals.get("P", 4)), "points": [start], "knots": [vals["K"]],
                     "w": [vals.get("R", 1.0)], "from": len(m.rows) - 1, "line": lineno,
                     "feed": vals.get("F", m.feed), "rot": {}}
            if "F" in vals:
                m.feed = vals["F"]
            continue
        if 4.0 in g:
            if "X" in vals:
                seconds = vals["X"]
            else:
                p_word = next(v for a, _, v in ws if a == "P")
                seconds = float(p_word) if "." in p_word else float(p_word) / 1000.0
            m.dwells.append((lineno, seconds, len(m.rows) - 1))
            continue
        if vals.get("M") in (0.0, 1.0):
            m.stops.append(lineno)
        if any(a in vals for a in _AXIS_ORDER):
            m.move(lineno, vals)
    close()
    return m.done()


def read_heidenhain(text: str) -> ReadMoves:
    """A HEIDENHAIN Klartext program: ``L`` moves (signed coordinates, modal F),
    ``CYCL DEF 9.1 DWELL`` seconds, ``M0`` stops."""
    m = _Moves()
    for lineno, raw in enumerate(text.splitlines(), start=1):
        m.mark(raw)
        block = raw.split(" ", 1)[1] if " " in raw else ""
        if block.startswith(";") or not block:
            continue
        if block.startswith("CYCL DEF 9.1 DWELL"):
            m.dwells.append((lineno, float(block.split()[-1]), len(m.rows) - 1))
            continue
        if block in ("M0", "STOP", "STOP M0"):
            m.stops.append(lineno)
            continue
        if not block.startswith("L "):
            continue
        vals = {}
        for tok in block.split()[1:]:
            if tok[0] in _AXIS_ORDER:
                vals[tok[0]] = float(tok[1:])
            elif tok.startswith("F") and tok != "FMAX":
                m.feed = float(tok[1:])
        m.move(lineno, vals)
    return m.done()
