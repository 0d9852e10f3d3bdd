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


def test_the_chords_enter_the_expected_reading_of_a_linuxcnc_program(plan_f1500):
    plan = load_plan(plan_f1500)
    assert plan.ran_on == "sinumerik840d"  # the first the sample lists
    spline = build_context(plan, "SDIT_E").written_um
    assert not spline.any()  # the BSPLINE keeps the sphere to nanometres
    ctx = build_context(plan.for_controller("linuxcnc"), "SDIT_E")
    written = ctx.written_um
    tolerance_um = plan.config.post.chord_tolerance_um
    # inside the sphere between vertices, by up to the chord tolerance, never out
    assert written.min() < -0.5 * tolerance_um
    assert written.min() >= -1.05 * tolerance_um
    assert written.max() <= 0.05 * tolerance_um  # vertices rounded as printed
    assert not written[~ctx.moving].any()
    with pytest.raises(ConfigError, match="no programs for controller 'fanuc'"):
        plan.for_controller("fanuc")


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
        tmp_path, default_text):
    """Planned for LinuxCNC with its timing (``timing.control = "linuxcnc"``), a
    recording made from the control's own motion (``perturb --control linuxcnc``: the
    chords, ramps and blends of LinuxCNC 2.9's planner) is aligned to its start and
    clock and has no finding; the truth says each run's planned and control time."""
    import json
    import subprocess
    import sys

    from conftest import edit

    text = edit(default_text, "controllers", '["linuxcnc"]')
    text = edit(text, "feed_mm_per_min", "1500.0")
    cfg = tmp_path / "lc.toml"
    cfg.write_text(text + '\n[timing]\ncontrol = "linuxcnc"\n')

    def run(*args):
        r = subprocess.run([sys.executable, "-m", "sdit_path", *args], capture_output=True,
                           text=True, timeout=900)
        assert r.returncode == 0, r.stderr
        return r.stdout

    run("plan", str(cfg), "--out", str(tmp_path / "P"), "-q")
    run("perturb", "--plan", str(tmp_path / "P"), "--program", "SDIT_E", "--control", "linuxcnc",
        "--noise-um", "0.02", "--lead-s", "4", "--clock-ppm", "30",
        "--out", str(tmp_path / "rec.csv"), "--truth", str(tmp_path / "truth.json"), "-q")
    truth = json.loads((tmp_path / "truth.json").read_text())
    runs = truth["control"]["runs"]
    assert len(runs) == 22 and all(abs(r["control_s"] / r["planned_s"] - 1) < 0.005 for r in runs)
    run("diagnose", "--plan", str(tmp_path / "P"), "--program", "SDIT_E", "--measured",
        str(tmp_path / "rec.csv"), "--json", str(tmp_path / "d.json"), "-q")
    report = json.loads((tmp_path / "d.json").read_text())
    assert report["findings"] == []
    al = report["alignment"]
    assert abs(al["offset_s"] - 4.0) < 0.002 and abs(al["clock_ppm"] - 30.0) < 3.0
