"""The model of LinuxCNC 2.9's motion planner (``timing.control = "linuxcnc"``) on
programs whose motion follows from first principles, and the plan it times.  Against
the real control: ``tests/nc/test_linuxcnc_control.py`` and
``validation/linuxcnc_tp_check.py``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sdit_path.config import parse_config
from sdit_path.plan.pipeline import plan
from sdit_path.timing.linuxcnc_tp import ControlLimits, simulate, stretches
from sdit_path.timing.trajectory import TimedDwell, TimedRun, Timer, sample

ROOT = Path(__file__).resolve().parents[2]
XYZ = ControlLimits(("X", "Y", "Z"), (100.0, 100.0, 100.0), (500.0, 500.0, 500.0))


def test_a_straight_move_from_rest_to_rest_is_a_trapezoid():
    """100 mm at F600 (10 mm/s) under 500 mm/s^2 in G64: a trapezoid at half the
    acceleration (2.9 keeps the other half for a parabolic blend with a next segment,
    ``tpGetScaledAccel``), 10 s at the feed plus one ramp's worth, v/(a/2) = 40 ms; the
    feed reached and never exceeded."""
    (st,) = stretches("G21 G90 G94 G64 P0.001 Q0\nG1 X0 Y0 Z0 F600\nG1 X100\nM2\n", XYZ.axes)
    sim = simulate(st, XYZ)
    assert sim.duration_s == pytest.approx(10.0 + 10.0 / 250.0, abs=0.003)
    x = np.r_[0.0, sim.position[:, 0]]
    v = np.diff(x) / 1e-3
    a = np.diff(v) / 1e-3
    assert v.max() == pytest.approx(10.0, rel=1e-9)
    assert np.abs(a).max() <= 250.0 * (1 + 1e-6)
    assert x[-1] == pytest.approx(100.0, abs=1e-12)


def test_inverse_time_blocks_with_rotary_motion_stop_at_their_ends():
    """LinuxCNC 2.9 blends no segment that moves a rotary axis tangentially: every such
    block is planned to be able to stop at its end, so a block too short to reach its
    speed runs a triangle.  A C turn of 10 blocks of 1 deg, each asked to take 10 ms
    (G93 F6000), under 400 deg/s^2 takes at least 2 sqrt(1/400) s = 100 ms each when
    alone; blended parabolically it may overlap but never beats the time to cover the
    whole turn when each block must be stoppable: the control is far slower than the
    100 ms the program asks for."""
    lim = ControlLimits(("X", "C"), (100.0, 360.0), (500.0, 400.0))
    text = "G21 G90 G64 P0.001 Q0\nG1 X0 C0 F600\nG93\n" + "".join(
        f"G1 C{k} F6000\n" for k in range(1, 11)) + "G94\nM2\n"
    (st,) = stretches(text, lim.axes)
    sim = simulate(st, lim)
    asked = 10 * 0.01
    assert sim.duration_s > 3 * asked
    c = np.r_[0.0, sim.position[:, 1]]
    w = np.diff(c) / 1e-3
    assert np.abs(np.diff(w) / 1e-3).max() <= 400.0 * (1 + 1e-9)
    assert c[-1] == pytest.approx(10.0, abs=1e-9)


def test_the_program_is_read_as_the_control_reads_it_and_refused_where_not_modelled():
    text = ("G21 G90 G94 G64 P0.001 Q0\nG1 X0 Y0 Z0 F600\nG4 P2\nG1 X1\nX2\nM0\nG1 Y1\nG4 P2\n"
            "G1 Z1\nM2\n")
    found = stretches(text, XYZ.axes)
    assert [(s.first_line, s.last_line, s.dwell_after_s) for s in found] == \
        [(4, 5, 0.0), (7, 7, 2.0), (9, 9, 0.0)]
    # the operator's way to the bar and back, outside the comments that frame the test
    (st,) = stretches("G21 G90 G94\nG1 Z9 F2000\nG1 X5 Y5 Z9\nG1 X0 Y0 Z0\nM0\n"
                      "(The test begins here)\nG1 X0 Y0 Z0 F600\nG4 P2\nG1 X1\nG4 P2\n"
                      "(THE TEST ENDS HERE)\nM0\nG1 Z9 F2000\nM2\n", XYZ.axes)
    assert (st.first_line, st.last_line, st.dwell_after_s) == (9, 9, 2.0)
    assert list(st.start) == [0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"line 3: G0 rapid"):
        stretches("G21 G90\nG1 X0 F600\nG0 X5\n", XYZ.axes)
    with pytest.raises(ValueError, match=r"line 2: .*A"):
        stretches("G21 G90\nG1 X0 A5 F600\n", XYZ.axes)


@pytest.fixture(scope="module")
def modelled():
    text = (ROOT / "tests" / "data" / "golden_small.toml").read_text(encoding="utf-8")
    text = text.replace('controllers = ["sinumerik840d", "linuxcnc"]', 'controllers = ["linuxcnc"]')
    cfg = parse_config(text + '\n[timing]\ncontrol = "linuxcnc"\n', "golden_small.toml")
    return plan(cfg)


def test_a_linuxcnc_timed_plan_runs_as_the_model_runs_its_program(modelled):
    """Every run of a plan timed with ``timing.control = "linuxcnc"`` lasts as long as
    the model's stretch of the program, the dwells as written; the ball stays on the
    planned curve at the control's pace; the feed is never
    exceeded."""
    cfg = modelled.config
    limits = ControlLimits.from_machine(cfg.machine, ("X", "Y", "Z"))
    for lp in modelled.layers:
        prog = next(p for p in modelled.programs if p.layer == lp.path.layer)
        found = [simulate(s, limits) for s in stretches(prog.text, limits.axes)]
        runs = [i for i in lp.timed.items if isinstance(i, TimedRun)]
        assert len(runs) == len(found)
        for run, sim in zip(runs, found):
            assert run.profile.duration_s == pytest.approx(sim.duration_s, abs=1e-12)
        dwells = sum(i.duration_s for i in lp.timed.items if isinstance(i, TimedDwell))
        assert lp.timed.duration_s == pytest.approx(
            dwells + sum(s.duration_s for s in found), abs=1e-9)
        smp = sample(lp.timed, Timer(cfg), 1000.0)
        r = np.linalg.norm(smp.ball_mm - np.array(cfg.ballbar.pivot_mm), axis=1)
        # on the planned curves: within their fit's tolerance of the sphere
        assert np.abs(r - cfg.ballbar.bar_length_mm).max() <= cfg.post.spline_tolerance_um * 1e-3
        feed = cfg.test.feed_mm_per_min / 60.0
        assert smp.speed_mm_per_s.max() <= feed * (1 + 1e-3)
        assert math.isclose(smp.t_s[-1], round(lp.timed.duration_s, 3), abs_tol=1.5e-3)


@pytest.mark.slow
def test_program_stops_and_passes_that_turn_back_are_timed_as_the_control_runs_them():
    """With segments left out (``--skip-infeasible`` on the collision sample) a layer has
    program stops around each repositioning and passes that turn back without a dwell:
    the stretches of the program, run through the model, are the plan's motion."""
    text = (ROOT / "samples" / "vmc_3axis_collision.toml").read_text(encoding="utf-8")
    text = text.replace('controllers = ["sinumerik840d", "linuxcnc"]', 'controllers = ["linuxcnc"]')
    cfg = parse_config(text + '\n[timing]\ncontrol = "linuxcnc"\n', "vmc_3axis_collision.toml")
    result = plan(cfg, skip_infeasible=True)
    limits = ControlLimits.from_machine(cfg.machine, ("X", "Y", "Z"))
    stops = 0
    for lp in result.layers:
        prog = next(p for p in result.programs if p.layer == lp.path.layer)
        stops += prog.text.count("\nM0\n")
        found = [simulate(s, limits).duration_s for s in stretches(prog.text, limits.axes)]
        moving = sum(i.profile.duration_s for i in lp.timed.items
                     if not isinstance(i, TimedDwell))
        assert moving == pytest.approx(sum(found), abs=1e-9)
    assert stops > 0
