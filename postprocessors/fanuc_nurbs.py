"""FANUC 30i (and controls with the NURBS interpolation option): ``G06.2`` B-splines.

The FANUC post (:mod:`.fanuc`) states the framing, comment, number, dwell and AI
contour control facts this one shares.  What ``G06.2`` needs [doc: FANUC Series
15i/150i-MA operator's manual B-63324EN 4.17, pp.121-128; its 30i descendants keep
the format]:

- ``G06.2 P_ K_ X_ Y_ Z_ [R_] F_`` starts the curve; every following block
  ``K_ X_ Y_ Z_ [R_]`` adds a control point with one knot; then as many knot-only
  blocks ``K_`` as the rank.  ``P`` is the rank (order) 2-4, degree + 1 (default 4,
  cubic); ``R`` a weight (default 1); the number of knots is the number of control
  points plus the rank, the first rank knots equal and the last rank knots equal
  (alarm PS1007), so the curve is clamped at both ends.
- The first control point must be the current position (PS1009): we write it, the
  end of the block before, exactly as printed there.
- ``G06.2`` is modal in group 01: the ``G01`` after the last knot ends it; no other
  command inside it; not under ``G93``, ``G95`` or cutter compensation (PS1006).
- Knots and weights are read with the increment system's decimals: with IS-C, 4
  decimals; the knots are the curve's own (its clamped vector, non-uniform where it
  is), scaled to millimetres of the run's length.
- Which look-ahead mode ``G06.2`` needs on a 30i or an 0i-F is not in the manuals we
  found (some builders ask for ``G05 P10000``): the program switches AI contour control
  on (``G05.1 Q1``), as the chord post does, and says so [assumed].
- Five axes: the control interpolates the machine axes' spline (X Y Z B C) and its
  feed is the machine's composite feed over them, not the ball's against the table:
  the program's timing differs from the plan's; the FANUC chord post (``fanuc``, G93
  inverse time) keeps it.
"""

from __future__ import annotations

import numpy as np

from sdit_path.nc.iso import (Dialect, chord_body, comment_lines, lint_iso, number,
                              point_words)
from sdit_path.nc.program import Program, SplineMove
from sdit_path.nc.words import fixed

from .fanuc import frame_iso, offset_word

_DIALECT = Dialect(dwell_word="X", dwell_decimal=True)


class FanucNurbs:
    name = "fanuc_nurbs"
    title = "FANUC 30i NURBS (G06.2, AI contour control)"
    short = "FANUC NURBS"
    extension = ".nc"
    path_form = "spline"
    corners = None
    max_decimals = 4
    five_axis = "machine"

    def render(self, program: Program) -> str:
        d = program.decimals
        offset, note = offset_word(program)
        body: list[str] = []
        for item in program.items:
            if isinstance(item, SplineMove):
                body += self._spline(item, d)
            else:
                body += chord_body((item,), d, _DIALECT)
        preamble = ["G17 G21 G40 G80 G90 G94", offset, "M05", "G05.1 Q1"]
        assumed = note + ["NURBS G06.2 with AI contour control G05.1 Q1 on",
                          "dwells G04 X in seconds"]
        return frame_iso(program, preamble, body, ["G05.1 Q0"], 4, assumed)

    @staticmethod
    def _spline(move: SplineMove, d: int) -> list[str]:
        curve = move.curve
        k = curve.degree + 1
        n = len(curve.control_points_mm)
        span = curve.knots[curve.degree + 1] - curve.knots[curve.degree]
        knots = (curve.knots - curve.knots[0]) * (move.knot_interval / span)
        labels = dict(move.labels)
        out = []
        for j in range(n):
            if j in labels:
                out += comment_lines(labels[j])
            rot = tuple((a, float(v[j])) for a, v in move.rotary_deg)
            line = f"K{number(knots[j], d)} {point_words(curve.control_points_mm[j], rot, d)}"
            if curve.weights is not None:
                line += f" R{number(curve.weights[j], 4)}"
            if j == 0:
                line = f"G06.2 P{k} {line} F{number(move.feed_mm_per_min, 3)}"
            out.append(line)
        out += [f"K{number(v, d)}" for v in knots[n:]]
        # G06.2 ends with the next group-01 code: a G01 to where the curve ended
        end = curve.control_points_mm[-1]
        rot = "".join(f" {a}{fixed(float(v[-1]), d)}" for a, v in move.rotary_deg)
        out.append(f"G01 {point_words(end, (), d)}{rot}")
        return out

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]:
        state = {"aicc": False, "nurbs": None}

        def dwell_ok(ws, values):
            if not (len(ws) == 2 and ws[1][0] == "X" and values.get("X", 0) > 0):
                return "dwell must be 'G04 X<seconds>.' alone in its block"
            return None

        def close(lineno):
            nb = state["nurbs"]
            state["nurbs"] = None
            if nb is None:
                return []
            rank, knots, points = nb["rank"], nb["knots"], nb["points"]
            out = []
            if nb["tail"] != rank:
                out.append(f"line {lineno}: G06.2 from line {nb['line']} ends with "
                           f"{nb['tail']} knot-only blocks, not its rank {rank}")
            if len(knots) != points + rank:
                out.append(f"line {lineno}: G06.2 from line {nb['line']}: {len(knots)} knots "
                           f"for {points} control points of rank {rank}")
            elif (np.diff(knots) < 0).any() or len(set(knots[:rank])) != 1 \
                    or len(set(knots[-rank:])) != 1:
                out.append(f"line {lineno}: G06.2 from line {nb['line']}: knots must rise, "
                           f"the first and the last {rank} equal")
            return out

        def extra(lineno, gnums, values, code):
            out = []
            if 5.1 in gnums:
                state["aicc"] = values.get("Q") == 1.0
            nb = state["nurbs"]
            if 6.2 in gnums:
                out += close(lineno)
                rank = int(values.get("P", 4))
                if rank not in (2, 3, 4):
                    out.append(f"line {lineno}: G06.2 P{rank}; the rank is 2-4")
                if "K" not in values:
                    out.append(f"line {lineno}: G06.2 needs its first knot")
                state["nurbs"] = {"line": lineno, "rank": rank, "knots": [values.get("K", 0.0)],
                                  "points": 1, "tail": 0}
            elif nb is not None and gnums:
                out += close(lineno)
            elif nb is not None:
                if set(values) - {"K", "X", "Y", "Z", "A", "B", "C", "R"} or "K" not in values:
                    out.append(f"line {lineno}: inside G06.2 only K X Y Z (A B C) R blocks")
                nb["knots"].append(values.get("K", 0.0))
                if set(values) == {"K"}:
                    nb["tail"] += 1
                elif nb["tail"]:
                    out.append(f"line {lineno}: a control point after knot-only blocks")
                else:
                    nb["points"] += 1
                if "R" in values and not values["R"] > 0:
                    out.append(f"line {lineno}: a weight must be > 0")
            if code in ("M30", "M02") and state["aicc"]:
                out.append(f"line {lineno}: AI contour control still on at the program end; "
                           f"G05.1 Q0 first")
            if 93.0 in gnums or 95.0 in gnums:
                out.append(f"line {lineno}: G93 / G95 are not allowed with G06.2")
            if 49.0 in gnums:
                out.append(f"line {lineno}: G49 cancels the ballbar cup's length offset")
            return out

        return lint_iso(text, travel_mm, dwell_ok, extra)
