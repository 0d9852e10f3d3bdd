"""Haas NGC (mills and UMC): 3-D ``G01`` chords with ``G187`` smoothing.

Facts relied on ([doc] a Haas manual, [src] a public post-processor, [assumed] not
confirmed):

- A file is ``%``, ``O01001 (NAME)`` (five digits), the blocks, ``M30``, ``%``;
  comments ``( ... )``, at most 80 characters a line [src: Autodesk "haas next
  generation.cps", FreeCAD's Haas post].  Everything is upper case [src: FreeCAD's
  post: older controls read nothing else].
- ``G187 P3 E..`` selects the finishing smoothness with a corner tolerance ``E`` of
  0.001-2.5 mm; ``G187`` alone returns to the settings (85, 191); it stands on a line
  of its own [doc: Haas mill manual 96-8000, G187; Haas UK "Smooth operator"].  Our
  chords keep 0.1 um, below the smallest E: the program asks for E0.001 and says so.
- ``G04 P`` with a decimal point dwells seconds, without one milliseconds [doc: the
  Haas mill manual's G04 (its Polish edition)]: we write ``G04 P2.``.  FANUC reads
  ``P`` as milliseconds and refuses a decimal point, which is why the FANUC post
  writes ``G04 X2.``; both mean 2 s where each is written.
- A number without a decimal point is read in least input increments: every axis and
  feed word carries its point; 4 decimals of a millimetre [assumed: the control's
  0.0001 in resolution reads them; the public posts write 3].
- ``G93`` inverse time, ``F`` on every block, for the 5-axis programs in machine axis
  values [src: the Autodesk post's ``onLinear5D``].
- The tool length offset of the ballbar cup is the operator's (``G43 H..`` active);
  the program never cancels it.
"""

from __future__ import annotations

from sdit_path.nc.iso import Dialect, chord_body, lint_iso
from sdit_path.nc.program import Program

from .fanuc import frame_iso, offset_word

_DIALECT = Dialect(dwell_word="P", dwell_decimal=True)
#: the smallest corner tolerance G187 takes (mm)
SMALLEST_E_MM = 0.001


class Haas:
    name = "haas"
    title = "Haas NGC (G01 chords, G187 smoothing)"
    short = "Haas"
    extension = ".nc"
    path_form = "chords"
    corners = None
    max_decimals = 4

    def render(self, program: Program) -> str:
        offset, note = offset_word(program)
        e = max(program.tolerance_mm, SMALLEST_E_MM)
        preamble = ["G17 G21 G40 G80 G90 G94", offset, "M05", f"G187 P3 E{e:.3f}"]
        why = ("the smallest G187 takes, above the chord tolerance" if e > program.tolerance_mm
               else "the chord tolerance")
        assumed = note + [f"G187 P3 E{e:.3f}: finishing smoothness, corner tolerance {e:g} mm "
                          f"({why})", "dwells G04 P with a decimal point: seconds"]
        body = chord_body(program.items, program.decimals, _DIALECT)
        return frame_iso(program, preamble, body, ["G187"], 5, assumed)

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]:
        smooth = {"on": False}

        def dwell_ok(ws, values):
            if not (len(ws) == 2 and ws[1][0] == "P" and "." in ws[1][2]
                    and values.get("P", 0) > 0):
                return "dwell must be 'G04 P<seconds>.' (with its point) alone in its block"
            return None

        def extra(lineno, gnums, values, code):
            out = []
            if 187.0 in gnums:
                smooth["on"] = "P" in values
                if "E" in values and not 0.001 <= values["E"] <= 2.5:
                    out.append(f"line {lineno}: G187 E must be 0.001-2.5 mm")
            if code in ("M30", "M02") and smooth["on"]:
                out.append(f"line {lineno}: G187 smoothing still set at the program end; "
                           f"G187 alone first")
            if 49.0 in gnums:
                out.append(f"line {lineno}: G49 cancels the ballbar cup's length offset")
            return out

        return lint_iso(text, travel_mm, dwell_ok, extra)
