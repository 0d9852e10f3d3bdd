"""HEIDENHAIN TNC (iTNC 530, TNC 640, TNC7) Klartext: ``L`` chords under cycle 32.

Facts relied on ([doc] a HEIDENHAIN manual, [src] a public post-processor, [assumed]
not confirmed):

- ``0 BEGIN PGM NAME MM`` first, ``N END PGM NAME MM`` last, blocks numbered in
  ascending order (we number every block, comments too, from 0 in steps of 1); names
  of ``A-Z a-z 0-9 _ - .`` [doc: TNC 620 user manual 10/2017 p.154; TNC 640 -05
  p.112].  A ``BLK FORM`` is needed only for the graphic test run: none is written
  [doc: TNC 426/430 ISO manual p.59].
- Comments ``;text`` on a block of their own [src: Autodesk ``heidenhain.cps``]; we
  keep printable ASCII without ``;`` and ``"``, at most 80 characters a line [src].
- ``L X+110.0000 Y-20.0000 Z+40.0000 R0 F1000`` a straight line; positions to 4
  decimals, signs always written [doc: TNC 640 input formats, +-99999.9999]; ``F`` in
  mm/min stays in force until changed [doc: TNC7 basic manual].
- ``CYCL DEF 32.0 TOLERANCE`` / ``CYCL DEF 32.1 T<mm>``: the path may leave the
  programmed chords by at most T; a ``32.1`` without a value returns to the machine
  builder's tolerance [doc: iTNC 530 cycles p.308 for T; src: ``heidenhain.cps`` for
  the block text and the reset].  T is written to 4 decimals, at least 0.0001 mm.
- ``CYCL DEF 9.0 DWELL TIME`` / ``CYCL DEF 9.1 DWELL 2``: seconds, 0-3600 with 3
  decimals [doc: TNC 640 input formats; src: the block text].  That cycles 9 and 32
  act where they are defined (no ``CYCL CALL``) [assumed: what every post relies on].
- A program stop: the operator's message as comments, then ``M0`` [doc: the M table,
  M0 stops the program, spindle and coolant off; src: ``heidenhain.cps``].  ``M30``
  before ``END PGM`` ends it [src].
- Five axes: ``FUNCTION TCPM F TCP AXIS POS PATHCTRL AXIS`` keeps the tool centre (the
  ball, the tool length running to its centre) on a straight line of the workpiece
  frame through every block while B and C, machine angles, move linearly, the feed
  being the ball's against the workpiece; ``FUNCTION RESET TCPM`` ends it [doc: TNC
  640 ISO manual p.400, TNC 620 p.576; src: the block text].  The ballbar cup's tool
  (its length to the ball centre) must be the active one: the operator's TOOL CALL
  [doc: M128 / TCPM use the active tool's length].
"""

from __future__ import annotations

import math
import re
import textwrap

from sdit_path.nc.program import (AxisMove, Comment, Dwell, LinearMove, PolylineMove,
                                  Program, ProgramStop)
from sdit_path.nc.text import neutralise
from sdit_path.nc.words import fixed, trimmed

MAX_LINE_CHARS = 80
_BLOCK = re.compile(r"^(\d+) (.*)$")
_NAME = re.compile(r"[A-Za-z0-9_.\-]+")


def _signed(value: float, d: int) -> str:
    text = fixed(value, d)
    return text if text.startswith("-") else "+" + text


def _words(point_mm, rotary, d: int) -> str:
    return " ".join(f"{a}{_signed(v, d)}" for a, v in
                    [*zip("XYZ", point_mm), *rotary])


def _comments(text: str) -> list[str]:
    clean = neutralise(text.replace(";", ","), forbidden='"').strip() or "-"
    return [f";{part}" for part in textwrap.wrap(clean, MAX_LINE_CHARS - 8)]


class Heidenhain:
    name = "heidenhain"
    title = "HEIDENHAIN TNC Klartext (L chords, cycle 32, TCPM on 5 axes)"
    short = "TNC"
    extension = ".h"
    path_form = "chords"
    corners = None
    max_decimals = 4
    five_axis = "tcpm"

    def render(self, program: Program) -> str:
        d = program.decimals
        body: list[str] = []
        feed = None
        for item in program.items:
            if isinstance(item, Comment):
                body += _comments(item.text)
            elif isinstance(item, LinearMove):
                body.append(f"L {_words(item.point_mm, item.rotary_deg, d)} R0 "
                            f"F{trimmed(item.feed_mm_per_min, 3)}")
                feed = item.feed_mm_per_min
            elif isinstance(item, AxisMove):
                ws = " ".join(f"{n}{_signed(v, d)}" for n, v in item.words)
                body.append(f"L {ws} R0 F{trimmed(item.feed_mm_per_min, 3)}")
                feed = item.feed_mm_per_min
            elif isinstance(item, Dwell):
                body += _comments(f"dwell at node {item.node_id}")
                body += ["CYCL DEF 9.0 DWELL TIME", f"CYCL DEF 9.1 DWELL {trimmed(item.seconds, 3)}"]
            elif isinstance(item, PolylineMove):
                if item.inverse_time_per_min is not None:
                    raise TypeError("Klartext has no inverse-time feed: a 5-axis program "
                                    "runs under TCPM")
                labels = dict(item.labels)
                for j, p in enumerate(item.points_mm):
                    if j in labels:
                        body += _comments(labels[j])
                    line = "L " + _words(p, tuple((n, v[j]) for n, v in item.rotary_deg), d)
                    if j == 0 and item.feed_mm_per_min != feed:
                        line += f" F{trimmed(item.feed_mm_per_min, 3)}"
                        feed = item.feed_mm_per_min
                    body.append(line)
            elif isinstance(item, ProgramStop):
                body += _comments(f"STOP: {item.message}")
                body.append("M0")
            else:
                raise TypeError(f"a Klartext chord program cannot carry {type(item).__name__}")
        t = max(math.ceil(program.tolerance_mm * 1e4 - 1e-9) / 1e4, 1e-4)
        head = []
        for line in program.header:
            head += _comments(line)
        head += _comments(f"cycle 32 T{t:.4f}: the path leaves the chords by at most {t:g} mm")
        offset = program.work_offset
        if offset != "G54":
            head += _comments(f"work offset {offset}: set the matching preset (datum) before "
                              f"the run")
        pre = ["CYCL DEF 32.0 TOLERANCE", f"CYCL DEF 32.1 T{t:.4f}"]
        post = ["CYCL DEF 32.0 TOLERANCE", "CYCL DEF 32.1"]
        if program.frame == "tcpm":
            pre.append("FUNCTION TCPM F TCP AXIS POS PATHCTRL AXIS")
            post.insert(0, "FUNCTION RESET TCPM")
        elif program.frame != "table":
            raise TypeError(f"Klartext programs are written in the table frame, not {program.frame}")
        blocks = [f"BEGIN PGM {program.name} MM", *head, *pre, *body, *post,
                  *_comments(f"end of {program.name}"), "M30", f"END PGM {program.name} MM"]
        return "\n".join(f"{k} {b}" for k, b in enumerate(blocks)) + "\n"

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]:
        problems: list[str] = []
        lines = text.split("\n")
        if lines and lines[-1] == "":
            lines = lines[:-1]
        expect = 0
        names = []
        tolerance_on = tcpm = False
        last = ""
        for lineno, raw in enumerate(lines, start=1):
            if any(ord(ch) < 32 or ord(ch) > 126 for ch in raw):
                problems.append(f"line {lineno}: control or non-ASCII character")
            if len(raw) > MAX_LINE_CHARS:
                problems.append(f"line {lineno}: {len(raw)} characters; at most {MAX_LINE_CHARS}")
            m = _BLOCK.match(raw)
            if not m:
                problems.append(f"line {lineno}: no block number")
                continue
            if int(m.group(1)) != expect:
                problems.append(f"line {lineno}: block {m.group(1)}, expected {expect}")
            expect = int(m.group(1)) + 1
            block = m.group(2)
            if block.startswith(";"):
                if '"' in block[1:] or ";" in block[1:]:
                    problems.append(f"line {lineno}: ';' or '\"' inside a comment")
                continue
            last = block
            for kw in ("BEGIN PGM", "END PGM"):
                if block.startswith(kw):
                    parts = block.split()
                    if len(parts) != 4 or parts[3] != "MM" or not _NAME.fullmatch(parts[2]):
                        problems.append(f"line {lineno}: expected '{kw} NAME MM', got {block!r}")
                    else:
                        names.append(parts[2])
            if block.startswith("CYCL DEF 32.1"):
                rest = block[len("CYCL DEF 32.1"):].strip()
                tolerance_on = bool(rest)
                if rest and not re.fullmatch(r"T\d+\.\d{1,4}", rest):
                    problems.append(f"line {lineno}: expected 'CYCL DEF 32.1 T<mm>', got {block!r}")
            if block.startswith("CYCL DEF 9.1"):
                if not re.fullmatch(r"CYCL DEF 9\.1 DWELL \d+(\.\d{1,3})?", block) or \
                        not float(block.split()[-1]) > 0:
                    problems.append(f"line {lineno}: expected 'CYCL DEF 9.1 DWELL <s>', got {block!r}")
            if block.startswith("FUNCTION TCPM"):
                tcpm = True
            if block == "FUNCTION RESET TCPM":
                tcpm = False
            if block.startswith("L "):
                problems += self._line(lineno, block, travel_mm)
        if not lines or not _BLOCK.match(lines[0]) or "BEGIN PGM" not in lines[0]:
            problems.append("framing: the first block must be BEGIN PGM NAME MM")
        if not lines or "END PGM" not in lines[-1]:
            problems.append("framing: the last block must be END PGM NAME MM")
        elif len(names) == 2 and names[0] != names[1]:
            problems.append(f"framing: BEGIN PGM {names[0]} ends as END PGM {names[1]}")
        if tolerance_on:
            problems.append("end: cycle 32's tolerance still set; reset it (CYCL DEF 32.1 alone)")
        if tcpm:
            problems.append("end: TCPM still on; FUNCTION RESET TCPM before the end")
        if not last.startswith("END PGM"):
            problems.append(f"end: the last block must be END PGM, got {last!r}")
        return problems

    @staticmethod
    def _line(lineno: int, block: str, travel_mm) -> list[str]:
        out = []
        for tok in block.split()[1:]:
            if tok in ("R0", "FMAX"):
                continue
            m = re.fullmatch(r"([XYZABC])([+-]\d+\.\d+)|F(\d+(\.\d+)?)|M(\d+)", tok)
            if not m:
                out.append(f"line {lineno}: cannot read {tok!r} (coordinates carry their sign "
                           f"and point)")
                continue
            if m.group(1):
                v = float(m.group(2))
                if not math.isfinite(v):
                    out.append(f"line {lineno}: {tok} is not finite")
                lim = travel_mm.get(m.group(1))
                if lim and not lim[0] <= v <= lim[1]:
                    out.append(f"line {lineno}: {m.group(1)}{v:g} outside the travel "
                               f"[{lim[0]:g}, {lim[1]:g}] mm")
            elif m.group(3) is not None and not float(m.group(3)) > 0:
                out.append(f"line {lineno}: F{m.group(3)}; a feed must be > 0")
        return out
