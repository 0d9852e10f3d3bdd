"""The expected reading follows the program as written for its controller: LinuxCNC's
chords dip inside the sphere, and a clean recording of a control that runs them has no
finding."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.analyse.diagnosis import diagnose_recording
from sdit_path.errors import ConfigError
from sdit_path.machine.kinematics import Kinematics
from sdit_path.plan.files import load_plan
from sdit_path.reading.context import build_context
from sdit_path.reading.trace import Trace
from sdit_path.timing.linuxcnc_tp import ControlLimits, simulate, stretches


@pytest.fixture(scope="module")
def linuxcnc_plan(tmp_path_factory, default_text):
    """The default sample at F1500 written for LinuxCNC alone and timed by its planner
    (``timing.control = "linuxcnc"``), planned by the command line."""
    import subprocess
    import sys

    from conftest import edit

    d = tmp_path_factory.mktemp("lc")
    text = edit(edit(default_text, "controllers", '["linuxcnc"]'), "feed_mm_per_min", "1500.0")
    (d / "lc.toml").write_text(text + '\n[timing]\ncontrol = "linuxcnc"\n')
    r = subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(d / "lc.toml"), "--out",
                        str(d / "P"), "-q"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    return d / "P"


@pytest.mark.slow
def test_the_chords_enter_the_expected_reading_of_a_linuxcnc_program(linuxcnc_plan, plan_f1500):
    both = load_plan(plan_f1500)
    assert both.ran_on == "sinumerik840d"  # the first the sample lists
    assert not build_context(both, "SDIT_E").written_um.any()  # a BSPLINE: the curve
    with pytest.raises(ConfigError, match="no programs for controller 'fanuc'"):
        both.for_controller("fanuc")
    # planned with our timing and run by LinuxCNC, the trajectory is the control's own
    # motion of the chords: nothing is added on top
    assert both.for_controller("linuxcnc").control_motion
    assert not build_context(both.for_controller("linuxcnc"), "SDIT_E").written_um.any()
    # planned with LinuxCNC's timing, the trajectory keeps to the curve: the chords add
    plan = load_plan(linuxcnc_plan)
    assert plan.ran_on == "linuxcnc" and not plan.control_motion
    ctx = build_context(plan, "SDIT_E")
    written = ctx.written_um
    tolerance_um = plan.config.post.chord_tolerance_um
    # inside the sphere between vertices, by up to the chord tolerance, never out
    assert written.min() < -0.5 * tolerance_um
    assert written.min() >= -1.05 * tolerance_um
    assert written.max() <= 0.05 * tolerance_um  # vertices rounded as printed
    assert not written[~ctx.moving].any()


def _linuxcnc_recording(plan, program: str, noise_um: float, lead_s: float = 3.0) -> Trace:
    """What a ballbar reads on a perfect machine run by LinuxCNC 2.9: its planner's
    commanded positions (the model of sdit_path.timing.linuxcnc_tp, checked against the
    real control to 0.001 um) every servo period, the dwells between, white noise."""
    cfg = plan.config
    text, entry = plan.for_controller("linuxcnc").program_text(program)
    assert entry["frame"]["name"] == "table"
    limits = ControlLimits.from_machine(cfg.machine, ("X", "Y", "Z"))
    parts, dwell = [], cfg.test.dwell_s
    for k, st in enumerate(stretches(text, ("X", "Y", "Z"))):
        sim = simulate(st, limits)
        moving = np.flatnonzero(sim.moving)
        still = int(round((lead_s + dwell if k == 0 else dwell) * 1000))
        parts += [np.repeat(sim.start[None, :], still, axis=0),
                  sim.position[moving[0]:moving[-1] + 1]]
    parts.append(np.repeat(parts[-1][-1:], int((dwell + lead_s) * 1000), axis=0))
    p = np.vstack(parts)
    reading = (np.linalg.norm(p - np.asarray(cfg.ballbar.pivot_mm), axis=1)
               - cfg.ballbar.bar_length_mm) * 1e3
    y = reading + noise_um * np.random.default_rng(7).standard_normal(len(p))
    assert Kinematics(cfg.machine).rotary == ()
    return Trace(np.arange(len(p)) * 1e-3, y, np.array([]), np.array([]), {"program": program})


@pytest.mark.slow
def test_a_clean_recording_of_linuxcnc_has_no_finding(plan_f1500):
    plan = load_plan(plan_f1500).for_controller("linuxcnc")
    trace = _linuxcnc_recording(plan, "SDIT_E", noise_um=0.02)
    result, _ = diagnose_recording(plan, "SDIT_E", trace, "linuxcnc.csv")
    assert not result.findings, [f.effect for f in result.findings]


@pytest.mark.slow
def test_a_linuxcnc_user_plans_the_controls_timing_and_reads_a_clean_recording_as_clean(
        tmp_path, linuxcnc_plan):
    """Planned for LinuxCNC with its timing (``timing.control = "linuxcnc"``), a
    recording made from the control's own motion (``perturb --control linuxcnc``: the
    chords, ramps and blends of LinuxCNC 2.9's planner) is aligned to its start and
    clock and has no finding; the truth says each run's planned and control time."""
    import json
    import subprocess
    import sys

    def run(*args):
        r = subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                           text=True, timeout=900)
        assert r.returncode == 0, r.stderr
        return r.stdout

    # the dwells exactly as programmed: the control's own timing, nothing else
    run("perturb", "--plan", str(linuxcnc_plan), "--program", "SDIT_E", "--control", "linuxcnc",
        "--dwell-extra-ms", "0,0", "--noise-um", "0.02", "--lead-s", "4", "--clock-ppm", "30",
        "--out", str(tmp_path / "rec.csv"), "--truth", str(tmp_path / "truth.json"), "-q")
    truth = json.loads((tmp_path / "truth.json").read_text())
    runs = truth["control"]["runs"]
    assert len(runs) == 22 and all(abs(r["control_s"] / r["planned_s"] - 1) < 0.005 for r in runs)
    run("diagnose", "--plan", str(linuxcnc_plan), "--program", "SDIT_E", "--measured",
        str(tmp_path / "rec.csv"), "--json", str(tmp_path / "d.json"), "-q")
    report = json.loads((tmp_path / "d.json").read_text())
    assert report["findings"] == []
    al = report["alignment"]
    assert abs(al["offset_s"] - 4.0) < 0.002 and abs(al["clock_ppm"] - 30.0) < 3.0


@pytest.mark.parametrize("controller", ["fanuc", "haas", "heidenhain", "fanuc_nurbs"])
def test_the_chords_of_every_chord_dialect_enter_the_expected_reading(tmp_path_factory,
                                                                     controller):
    """FANUC, Haas and HEIDENHAIN chords are read back with our reader of each dialect
    and dip inside the sphere between vertices as LinuxCNC's do; a FANUC NURBS keeps
    the curve."""
    import subprocess
    import sys

    from conftest import DATA

    d = tmp_path_factory.mktemp(controller)
    text = (DATA / "golden_small.toml").read_text().replace(
        'controllers = ["sinumerik840d", "linuxcnc"]', f'controllers = ["{controller}"]')
    (d / "c.toml").write_text(text)
    r = subprocess.run([sys.executable, "-m", "sdit_path", "plan", str(d / "c.toml"), "--out",
                        str(d / "P"), "-q"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    plan = load_plan(d / "P")
    assert plan.ran_on == controller
    ctx = build_context(plan, "GOLD_A")
    written = ctx.written_um
    if controller == "fanuc_nurbs":
        assert not written.any()
        return
    # inside the sphere by up to the chord tolerance, measured from the planned curve,
    # which this small plan keeps only within its (coarse) spline tolerance
    tolerance_um = plan.config.post.chord_tolerance_um
    curve_um = plan.config.post.spline_tolerance_um
    assert written.min() < -0.5 * tolerance_um
    assert written.min() >= -1.05 * tolerance_um - curve_um
    assert written.max() <= 0.05 * tolerance_um + curve_um
    assert not written[~ctx.moving].any()
