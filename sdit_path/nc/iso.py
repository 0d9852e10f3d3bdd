"""What the ISO-dialect posts (FANUC, Haas) share: comments, numbers with a decimal
point, the chord body and a lint.

Facts relied on (sources in each post's docstring): a program is framed by ``%`` lines
and begins with an ``O`` number; comments are ``( ... )``, never nested, and a file
reader may drop lower-case letters and some special characters, so comment text is
upper case from a small set; an axis or feed word without a decimal point is read in
least input increments (``X10`` is 0.01 mm at 0.001 mm), so every one is written with
its point; ``G93`` inverse time needs ``F`` on every move; ``M30`` ends the program.
"""

from __future__ import annotations

import math
import re
import textwrap
from dataclasses import dataclass

from .program import AxisMove, Comment, Dwell, LinearMove, PolylineMove, ProgramStop
from .text import neutralise
from .words import fixed, trimmed, words, xyz

#: characters a comment keeps (the rest become spaces): what the public FANUC and Haas
#: posts let through, upper case
_COMMENT_KEEP = re.compile(r"[^A-Z0-9 .,=_+\-/:]")
#: the line length the public posts keep to (no control's limit was found)
MAX_LINE_CHARS = 80


def comment_lines(text: str) -> list[str]:
    """User or header text as ``( ... )`` lines of at most :data:`MAX_LINE_CHARS`."""
    clean = _COMMENT_KEEP.sub(" ", neutralise(text).upper())
    clean = re.sub(r" {2,}", " ", clean).strip() or "-"
    return [f"({part})" for part in textwrap.wrap(clean, MAX_LINE_CHARS - 2)]


def number(value: float, decimals: int) -> str:
    """A word's number with its decimal point: ``600`` -> ``600.``, ``2.5`` -> ``2.5``."""
    text = trimmed(value, decimals)
    return text if "." in text else text + "."


def point_words(point_mm, rotary: tuple[tuple[str, float], ...], d: int) -> str:
    return xyz(point_mm, d) + "".join(f" {n}{fixed(v, d)}" for n, v in rotary)


@dataclass(frozen=True, slots=True)
class Dialect:
    """How one ISO control writes what differs: its dwell block (``dwell(seconds)``)."""

    dwell_word: str  # "X" (seconds) or "P"
    dwell_decimal: bool  # P2. (seconds, Haas) rather than P2000 (ms)

    def dwell(self, seconds: float) -> str:
        if self.dwell_word == "X" or self.dwell_decimal:
            return f"G04 {self.dwell_word}{number(seconds, 3)}"
        return f"G04 P{int(round(seconds * 1000))}"


def chord_body(items, d: int, dialect: Dialect) -> list[str]:
    """The program's items as ISO blocks: ``G01`` moves (``G93`` inverse time where the
    program gives it), dwells, stops with their message."""
    body: list[str] = []
    modal_feed = None
    for item in items:
        if isinstance(item, Comment):
            body += comment_lines(item.text)
        elif isinstance(item, LinearMove):
            rot = tuple(item.rotary_deg)
            body.append(f"G01 {point_words(item.point_mm, rot, d)} "
                        f"F{number(item.feed_mm_per_min, 3)}")
            modal_feed = item.feed_mm_per_min
        elif isinstance(item, AxisMove):
            ws = " ".join(f"{n}{fixed(v, d)}" for n, v in item.words)
            body.append(f"G01 {ws} F{number(item.feed_mm_per_min, 3)}")
            modal_feed = item.feed_mm_per_min
        elif isinstance(item, Dwell):
            body += comment_lines(f"dwell at node {item.node_id}")
            body.append(dialect.dwell(item.seconds))
        elif isinstance(item, PolylineMove):
            labels = dict(item.labels)
            inverse = item.inverse_time_per_min
            if inverse is not None:
                body += comment_lines("inverse time: every block's F is 1/minutes")
                body.append("G93")
            for j, p in enumerate(item.points_mm):
                if j in labels:
                    body += comment_lines(labels[j])
                line = point_words(p, tuple((n, v[j]) for n, v in item.rotary_deg), d)
                if inverse is not None:
                    line += f" F{number(inverse[j], 4)}"
                elif j == 0 and item.feed_mm_per_min != modal_feed:
                    line += f" F{number(item.feed_mm_per_min, 3)}"
                body.append(f"G01 {line}" if j == 0 else line)
            modal_feed = None if inverse is not None else item.feed_mm_per_min
            if inverse is not None:
                body.append("G94")
        elif isinstance(item, ProgramStop):
            body += comment_lines(f"STOP: {item.message}")
            body.append("M00")
        else:
            raise TypeError(f"an ISO chord program cannot carry {type(item).__name__}")
    return body


_AXES = "XYZABC"


def lint_iso(text: str, travel_mm: dict[str, tuple[float, float]], dwell_ok,
             extra=None) -> list[str]:
    """Problems of an ISO program: framing (``%``, ``O`` number, ``M30``), comments,
    words, decimal points, feeds, dwells (``dwell_ok(words, values) -> str | None``),
    inverse time, travel.  ``extra(lineno, gnums, values, code) -> list[str]`` adds a
    control's own rules."""
    problems: list[str] = []
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines = lines[:-1]
    if not lines or lines[0] != "%" or lines[-1] != "%":
        problems.append("framing: the first and the last line must be '%'")
    if len(lines) < 2 or not re.fullmatch(r"O\d{4,8}( \([^()]*\))?", lines[1]):
        problems.append("framing: the second line must be the program's O number")
    last_code = ""
    inverse_time = False
    seen_g21 = False
    for lineno, raw in enumerate(lines, start=1):
        if any(ord(ch) < 32 or ord(ch) > 126 for ch in raw):
            problems.append(f"line {lineno}: control or non-ASCII character")
        if len(raw) > MAX_LINE_CHARS:
            problems.append(f"line {lineno}: {len(raw)} characters; at most {MAX_LINE_CHARS}")
        if raw == "%" or lineno == 2:
            continue
        code, depth = [], 0
        for ch in raw:
            if ch == "(":
                if depth:
                    problems.append(f"line {lineno}: nested comment")
                depth += 1
            elif ch == ")":
                if not depth:
                    problems.append(f"line {lineno}: ')' without '('")
                depth = max(0, depth - 1)
            elif depth:
                if _COMMENT_KEEP.match(ch):
                    problems.append(f"line {lineno}: {ch!r} in a comment")
            else:
                code.append(ch)
        if depth:
            problems.append(f"line {lineno}: unclosed comment")
        code_s = "".join(code).strip()
        if not code_s:
            continue
        if code_s != code_s.upper():
            problems.append(f"line {lineno}: lower-case code")
        if "%" in code_s or ";" in code_s:
            problems.append(f"line {lineno}: '%' or ';' inside a block")
        last_code = code_s
        ws, bad = words(code_s)
        for tok in bad:
            problems.append(f"line {lineno}: cannot read word {tok!r}")
        values: dict[str, float] = {}
        gnums = []
        for a, eq, v in ws:
            if eq:
                problems.append(f"line {lineno}: '{a}=' is not ISO syntax")
            if not v:
                problems.append(f"line {lineno}: address {a} without a value")
                continue
            n = float(v)
            if not math.isfinite(n):
                problems.append(f"line {lineno}: {a} is not finite")
            if a == "G":
                gnums.append(n)
            else:
                values[a] = n
            if (a in _AXES or a in ("F", "K", "R")) and "." not in v:
                problems.append(f"line {lineno}: {a}{v} without a decimal point is read in "
                                f"least input increments")
            if a == "F" and not n > 0:
                problems.append(f"line {lineno}: F{v}; a feed must be > 0")
        if 21.0 in gnums:
            seen_g21 = True
        if 20.0 in gnums:
            problems.append(f"line {lineno}: G20 (inch) found; programs are metric (G21)")
        if 93.0 in gnums:
            inverse_time = True
        if 94.0 in gnums:
            inverse_time = False
        if inverse_time and any(a in values for a in _AXES) and "F" not in values:
            problems.append(f"line {lineno}: a move under G93 (inverse time) needs its F word")
        if 4.0 in gnums:
            why = dwell_ok(ws, values)
            if why:
                problems.append(f"line {lineno}: {why}, got {code_s!r}")
        for axis, (lo, hi) in travel_mm.items():
            if axis in values and not lo <= values[axis] <= hi:
                problems.append(f"line {lineno}: {axis}{values[axis]:g} outside the travel "
                                f"[{lo:g}, {hi:g}] mm")
        if extra is not None:
            problems += extra(lineno, gnums, values, code_s)
    if not seen_g21:
        problems.append("preamble: G21 (mm) missing")
    if last_code not in ("M30", "M02", "M2"):
        problems.append(f"end: the last block must be M30, got {last_code!r}")
    return problems
