"""LinuxCNC 2.9: 3-D G1 chords.

LinuxCNC's NURBS (G5.2/G5.3) work in the XY plane only and silently ignore Z, so the
spherical path is written as 3-D chords whose radial deviation, sagitta included,
stays within the stated tolerance; ``G64 P<tol> Q0`` keeps blending within the same
tolerance and switches the naive-CAM merger off.  ``G4 P<s>`` dwells seconds.
Comments are ``( ... )``; user text never starts a special comment (MSG, DEBUG, LOG...).
"""

from __future__ import annotations

import math
import re

from sdit_path.nc.chords import CornerModel
from sdit_path.nc.program import (AxisMove, Comment, Dwell, LinearMove, PolylineMove, Program,
                                  ProgramStop, SplineMove)
from sdit_path.nc.text import neutralise
from sdit_path.nc.words import fixed, frame, trimmed, words, xyz

#: Comments LinuxCNC acts on (rs274ngc: MSG, DEBUG, PRINT, LOG..., PROBEOPEN/CLOSE,
#: ABORT; the Python plug-in: PY, PYRUN, PYRELOAD; the AXIS GUI: AXIS,...): the
#: interpreter skips leading white space and compares lower case.  Any comment whose
#: first word is followed by a comma is treated the same, so that a keyword added in a
#: later release is neutralised too.
_SPECIAL = re.compile(r"^\s*(msg|debug|print|log|probe|abort|py|axis|remap|[a-z0-9_]+\s*,)",
                      re.IGNORECASE)
_OFFSETS = {"G54", "G55", "G56", "G57", "G58", "G59"}
#: rs274ngc refuses lines of LINELEN (255) characters less its terminators; keep well below
MAX_LINE_CHARS = 250
#: user text in one comment is cut to this length (the line keeps its parentheses)
MAX_COMMENT_CHARS = 200


def _comment(text: str) -> str:
    text = neutralise(text, forbidden="()")
    if _SPECIAL.match(text):
        text = "- " + text
    if len(text) > MAX_COMMENT_CHARS:
        text = text[: MAX_COMMENT_CHARS - 3].rstrip() + "..."
    return text


class LinuxCNC:
    name = "linuxcnc"
    title = "LinuxCNC 2.9"
    short = "LinuxCNC"
    extension = ".ngc"
    path_form = "chords"
    #: LinuxCNC 2.9's planner joins two chords at the feed when the turn, taken within one
    #: 1 ms servo period, asks at most ARC_BLEND_KINK_RATIO (default 0.1) of an axis'
    #: acceleration (tp.c, tpSetupTangent), or rounds the corner with an arc within G64 P
    #: at BLEND_ACC_RATIO_NORMAL (0.866) of it (tpCreateLineLineBlend); half of that
    #: leaves room for a feed override up to 200 %; blocks shorter than 1.02 servo
    #: periods at speed are slowed (TP_MIN_SEGMENT_CYCLES), so chords stay two periods long
    corners = CornerModel(servo_period_s=0.001, kink_ratio=0.1, normal_accel_ratio=0.866,
                          min_arc_periods=4.0, margin=0.5, min_block_periods=2.0)

    def render(self, program: Program) -> str:
        d = program.decimals

        body: list[str] = []
        modal_feed = None  # the F in force (None after inverse time)
        for item in program.items:
            if isinstance(item, Comment):
                body.append(f"({_comment(item.text)})")
            elif isinstance(item, LinearMove):
                rot = "".join(f" {n}{fixed(v, d)}" for n, v in item.rotary_deg)
                body.append(f"G1 {xyz(item.point_mm, d)}{rot} F{trimmed(item.feed_mm_per_min, 3)}")
                modal_feed = item.feed_mm_per_min
            elif isinstance(item, AxisMove):
                ws = " ".join(f"{n}{fixed(v, d)}" for n, v in item.words)
                body.append(f"G1 {ws} F{trimmed(item.feed_mm_per_min, 3)}")
                modal_feed = item.feed_mm_per_min
            elif isinstance(item, Dwell):
                body.append(f"(dwell at node {_comment(item.node_id)})")
                body.append(f"G4 P{trimmed(item.seconds, 3)}")
            elif isinstance(item, PolylineMove):
                labels = dict(item.labels)
                inverse = item.inverse_time_per_min
                if inverse is not None:
                    body.append("(inverse time: every block's F is 1/minutes)")
                    body.append("G93")
                for j, p in enumerate(item.points_mm):
                    if j in labels:
                        body.append(f"({_comment(labels[j])})")
                    line = xyz(p, d) + "".join(f" {n}{fixed(v[j], d)}" for n, v in item.rotary_deg)
                    if inverse is not None:
                        line += f" F{fixed(inverse[j], 4)}"
                    elif j == 0 and item.feed_mm_per_min != modal_feed:
                        # a sector re-planned at its own feed (and the feed after it)
                        line += f" F{trimmed(item.feed_mm_per_min, 3)}"
                    body.append(f"G1 {line}" if j == 0 else line)
                modal_feed = None if inverse is not None else item.feed_mm_per_min
                if inverse is not None:
                    body.append("G94")
            elif isinstance(item, ProgramStop):
                body.append(f"(STOP: {_comment(item.message)})")
                body.append("M0")
            elif isinstance(item, SplineMove):
                raise TypeError("LinuxCNC programs carry 3-D chords, not splines")
        tol = program.tolerance_mm
        offset = program.work_offset if program.work_offset in _OFFSETS else "G54"
        preamble = ["G21 G17 G90 G94 G40", offset, f"G64 P{trimmed(tol, 6)} Q0", "M5"]
        header = [_comment(line) for line in program.header]
        if program.work_offset not in _OFFSETS:
            header.append(f"{_comment(program.work_offset)} has no LinuxCNC equivalent: "
                          f"run with a zero G54 offset for machine coordinates")
        return frame("linuxcnc/program.ngc.j2", name=program.name, header=header,
                     preamble=preamble, body=body)

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]:
        problems: list[str] = []
        lines = text.split("\n")
        if lines and lines[-1] == "":
            lines = lines[:-1]
        last_code = ""
        seen_g21 = seen_g94 = False
        inverse_time = False
        for lineno, raw in enumerate(lines, start=1):
            if any(ord(ch) < 32 or ord(ch) > 126 for ch in raw):
                problems.append(f"line {lineno}: control or non-ASCII character")
            if len(raw) > MAX_LINE_CHARS:
                problems.append(f"line {lineno}: {len(raw)} characters; LinuxCNC reads at most "
                                f"{MAX_LINE_CHARS}")
            stripped = raw.strip()
            if stripped == "%":
                if lineno not in (1, len(lines)):
                    problems.append(f"line {lineno}: '%' only on the first and last line")
                continue
            code, depth, comments = [], 0, []
            for ch in raw:
                if ch == "(":
                    if depth:
                        problems.append(f"line {lineno}: nested comment")
                    depth += 1
                    comments.append("")
                elif ch == ")":
                    if not depth:
                        problems.append(f"line {lineno}: ')' without '('")
                    depth = max(0, depth - 1)
                elif ch == ";" and not depth:
                    break
                elif depth:
                    comments[-1] += ch
                else:
                    code.append(ch)
            if depth:
                problems.append(f"line {lineno}: unclosed comment")
            for c in comments:
                if _SPECIAL.match(c) and not c.lstrip().startswith("- "):
                    problems.append(f"line {lineno}: special comment ({c.split(',')[0]}...) "
                                    f"would be executed")
            code_s = "".join(code).strip().upper()
            if not code_s:
                continue
            last_code = code_s
            ws, bad = words(code_s)
            for tok in bad:
                problems.append(f"line {lineno}: cannot read word {tok!r}")
            values = {}
            gcodes = []
            for a, eq, v in ws:
                if eq:
                    problems.append(f"line {lineno}: '{a}=' is not LinuxCNC syntax")
                if not v:
                    problems.append(f"line {lineno}: address {a} without a value")
                    continue
                number = float(v)
                if not math.isfinite(number):
                    problems.append(f"line {lineno}: {a} is not finite")
                if a == "G":
                    gcodes.append(v)
                else:
                    values[a] = number
                if a == "F" and not number > 0:
                    problems.append(f"line {lineno}: F{v}; a feed must be > 0")
            gnums = [float(g) for g in gcodes]
            if 21.0 in gnums:
                seen_g21 = True
            if 94.0 in gnums:
                seen_g94 = True
            if 93.0 in gnums:
                inverse_time = True
            if 94.0 in gnums:
                inverse_time = False
            if inverse_time and any(a in values for a in "XYZABC") and "F" not in values:
                problems.append(f"line {lineno}: a move under G93 (inverse time) needs its F word")
            if 20.0 in gnums:
                problems.append(f"line {lineno}: G20 (inch) found; programs are metric (G21)")
            if any(g in (5.1, 5.2, 5.3) for g in gnums):
                problems.append(f"line {lineno}: G5.x NURBS ignore Z in LinuxCNC; use 3-D chords")
            if 4.0 in gnums:
                if not (len(ws) == 2 and ws[1][0] == "P" and values.get("P", 0) > 0):
                    problems.append(f"line {lineno}: dwell must be 'G4 P<seconds>' alone in its "
                                    f"block, got {code_s!r}")
            if 64.0 in gnums and not values.get("P", 0) > 0:
                problems.append(f"line {lineno}: G64 needs a positive P tolerance")
            for axis, (lo, hi) in travel_mm.items():
                if axis in values and not lo <= values[axis] <= hi:
                    problems.append(f"line {lineno}: {axis}{values[axis]:g} outside the travel "
                                    f"[{lo:g}, {hi:g}] mm")
        if not seen_g21:
            problems.append("preamble: G21 (mm) missing")
        if not seen_g94:
            problems.append("preamble: G94 (feed per minute) missing")
        if last_code not in ("M2", "M30", "M02"):
            problems.append(f"end: the last block must be M2 or M30, got {last_code!r}")
        return problems

