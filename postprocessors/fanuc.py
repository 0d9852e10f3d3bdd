"""FANUC Series 0i-F / 30i (milling): 3-D ``G01`` chords under AI contour control.

Facts relied on, and where they come from ([doc] a FANUC manual or a manual of a
FANUC-compatible dialect, [src] a public post-processor, [assumed] not confirmed):

- A file is ``%``, the program number ``O0001`` with its name in parentheses, the
  blocks, ``M30``, ``%`` [doc: FANUC 30i-A Fast Data Server B-64014EN/03 2.5; the
  Autodesk ``fanuc.cps`` post].  Program numbers are 1-9999; O8000-O9999 are often the
  builder's: we number from ``O1001`` in the plan's order [src: ``fanuc.cps``].
- A file reader drops lower-case letters and some special characters [doc: 16i
  B-63524EN/01, memory-card format]: everything is upper case, comments keep
  ``A-Z 0-9 . , = _ + - / :`` and spaces, at most 80 characters a line [src].
- A number without a decimal point is read in least input increments: every axis and
  feed word carries its point [doc: FANUC manuals, input with a decimal point].
- Coordinates with 4 decimals: the increment system IS-C (0.0001 mm), an option on
  most controls (IS-B, 0.001 mm, is standard): set ``post.decimals = 3`` for IS-B,
  with a chord tolerance that holds it [assumed: the machine's increment system].
- ``G05.1 Q1`` switches AI contour control (look-ahead, its corner and acceleration
  control from the builder's parameters) on, ``G05.1 Q0`` off, before ``M30``; no
  tolerance word exists for it [src: ``fanuc.cps``]; an M code or M00 empties its
  buffer [doc: AI nano contour control A-78962EN 7.1].  Whether ``G04`` keeps it on
  is not documented: a dwell stops the machine anyway [assumed].
- ``G04 X2.`` dwells 2 s, alone in its block (``G04 P`` counts milliseconds and takes
  no decimal point) [doc: SINUMERIK ISO dialect (FANUC-compatible) 3.3.1].
- ``G93`` inverse time, ``F`` on every block, for the 5-axis programs in machine
  axis values (B, C in degrees) [src: ``fanuc.cps``]; it is an option on some
  controls [assumed].
- The tool length offset of the ballbar cup is the operator's (``G43 H..`` active, as
  the program's header says); the program never cancels it (no ``G49``).
"""

from __future__ import annotations

from sdit_path.nc.iso import Dialect, chord_body, comment_lines, lint_iso
from sdit_path.nc.program import Program

_DIALECT = Dialect(dwell_word="X", dwell_decimal=True)
#: the first program number (O1001, O1002, ... in the plan's order)
FIRST_NUMBER = 1000


def frame_iso(program: Program, preamble: list[str], body: list[str], footer: list[str],
              o_digits: int, assumed: list[str]) -> str:
    """``%``, the O number and name, the header as comments, the blocks, ``M30``, ``%``."""
    lines = ["%", f"O{FIRST_NUMBER + program.number:0{o_digits}d} ({program.name})"]
    for line in (*program.header, *assumed):
        lines += comment_lines(line)
    lines += preamble + body + footer
    lines += comment_lines(f"end of {program.name}") + ["M30", "%"]
    return "\n".join(lines) + "\n"


def offset_word(program: Program) -> tuple[str, list[str]]:
    """The work offset block and what the header says when there is none."""
    if program.work_offset.startswith("G5") and program.work_offset != "G500":
        return program.work_offset, []
    return "G54", [f"work offset {program.work_offset} has no equivalent here: run with a "
                   f"zero G54 offset for machine coordinates"]


class Fanuc:
    name = "fanuc"
    title = "FANUC 0i-F / 30i (G01 chords, AI contour control)"
    short = "FANUC"
    extension = ".nc"
    path_form = "chords"
    corners = None  # the corner control is the builder's parameters: not modelled
    max_decimals = 4

    def render(self, program: Program) -> str:
        offset, note = offset_word(program)
        preamble = ["G17 G21 G40 G80 G90 G94", offset, "M05",
                    "G05.1 Q1"]
        assumed = note + ["AI contour control G05.1 Q1 on: its corner tolerance is the "
                          "machine builder's parameters", "dwells G04 X in seconds"]
        body = chord_body(program.items, program.decimals, _DIALECT)
        return frame_iso(program, preamble, body, ["G05.1 Q0"], 4, assumed)

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]:
        aicc = {"on": False}

        def dwell_ok(ws, values):
            if not (len(ws) == 2 and ws[1][0] == "X" and values.get("X", 0) > 0):
                return "dwell must be 'G04 X<seconds>.' alone in its block"
            return None

        def extra(lineno, gnums, values, code):
            out = []
            if 5.1 in gnums:
                aicc["on"] = values.get("Q") == 1.0
            if code in ("M30", "M02") and aicc["on"]:
                out.append(f"line {lineno}: AI contour control still on at the program end; "
                           f"G05.1 Q0 first")
            if 49.0 in gnums:
                out.append(f"line {lineno}: G49 cancels the ballbar cup's length offset")
            return out

        return lint_iso(text, travel_mm, dwell_ok, extra)
