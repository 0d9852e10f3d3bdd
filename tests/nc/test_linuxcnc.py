from __future__ import annotations

import os

import numpy as np
import pytest

from sdit_path.nc.chords import chord_deviation
from sdit_path.nc.registry import get_postprocessor

from conftest import have_linuxcnc

POST = get_postprocessor("linuxcnc")
TRAVEL = {"X": (-400.0, 400.0), "Y": (-250.0, 250.0), "Z": (-100.0, 450.0)}

GOOD = """%
(tiny)
G21 G17 G90 G94 G40
G54
G64 P0.0001 Q0
G1 X10.000000 Y0.000000 Z50.000000 F600
G4 P2
G1 X9.9 Y1.0 Z50.0
X9.8 Y2.0 Z50.0
M2
%
"""


def test_good_program_lints_clean():
    assert POST.lint(GOOD, TRAVEL) == []


@pytest.mark.parametrize("old,new,expected", [
    ("G4 P2", "G4 P2 X1", "alone in its block"),
    ("G4 P2", "G4 F2", "alone in its block"),
    ("X9.8 Y2.0", "G5.2 X9.8 Y2.0", "G5.x NURBS ignore Z"),
    ("(tiny)", "(tiny (nested))", "nested comment"),
    ("(tiny)", "(MSG, hello)", "special comment"),
    ("X9.8 Y2.0", "X9.8 Y999.0", "outside the travel"),
    ("M2\n", "G0 X0\n", "last block must be M2 or M30"),
    ("G21", "G20", "G20 (inch)"),
    ("G64 P0.0001", "G64 P0", "positive P tolerance"),
    ("X9.8 Y2.0", "X=9.8 Y2.0", "not LinuxCNC syntax"),
])
def test_each_rule_catches_its_fault(old, new, expected):
    bad = GOOD.replace(old, new, 1)
    assert bad != GOOD
    problems = POST.lint(bad, TRAVEL)
    assert any(expected in p for p in problems), problems


def _require_interpreter():
    if not have_linuxcnc():
        if os.environ.get("CI"):
            pytest.fail("Debian's linuxcnc-uspace is not installed: .ci/run must install it")
        pytest.skip("LinuxCNC interpreter (linuxcnc-uspace) not installed")


@pytest.mark.oracle
def test_bundled_programs_pass_the_real_interpreter(default_plan, tmp_path):
    """Every LinuxCNC layer program runs in LinuxCNC's own interpreter without error;
    every point it reports, and every chord between them, lies on the sphere within
    the stated tolerance; it dwells 2 s at the static nodes of the plan."""
    _require_interpreter()
    from linuxcnc_oracle import interpret, ok

    h = default_plan.hemisphere
    tol = default_plan.config.post.chord_tolerance_um * 1e-3
    progs = [p for p in default_plan.programs if p.controller == "linuxcnc"]
    assert [p.layer for p in progs] == list("ABCDE")
    for prog in progs:
        f = tmp_path / prog.file.replace("/", "_")
        f.write_text(prog.text)
        result, message, rec = interpret(str(f))
        assert ok(result), f"{prog.file}: interpreter error: {message}"
        assert not rec.traverses and not rec.arcs
        p = np.array([x[1:4] for x in rec.feeds])
        assert len(p) > 1000
        r = np.linalg.norm(p - h.centre_mm, axis=1) - h.radius_mm
        assert np.abs(r).max() <= tol
        assert chord_deviation(p[:-1], p[1:], h.centre_mm, h.radius_mm).max() <= tol
        path = next(x for x in default_plan.paths if x.layer == prog.layer)
        assert [s for _, s in rec.dwells] == [2.0] * len(path.dwells)
        # the machine is at the dwell's node when it dwells
        node_pos = {n.id: n.position_mm for n in h.nodes}
        feed_lines = np.array([x[0] for x in rec.feeds])
        for (line, _), d in zip(rec.dwells, path.dwells):
            before = p[np.searchsorted(feed_lines, line) - 1]
            assert np.abs(before - node_pos[d.node_id]).max() < 2e-6


@pytest.mark.oracle
def test_interpreter_rejects_a_broken_program(tmp_path):
    """The oracle can fail: a program with an error is reported as one."""
    _require_interpreter()
    from linuxcnc_oracle import interpret, ok

    f = tmp_path / "bad.ngc"
    f.write_text(GOOD.replace("G4 P2", "G4"))
    result, message, _ = interpret(str(f))
    assert not ok(result) and message
