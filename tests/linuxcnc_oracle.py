"""The LinuxCNC interpreter (Debian's ``linuxcnc-uspace``) as an independent oracle.

Its Python module ``gcode`` parses a program exactly as LinuxCNC does and reports
every canonical move through callbacks, in inches, as doubles.  It rewrites the
parameter file it is given, so it gets a fresh temporary one.
"""

from __future__ import annotations

import os
import sys
import tempfile
from dataclasses import dataclass, field

from sdit_path.program_marks import TEST_BEGINS, TEST_ENDS

DIST = "/usr/lib/python3/dist-packages"


def load_gcode():
    if DIST not in sys.path:
        sys.path.append(DIST)
    import gcode  # noqa: PLC0415

    return gcode


@dataclass
class Recorder:
    parameter_file: str
    feeds: list = field(default_factory=list)
    traverses: list = field(default_factory=list)
    dwells: list = field(default_factory=list)
    arcs: list = field(default_factory=list)
    rates: list = field(default_factory=list)  # (line, mm/min) as each F takes effect
    messages: list = field(default_factory=list)
    comments: list = field(default_factory=list)
    line: int = 0

    def __getattr__(self, name):  # every other canonical call is accepted and ignored
        if name.startswith("__"):
            raise AttributeError(name)
        return lambda *a, **k: None

    @property
    def test_feeds(self) -> list:
        """The feeds of the test: from the pose it starts at (the last feed before the
        comment that begins it) to the comment that ends it; the operator's way to the
        bar and back is left out (a program without those comments: every feed)."""
        marks = {text.strip().lower(): line for line, text in self.comments}
        first = marks.get(TEST_BEGINS)
        last = marks.get(TEST_ENDS, 1 << 30)
        if first is None:
            return self.feeds
        before = [f for f in self.feeds if f[0] < first]
        return before[-1:] + [f for f in self.feeds if first < f[0] < last]

    def comment(self, text):
        self.comments.append((self.line, text))

    def next_line(self, state):
        self.line = state.sequence_number

    def straight_feed(self, *a):
        # x y z in inches; a b c in degrees
        self.feeds.append((self.line, a[0] * 25.4, a[1] * 25.4, a[2] * 25.4, a[3], a[4], a[5]))

    def straight_traverse(self, *a):
        self.traverses.append((self.line, a[0] * 25.4, a[1] * 25.4, a[2] * 25.4))

    def arc_feed(self, *a):
        self.arcs.append((self.line,) + a)

    def message(self, text):  # (MSG, ...) and the like reach the operator's screen
        self.messages.append((self.line, text))

    def dwell(self, seconds):
        self.dwells.append((self.line, seconds))

    def set_feed_rate(self, rate):  # inches per minute (0 in inverse-time mode)
        self.rates.append((self.line, rate * 25.4))

    def get_external_length_units(self):
        return 1.0 / 25.4

    def get_external_angular_units(self):
        return 1.0

    def get_axis_mask(self):
        return 1 | 2 | 4 | 8 | 16 | 32  # X Y Z A B C

    def get_block_delete(self):
        return 0

    def get_tool(self, idx):
        return (-1, 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0)


def interpret(path: str) -> tuple[int, str, Recorder]:
    """Run the interpreter on ``path``; return (result code, message, recorder)."""
    gcode = load_gcode()
    with tempfile.TemporaryDirectory() as tmp:
        var = os.path.join(tmp, "sdit.var")
        open(var, "w").close()
        rec = Recorder(var)
        result, _ = gcode.parse(path, rec, "", "")
        message = gcode.strerror(result) if result > gcode.MIN_ERROR else ""
    return result, message, rec


def ok(result: int) -> bool:
    return result <= load_gcode().MIN_ERROR
