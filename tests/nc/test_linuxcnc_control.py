"""A program of ours run on LinuxCNC itself: Debian's linuxcnc-uspace, its interpreter,
trajectory planner and motion controller, headless (``validation/linuxcnc_run.py``),
sampled every 1 ms servo period and compared run by run with our plan.  The whole
layers of both samples run as a campaign (``docs/validation/``)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sdit_path.config import load_config
from sdit_path.plan.files import load_plan

pytestmark = [pytest.mark.oracle, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "validation"))


@pytest.mark.skipif(shutil.which("linuxcnc") is None, reason="Debian's linuxcnc-uspace")
def test_the_real_control_runs_a_small_plan_as_planned(tmp_path):
    """The first five stretches of GOLD_B of the small test plan (three transits and two
    sector passes, half a minute on the control), against both timings of the plan.
    Our jerk-limited plan: every dwell where the program has one, every run within
    1.5 % of its planned duration (LinuxCNC 2.9 has no jerk limit, so its ramps are a
    little shorter), the feed held between the ramps (its corners are rounded within
    G64 P, not slowed), the commanded path within the chord tolerance of the sphere and
    the curve tolerance of our curve.  The same plan timed with
    ``timing.control = "linuxcnc"`` (the same program text, the planner's model):
    every run within 1 % of the control's, the motion within 0.2 %.  The whole layers
    of both samples run as a campaign (``docs/validation/``)."""
    import linuxcnc_run
    import linuxcnc_tp_check

    source = ROOT / "tests" / "data" / "golden_small.toml"
    cfg = load_config(source)
    text = source.read_text(encoding="utf-8")
    assert 'controllers = ["sinumerik840d", "linuxcnc"]' in text
    (tmp_path / "variant").mkdir()
    modelled = tmp_path / "variant" / source.name  # the same name: the same header
    modelled.write_text(text.replace('controllers = ["sinumerik840d", "linuxcnc"]',
                                     'controllers = ["linuxcnc"]')
                        + '\n[timing]\ncontrol = "linuxcnc"\n', encoding="utf-8")
    planning = [subprocess.Popen([sys.executable, "-m", "sdit_path", "plan", str(config),
                                  "--out", str(tmp_path / out), "-q"])
                for config, out in ((source, "plan"), (modelled, "modelled"))]
    assert all(p.wait(timeout=300) == 0 for p in planning)
    files = load_plan(tmp_path / "plan")
    model = load_plan(tmp_path / "modelled")
    program = "GOLD_B"
    full = linuxcnc_run.program_text(files, program)
    assert full == linuxcnc_run.program_text(model, program)
    axes = linuxcnc_run.program_axes(files, program)
    runs = 5
    cut = linuxcnc_tp_check.cut_program(full, runs, axes)
    position, line = linuxcnc_run.run_text(files, cut, axes, tmp_path / "control", 180.0)

    c = linuxcnc_run.compare(files, linuxcnc_run.control_run(files, program, position, line))
    assert len(c["runs"]) == runs and c["dwells_control"] == runs + 1, c
    feed = cfg.test.feed_mm_per_min / 60.0
    for r in c["runs"]:
        assert abs(r["ratio"] - 1.0) <= 0.015, r
        assert r["min_cruise_speed_mm_s"] >= 0.98 * feed, r
    tol = cfg.post.chord_tolerance_um
    assert c["max_from_sphere_um"] <= tol * 1.01, c
    assert c["max_from_curve_um"] <= cfg.post.chord_curve_tolerance_um + tol, c

    m = linuxcnc_run.compare(model, linuxcnc_run.control_run(model, program, position, line))
    assert len(m["runs"]) == runs, m
    for r in m["runs"]:
        assert abs(r["ratio"] - 1.0) <= 0.01, r
    assert abs(m["motion_ratio"] - 1.0) <= 0.002, m
