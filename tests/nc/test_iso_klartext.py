"""The FANUC, FANUC NURBS, Haas and HEIDENHAIN posts: golden files, lint rules, and the
read-back check (emit -> read back with our reader of that dialect -> on the sphere
within the stated tolerance, dwells at the nodes, feed words equal to the plan's)."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.config import parse_config, sample_path
from sdit_path.geometry.nurbs import radial_deviation
from sdit_path.machine.kinematics import Kinematics
from sdit_path.nc.chords import chord_deviation
from sdit_path.nc.readback import read_heidenhain, read_iso
from sdit_path.nc.registry import get_postprocessor
from sdit_path.plan.pipeline import plan

from conftest import DATA, GOLDEN

NEW = ("fanuc", "fanuc_nurbs", "haas", "heidenhain")
ALL = ("sinumerik840d", "linuxcnc") + NEW
TRAVEL = {"X": (-400.0, 400.0), "Y": (-250.0, 250.0), "Z": (-100.0, 450.0)}


def all_controllers(path, controllers=ALL) -> object:
    text = path.read_text()
    old = 'controllers = ["sinumerik840d", "linuxcnc"]'
    assert old in text
    return parse_config(text.replace(old, f"controllers = {list(controllers)!r}".replace("'", '"')),
                        str(path))


@pytest.fixture(scope="module")
def small_plan():
    return plan(all_controllers(DATA / "golden_small.toml"))


def read(controller: str, text: str):
    return read_heidenhain(text) if controller == "heidenhain" else read_iso(text)


def test_whole_program_golden(small_plan, regen_golden):
    for prog in small_plan.programs:
        if prog.controller not in NEW:
            continue
        golden = GOLDEN / prog.file.replace("/", "__")
        if regen_golden:
            golden.write_text(prog.text)
        assert prog.text == golden.read_text(), f"{golden} differs; rerun with --regen-golden " \
                                                f"and review the diff"


def test_the_existing_posts_are_unchanged_by_the_new_ones(small_plan):
    for prog in small_plan.programs:
        if prog.controller in ("sinumerik840d", "linuxcnc"):
            assert prog.text == (GOLDEN / prog.file.replace("/", "__")).read_text()


def check_read_back(result, controllers=NEW):
    """Every program of ``controllers`` read back: its poses (and splines) within the
    program's stated tolerance of the sphere, its dwells where the plan dwells, its
    feed words the plan's."""
    cfg, hemi = result.config, result.hemisphere
    kin = Kinematics(cfg.machine)
    c, radius = hemi.centre_mm, hemi.radius_mm
    for prog in result.programs:
        if prog.controller not in controllers:
            continue
        program = prog.built.program
        got = read(prog.controller, prog.text)
        # the first move raises Z alone from where the machine stands (X, Y unknown)
        assert not np.isnan(got.points[1:]).any(), prog.file
        tol = program.tolerance_mm
        if program.frame == "machine":
            q = np.zeros((len(got.points), len(kin.names)))
            for col, name in enumerate(got.axes):
                v = got.points[:, col]
                q[:, kin.index[name]] = np.radians(v) if kin.axes[kin.index[name]].is_rotary else v
            ball = kin.forward(q)
        else:
            ball = got.points[:, :3]
        path = next(la.path for la in result.layers if la.path.layer == prog.layer)
        # the test: from its first dwell to its last (before and after, the operator's
        # way to the bar and back, off the sphere, at post.approach_feed_mm_per_min)
        test = got.test
        first, last = test.start, test.stop - 1
        assert set(np.round(got.feeds[:first], 6)) == {cfg.post.approach_feed_mm_per_min}
        assert set(np.round(got.feeds[last + 1:], 6)) == {cfg.post.approach_feed_mm_per_min}
        assert len(got.stops) >= 2, prog.file  # mount the bar, take it off
        # the test starts where it first dwells and ends at its last dwell
        assert np.array_equal(got.points[first], got.points[got.dwells[0][2]]), prog.file
        assert got.dwells[-1][2] == last, prog.file
        # the poses: every one on the sphere (the retreats of a remount aside)
        assert len(path.dwells) == len(got.dwells), prog.file
        on = np.abs(np.linalg.norm(ball[test] - c, axis=1) - radius)
        assert on.max() <= tol + 1e-9, (prog.file, on.max())
        if program.frame in ("table", "tcpm") and prog.controller != "fanuc_nurbs":
            sag = chord_deviation(ball[test][:-1], ball[test][1:], c, radius)
            assert sag.max() <= tol + 1e-9, (prog.file, sag.max())
        for _, curve, _ in got.splines:
            if program.frame == "table":
                u = np.linspace(*curve.domain, 4001)
                dev = np.abs(radial_deviation(curve, c, radius, u)).max()
                assert dev <= tol + 1e-9, (prog.file, dev)
        # dwells: as long as planned, at the nodes (within the grid's rounding)
        step = 10.0 ** (-program.decimals)
        for (_, seconds, at), dwell in zip(got.dwells, path.dwells):
            assert seconds == pytest.approx(dwell.seconds)
            node = hemi.node(dwell.node_id).position_mm
            assert np.linalg.norm(ball[at] - node) <= 3 * step + tol, (prog.file, dwell.node_id)
        # feeds: the plan's (inverse time where the program gives it per block)
        moves = slice(got.dwells[0][2], last + 1)  # the move to the start node on
        feeds = set(np.round(got.feeds[moves][~got.inverse_time[moves]], 6))
        planned = {cfg.test.feed_mm_per_min} | {f for _, f in cfg.test.sector_feeds(prog.layer)}
        assert feeds <= planned, (prog.file, feeds)
        assert not get_postprocessor(prog.controller).lint(prog.text, {})


def test_small_plan_reads_back_on_the_sphere(small_plan):
    check_read_back(small_plan)


def test_default_sample_reads_back_on_the_sphere():
    check_read_back(plan(all_controllers(sample_path("vmc_3axis.toml"), NEW)))


@pytest.mark.slow
def test_five_axis_sample_reads_back_on_the_sphere():
    """The 5-axis sample: FANUC and Haas in machine axes (G93), the FANUC NURBS as a
    machine-axis spline, HEIDENHAIN under TCPM in the table frame."""
    result = plan(all_controllers(sample_path("bc_table_5axis.toml"), NEW))
    frames = {p.controller: p.built.program.frame for p in result.programs}
    assert frames["heidenhain"] == "tcpm" and frames["fanuc"] == "machine"
    check_read_back(result, ("fanuc", "haas", "heidenhain"))
    text = next(p.text for p in result.programs if p.controller == "heidenhain")
    assert "FUNCTION TCPM F TCP AXIS POS PATHCTRL AXIS" in text and "FUNCTION RESET TCPM" in text


# ---------------------------------------------------------------------------- lint

FANUC = """%
O1001 (GOOD)
(A TINY PROGRAM)
G17 G21 G40 G80 G90 G94
G54
G05.1 Q1
G01 X10.0000 Y0.0000 Z50.0000 F600.
G04 X2.
(A1-1)
G01 X9.9000 Y1.0000 Z50.0000
X9.7000 Y2.0000 Z50.0000
(STOP: TAKE THE BAR OFF)
M00
G05.1 Q0
M30
%
"""


@pytest.mark.parametrize("old,new,expected", [
    ("X9.7000", "X9.7", None),
    ("X9.7000", "X97", "without a decimal point"),
    ("F600.", "F600", "without a decimal point"),
    ("G04 X2.", "G04 P2.", "dwell must be 'G04 X"),
    ("G04 X2.", "G04 X2. Y1.", "dwell must be 'G04 X"),
    ("G05.1 Q0\n", "", "AI contour control still on"),
    ("(A1-1)", "(A1-1 (NESTED))", "nested comment"),
    ("(A1-1)", "(a1-1)", "'a' in a comment"),
    ("(A1-1)", "(A1-1; G0 X0)", "';' in a comment"),
    ("X9.9000", "X999.9000", "outside the travel"),
    ("G17 G21", "G17 G20", "G20 (inch)"),
    ("G54\n", "G54\nG49\n", "G49 cancels"),
    ("M30\n%\n", "M30\n", "first and the last line"),
    ("O1001 (GOOD)", "(GOOD)", "O number"),
    ("G01 X9.9000", "g01 X9.9000", "lower-case"),
])
def test_fanuc_lint_rules(old, new, expected):
    post = get_postprocessor("fanuc")
    assert post.lint(FANUC, TRAVEL) == []
    bad = FANUC.replace(old, new, 1)
    assert bad != FANUC
    problems = post.lint(bad, TRAVEL)
    if expected is None:
        assert problems == []
    else:
        assert any(expected in p for p in problems), problems


def test_haas_reads_p_with_its_point_as_seconds_and_fanuc_refuses_it():
    haas = FANUC.replace("G05.1 Q1", "G187 P3 E0.001").replace("G05.1 Q0", "G187") \
        .replace("G04 X2.", "G04 P2.").replace("O1001", "O01001")
    assert get_postprocessor("haas").lint(haas, TRAVEL) == []
    assert read_iso(haas).dwells[0][1] == 2.0
    assert read_iso(haas.replace("G04 P2.", "G04 P2000")).dwells[0][1] == 2.0
    assert any("G04 P<seconds>." in p for p in get_postprocessor("haas").lint(
        haas.replace("G04 P2.", "G04 P2000"), TRAVEL))
    assert any("G187 smoothing still set" in p for p in get_postprocessor("haas").lint(
        haas.replace("G187\n", ""), TRAVEL))


NURBS = FANUC.replace("""(A1-1)
G01 X9.9000 Y1.0000 Z50.0000
X9.7000 Y2.0000 Z50.0000
""", """G06.2 P3 K0. X10.0000 Y0.0000 Z50.0000 F600.
K0. X10.0000 Y1.0000 Z50.0000
K0. X9.0000 Y2.0000 Z50.0000
K1.
K1.
K1.
G01 X9.0000 Y2.0000 Z50.0000
""")


@pytest.mark.parametrize("old,new,expected", [
    ("K1.\nK1.\nK1.\n", "K1.\nK1.\n", "not its rank"),
    ("K0. X9.0000", "K0.5 X9.0000", "knots must rise, the first and the last"),
    ("G06.2 P3", "G06.2 P5", "rank is 2-4"),
    ("K0. X10.0000 Y1.0000", "X10.0000 Y1.0000", "only K X Y Z"),
])
def test_fanuc_nurbs_lint_rules(old, new, expected):
    post = get_postprocessor("fanuc_nurbs")
    assert post.lint(NURBS, TRAVEL) == []
    got = read_iso(NURBS)
    assert len(got.splines) == 1 and got.splines[0][1].degree == 2
    problems = post.lint(NURBS.replace(old, new, 1), TRAVEL)
    assert any(expected in p for p in problems), problems


KLARTEXT = """0 BEGIN PGM GOOD MM
1 ;a tiny program
2 CYCL DEF 32.0 TOLERANCE
3 CYCL DEF 32.1 T0.0001
4 L X+10.0000 Y+0.0000 Z+50.0000 R0 F600
5 CYCL DEF 9.0 DWELL TIME
6 CYCL DEF 9.1 DWELL 2
7 L X+9.9000 Y+1.0000 Z+50.0000
8 ;STOP: take the bar off
9 M0
10 CYCL DEF 32.0 TOLERANCE
11 CYCL DEF 32.1
12 M30
13 END PGM GOOD MM
"""


@pytest.mark.parametrize("old,new,expected", [
    ("7 L X+9.9000", "8 L X+9.9000", "expected 7"),
    ("X+9.9000", "X9.9000", "carry their sign"),
    ("X+9.9000", "X+999.9000", "outside the travel"),
    ("DWELL 2\n", "DWELL 0\n", "CYCL DEF 9.1 DWELL <s>"),
    ("11 CYCL DEF 32.1\n", "11 ;reset\n", "cycle 32's tolerance still set"),
    ("13 END PGM GOOD MM", "13 END PGM OTHER MM", "ends as END PGM OTHER"),
    ("1 ;a tiny program", '1 ;a "tiny" program', "inside a comment"),
    ("4 L X+10.0000", "4 L X+10.0000 B+1.0000\n", "no block number"),
])
def test_heidenhain_lint_rules(old, new, expected):
    post = get_postprocessor("heidenhain")
    assert post.lint(KLARTEXT, TRAVEL) == []
    got = read_heidenhain(KLARTEXT)
    assert got.dwells[0][1] == 2.0 and got.stops == (10,)
    problems = post.lint(KLARTEXT.replace(old, new, 1), TRAVEL)
    assert any(expected in p for p in problems), problems


def test_user_text_never_becomes_a_block():
    text = (DATA / "golden_small.toml").read_text().replace(
        'controllers = ["sinumerik840d", "linuxcnc"]',
        'controllers = ["fanuc", "fanuc_nurbs", "haas", "heidenhain"]\n'
        'comment = "note\\nG0 X-999 Z-999\\u2028M0 ) (MSG, boom; G1 X0 %"')
    result = plan(parse_config(text, "hostile.toml"))
    for prog in result.programs:
        assert not get_postprocessor(prog.controller).lint(prog.text, {})
        for line in prog.text.splitlines():
            code = line.lstrip("0123456789 ")
            if "X-999" in line or "MSG" in line:
                assert code.startswith((";", "(")), line
