from __future__ import annotations


import numpy as np
import pytest

from sdit_path.config import load_config
from sdit_path.nc.readback import read_sinumerik
from sdit_path.nc.registry import get_postprocessor
from sdit_path.plan.pipeline import plan

from conftest import DATA, GOLDEN

POST = get_postprocessor("sinumerik840d")
TRAVEL = {"X": (-400.0, 400.0), "Y": (-250.0, 250.0), "Z": (-100.0, 450.0)}

GOOD = """; tiny
G17 G90 G71 G94 G40 G54
M5
G1 X10.000000 Y0.000000 Z50.000000 F600
G4 F2
BSPLINE SD=3 X10.0 Y1.0 Z50.0 PL=1.5 F600
X9.9 Y2.0 Z50.0 PL=1.5
; A1-2
X9.7 Y3.0 Z50.0 PL=1.5
X9.4 Y4.0 Z50.0 PL=1.5
G1
G4 F2
M30
"""


def lint(text: str) -> list[str]:
    return POST.lint(text, TRAVEL)


def test_good_program_lints_clean():
    assert lint(GOOD) == []


@pytest.mark.parametrize("old,new,expected", [
    ("SD=3", "SD=4", "degree must be 2 or 3"),
    ("Z50.0 PL=1.5 F600", "Z50.0 PL=1.5 PW=3.5 F600", "weights must lie in 0..3"),
    ("Z50.0 PL=1.5 F600", "Z50.0 PL=1.5 PW=0.12345 F600", "at most 4 decimals"),
    ("X9.9 Y2.0 Z50.0 PL=1.5", "X9.9 Y2.0 Z50.0 PL=1.6", "knot intervals differ"),
    ("G4 F2\nBSPLINE", "G4 F2 X3\nBSPLINE", "alone in its block"),
    ("G4 F2\nBSPLINE", "G4 S2\nBSPLINE", "alone in its block"),
    ("X9.9 Y2.0", "Xnan Y2.0", "cannot read word 'XNAN'"),
    ("X9.9 Y2.0", "X999.9 Y2.0", "outside the travel"),
    ("M30\n", "M2\n", "last block must be M30"),
    ("G94", "G95", "G94 (feed in mm/min) missing"),
    ("; A1-2", "; A1-2\x0bG0 X0", "control or non-ASCII"),
])
def test_each_rule_catches_its_fault(old, new, expected):
    bad = GOOD.replace(old, new.replace("Xnan", "XNAN"), 1)
    assert bad != GOOD
    assert any(expected in p for p in lint(bad)), lint(bad)


def test_spline_block_density_rule():
    filler = "\n".join(["; note"] * 6)
    bad = GOOD.replace("; A1-2", filler + "\nX9.8 Y2.5 Z50.0 PL=1.5\n" + filler)
    problems = lint(bad)
    assert any("spline blocks (>= 6 needed)" in p for p in problems), problems


def test_whole_program_golden(regen_golden):
    result = plan(load_config(DATA / "golden_small.toml"))
    for prog in result.programs:
        golden = GOLDEN / prog.file.replace("/", "__")
        if regen_golden:
            golden.write_text(prog.text)
        assert prog.text == golden.read_text(), f"{golden} differs; rerun with --regen-golden " \
                                                f"only if the change is intended"


def test_default_programs_round_trip_on_the_sphere(default_plan):
    """Read every 840D program back from its words and evaluate it as the control
    would: radial deviation <= 0.01 um everywhere, dwell 2 s at every static node."""
    h = default_plan.hemisphere
    progs = [p for p in default_plan.programs if p.controller == "sinumerik840d"]
    assert [p.layer for p in progs] == list("ABCDE")
    node_pos = {n.id: n.position_mm for n in h.nodes}
    worst = 0.0
    for prog in progs:
        read = read_sinumerik(prog.text)
        assert len(read.splines) == len(next(x for x in default_plan.paths
                                             if x.layer == prog.layer).runs)
        for curve in read.splines:
            u = np.linspace(*curve.domain, 40 * (len(curve.control_points_mm)))
            r = np.linalg.norm(curve.evaluate(u) - h.centre_mm, axis=1) - h.radius_mm
            worst = max(worst, float(np.abs(r).max()))
        # every dwell: G4 F2 at a static node, and every lower-track node is visited
        path = next(x for x in default_plan.paths if x.layer == prog.layer)
        assert len(read.dwells) == len(path.dwells)
        for (_, seconds, xyz), d in zip(read.dwells, path.dwells):
            assert seconds == 2.0
            assert np.abs(np.array(xyz) - node_pos[d.node_id]).max() < 1e-6
        visited = {d.node_id for d in path.dwells}
        assert {f"{prog.layer}-{k}" for k in range(1, 7)} <= visited
        reported = prog.built.max_deviation_mm
        assert reported <= 1e-5
    assert worst <= 1e-5
    assert "TOP" in {d.node_id for d in default_plan.paths[-1].dwells}
    every = {d.node_id for path in default_plan.paths for d in path.dwells}
    assert every == set(node_pos), set(node_pos) - every


def test_dwell_blocks_are_alone_and_feed_is_g94(default_plan):
    for prog in default_plan.programs:
        if prog.controller != "sinumerik840d":
            continue
        lines = prog.text.splitlines()
        assert "G17 G90 G71 G94 G40 G54" in lines
        assert lines[-1] == "M30"
        dwells = [l for l in lines if l.startswith("G4")]
        assert dwells and all(l == "G4 F2" for l in dwells)
        assert all(("F600" in l) for l in lines if l.startswith("BSPLINE"))


def test_segment_ids_in_comments(default_plan):
    text = next(p.text for p in default_plan.programs
                if p.controller == "sinumerik840d" and p.layer == "D")
    comments = [l[2:] for l in text.splitlines() if l.startswith("; D")]
    assert comments[:18] == [f"D{s}-{k}" for s in range(1, 7) for k in range(1, 4)]
    assert comments[18:36] == [f"D{s}-{k}" for s in range(6, 0, -1) for k in range(3, 0, -1)]
