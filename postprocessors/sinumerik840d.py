"""SINUMERIK 840D sl: main programs (.MPF) with BSPLINE.

Facts relied on (programming manual, job planning): ``BSPLINE`` is modal in G group 1;
each following block is one control point and the curve starts at the current
position, clamped at both ends; ``SD=`` degree 2 or 3; ``PW=`` weight 0..3 in steps of
0.0001; ``PL=`` knot-interval length.  Which interval a block's PL belongs to is not
documented, so every PL of a curve is written and all are equal: every reading gives
the same uniform knot vector.  ``G4 F<s>`` dwells seconds, alone in its block; F is
mm/min under G94; comments start with ``;``.  At least 6 of every 10 blocks of a spline
must be spline blocks.
"""

from __future__ import annotations

import math

from sdit_path.nc.program import (AxisMove, Comment, Dwell, LinearMove, PolylineMove, Program,
                                  ProgramStop, SplineMove)
from sdit_path.nc.text import neutralise
from sdit_path.nc.words import fixed, frame, trimmed, words, xyz

MAX_BLOCK_CHARS = 512
_KEYWORDS = {"BSPLINE", "ASPLINE", "CSPLINE", "CIP", "CT", "POLY", "TRAORI", "TRAFOOF",
             "ORIWKS", "ORIAXES", "ORIMKS", "ORIVECT"}
_MOTION = {"G0", "G00", "G1", "G01", "G2", "G02", "G3", "G03", "CIP", "CT", "ASPLINE",
           "CSPLINE", "POLY", "BSPLINE"}


#: user text in one comment is cut to this length
MAX_COMMENT_CHARS = 200


def _comment(text: str) -> str:
    text = neutralise(text)
    if len(text) > MAX_COMMENT_CHARS:
        text = text[: MAX_COMMENT_CHARS - 3].rstrip() + "..."
    return text


class Sinumerik840D:
    name = "sinumerik840d"
    title = "SINUMERIK 840D sl"
    short = "840D"
    extension = ".MPF"
    path_form = "spline"
    corners = None  # a native spline: no chords

    # ------------------------------------------------------------------ rendering

    def render(self, program: Program) -> str:
        d = program.decimals

        body: list[str] = []
        for item in program.items:
            if isinstance(item, Comment):
                body.append(f"; {_comment(item.text)}")
            elif isinstance(item, LinearMove):
                rot = "".join(f" {n}{fixed(v, d)}" for n, v in item.rotary_deg)
                body.append(f"G1 {xyz(item.point_mm, d)}{rot} F{trimmed(item.feed_mm_per_min, 3)}")
            elif isinstance(item, AxisMove):
                ws = " ".join(f"{n}{fixed(v, d)}" for n, v in item.words)
                body.append(f"G1 {ws} F{trimmed(item.feed_mm_per_min, 3)}")
            elif isinstance(item, Dwell):
                body.append(f"; dwell at node {_comment(item.node_id)}")
                body.append(f"G4 F{trimmed(item.seconds, 3)}")
            elif isinstance(item, SplineMove):
                body.extend(self._spline(item, d))
            elif isinstance(item, ProgramStop):
                body.append(f"; STOP: {_comment(item.message)}")
                body.append("M0")
            elif isinstance(item, PolylineMove):
                raise TypeError("SINUMERIK 840D programs carry splines, not chords")
        preamble = [f"G17 G90 G71 G94 G40 {program.work_offset}", "M5"]
        footer = []
        if program.frame == "traori":
            preamble += ["TRAORI", "ORIWKS", "ORIAXES"]
            footer.append("TRAFOOF")
        header = [_comment(line) for line in program.header]
        return frame("sinumerik840d/program.mpf.j2", name=program.name, header=header,
                     preamble=preamble, body=body, footer=footer)

    @staticmethod
    def _spline(move: SplineMove, d: int) -> list[str]:
        curve = move.curve
        labels = dict(move.labels)
        pl = f"PL={trimmed(move.knot_interval, 3)}"
        out = []
        for j in range(1, len(curve.control_points_mm)):
            if j in labels:
                out.append(f"; {_comment(labels[j])}")
            words_ = xyz(curve.control_points_mm[j], d)
            words_ += "".join(f" {n}{fixed(v[j], d)}" for n, v in move.rotary_deg)
            if curve.weights is not None:
                words_ += f" PW={curve.weights[j]:.4f}"
            if j == 1:
                out.append(f"BSPLINE SD={curve.degree} {words_} {pl} "
                           f"F{trimmed(move.feed_mm_per_min, 3)}")
            else:
                out.append(f"{words_} {pl}")
        out.append("G1")
        return out

    # ------------------------------------------------------------------ lint

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]:
        problems: list[str] = []
        lines = text.split("\n")
        if lines and lines[-1] == "":
            lines = lines[:-1]
        in_spline = False
        run: list[bool] = []  # per block of the current spline: is it a spline block
        run_start = 0
        pls: set[str] = set()
        seen_g94 = seen_g71 = False
        traori_line = 0
        last_code = ""

        def close_run(lineno: int) -> None:
            for k in range(0, max(1, len(run) - 9)):
                window = run[k:k + 10]
                if len(window) == 10 and sum(window) < 6:
                    problems.append(f"line {run_start + k}: only {sum(window)} of 10 blocks in the "
                                    f"spline starting at line {run_start} are spline blocks (>= 6 needed)")
                    break
            if len(pls) > 1:
                problems.append(f"line {run_start}: knot intervals differ within one spline "
                                f"({', '.join(sorted(pls))}); they must all be equal")

        for lineno, raw in enumerate(lines, start=1):
            if any(ord(ch) < 32 or ord(ch) > 126 for ch in raw):
                problems.append(f"line {lineno}: control or non-ASCII character")
            if len(raw) > MAX_BLOCK_CHARS:
                problems.append(f"line {lineno}: block longer than {MAX_BLOCK_CHARS} characters")
            code = raw.split(";", 1)[0].strip()
            if not code:
                if in_spline and raw.strip():
                    run.append(False)
                continue
            last_code = code
            ws, bad = words(code)
            bad += [a for a, _, v in ws if not v and a not in _KEYWORDS]
            for tok in bad:
                problems.append(f"line {lineno}: cannot read word {tok!r}")
            addresses = [f"{a}{v}" if a == "G" else a for a, _, v in ws]
            values = {}
            for a, eq, v in ws:
                if v:
                    try:
                        values[a] = float(v)
                    except ValueError:
                        problems.append(f"line {lineno}: {a}{eq}{v} is not a number")
                    else:
                        if not math.isfinite(values[a]):
                            problems.append(f"line {lineno}: {a} is not finite")
                        elif a == "F" and not values[a] > 0:
                            problems.append(f"line {lineno}: F{v}; a feed or dwell must be > 0")
            if "G94" in addresses:
                seen_g94 = True
            if "G71" in addresses:
                seen_g71 = True
            if "G70" in addresses:
                problems.append(f"line {lineno}: G70 (inch) found; programs are metric (G71)")
            if "G4" in addresses or "G04" in addresses:
                if not (len(ws) == 2 and ws[1][0] == "F" and ws[1][1] == "" and values.get("F", 0) > 0):
                    problems.append(f"line {lineno}: dwell must be 'G4 F<seconds>' alone in its "
                                    f"block, got {code!r}")
                if in_spline:
                    run.append(False)
                continue
            if "TRAORI" in addresses:
                traori_line = lineno
            if "TRAFOOF" in addresses:
                if not traori_line:
                    problems.append(f"line {lineno}: TRAFOOF without TRAORI")
                traori_line = 0
            if "M30" in addresses and traori_line:
                problems.append(f"line {lineno}: TRAORI (line {traori_line}) still active at M30; "
                                f"switch it off with TRAFOOF")
            motion = [a for a in addresses if a in _MOTION]
            if "BSPLINE" in motion:
                if in_spline:
                    close_run(lineno)
                in_spline, run, run_start, pls = True, [], lineno, set()
            elif motion and in_spline:
                close_run(lineno)
                in_spline = False
            if "SD" in values and values["SD"] not in (2.0, 3.0):
                problems.append(f"line {lineno}: SD={values['SD']:g}; the degree must be 2 or 3")
            if "PW" in values:
                text_pw = next(v for a, _, v in ws if a == "PW")
                frac = text_pw.split(".", 1)[1] if "." in text_pw else ""
                if not 0.0 <= values["PW"] <= 3.0 or len(frac) > 4:
                    problems.append(f"line {lineno}: PW={text_pw}; weights must lie in 0..3 "
                                    f"with at most 4 decimals")
            if "PL" in values:
                if values["PL"] <= 0:
                    problems.append(f"line {lineno}: PL must be positive")
                pls.add(next(v for a, _, v in ws if a == "PL"))
            for axis, (lo, hi) in travel_mm.items():
                if axis in values and not lo <= values[axis] <= hi:
                    problems.append(f"line {lineno}: {axis}{values[axis]:g} outside the travel "
                                    f"[{lo:g}, {hi:g}] mm")
            if in_spline:
                run.append(any(a in ("X", "Y", "Z", "A", "B", "C") for a, _, _ in ws))
        if in_spline:
            close_run(len(lines))
        if not seen_g94:
            problems.append("preamble: G94 (feed in mm/min) missing")
        if not seen_g71:
            problems.append("preamble: G71 (metric) missing")
        if last_code != "M30":
            problems.append(f"end: the last block must be M30, got {last_code!r}")
        return problems
