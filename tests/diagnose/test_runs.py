"""A recording's own timing, run by run: its still stretches matched to the program's
dwells, every run placed by the reading, and a real control's 5-axis recording, refused
before, recognised and timed."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from sdit_path.diagnose.runs import match_dwells, still_stretches


def _recording(run_s, dwell_s=2.0, lead_s=5.0, noise=0.2, flat_inside=None, seed=0):
    """A reading that stands still at each dwell and wanders during each run; with
    ``flat_inside`` (run index), that run's reading stands still for its middle second."""
    rng = np.random.default_rng(seed)
    t, y, level, now = [], [], 0.0, 0.0
    def add(duration, f):
        nonlocal now
        tt = np.arange(now, now + duration, 0.001)
        t.append(tt)
        y.append(f(tt - now))
        now += duration
    add(lead_s + dwell_s, lambda u: np.full(len(u), level))
    for k, d in enumerate(run_s):
        start = level

        def shape(u, d=d, start=start, hold=flat_inside == k):
            if hold:  # the reading holds for a second mid-run
                u = np.where(np.abs(u - d / 2) < 0.5, d / 2 - 0.5, u)
            return start + 3.0 * np.sin(np.pi * u / d) + 0.5 * u / d

        add(d, shape)
        level = float(y[-1][-1])
        add(dwell_s, lambda u, level=level: np.full(len(u), level))
    add(3.0, lambda u: np.full(len(u), level))
    t, y = np.concatenate(t), np.concatenate(y)
    return t, y + noise * rng.standard_normal(len(t))


def test_still_stretches_are_the_dwells_and_match_the_programs_in_order():
    planned = [4.7, 6.3, 6.3, 4.7]
    runs = [(0, d, "a", "b") for d in planned]
    # the control took longer on the middle runs, as LinuxCNC's 5-axis crawl does
    took = [4.6, 12.4, 11.8, 4.7]
    t, y = _recording(took, flat_inside=1)
    st = still_stretches(t, y, 0.2, 0.6)
    # the dwells and, inside the runs, where the reading turns or holds
    assert len(st) > len(took) + 1
    found = match_dwells(runs, st, 2.0)
    assert found is not None
    cost, pairs = found
    # every run leaves and reaches the stretches of its dwells
    starts = [st[i].end_s for i, _ in pairs]
    ends = [st[j].start_s for _, j in pairs]
    expected_start = 7.0
    for k, d in enumerate(took):
        assert abs(starts[k] - expected_start) < 0.6
        assert abs(ends[k] - (expected_start + d)) < 0.6
        expected_start += d + 2.0
    # a program with twice the runs fits this recording's dwells worse (its alignment,
    # which follows, tells them apart for good)
    other = match_dwells(runs + runs, st, 2.0)
    assert other is None or other[0] > cost + 3
    # and one with fewer dwells than the recording's runs needs still stretches that
    # are not there: a run twice as long as planned everywhere
    fewer = match_dwells(runs[:2], st, 2.0)
    assert fewer is None or fewer[0] > cost


def _recorded(plan_dir, program, tmp_path, effect=None):
    out = tmp_path / f"{program}.csv"
    truth = tmp_path / f"{program}.json"
    args = [sys.executable, "-m", "sdit_path", "perturb", "--plan", str(plan_dir), "--program",
            program, "--control", "linuxcnc", "--lead-s", "6.5", "--clock-ppm", "-70",
            "--noise-um", "0.15", "--seed", "3", "--out", str(out), "--truth", str(truth), "-q"]
    if effect:
        args += ["--effect", effect]
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return out, json.loads(truth.read_text())


@pytest.mark.slow
def test_a_five_axis_recording_of_linuxcnc_is_recognised_and_timed_run_by_run(
        five_axis_plan, tmp_path):
    """The recording follows LinuxCNC's own motion of SDIT5_E (12 of its 22 runs take
    twice their planned time): given unnamed, with no controller named, it is
    recognised, timed run by run from LinuxCNC's time law, and every run's duration
    lies within three of its stated standard uncertainties."""
    from sdit_path.analyse.matching import match
    from sdit_path.plan.files import load_plan
    from sdit_path.reading.recording import read_trace

    plan = load_plan(five_axis_plan)
    program = plan.program_names[-1]
    path, truth = _recorded(five_axis_plan, program, tmp_path,
                            "setup_offset:dx_um=6,dy_um=-3,dz_um=4")
    rec, how = match(plan, read_trace(path), "rec.csv")
    assert rec.program == program and "run by run" in how, how
    assert rec.runs is not None and rec.motion == "linuxcnc"
    clock = 1 + truth["recording"]["clock_ppm"] * 1e-6
    true_s = np.array([r["control_s"] for r in truth["control"]["runs"]]) * clock
    table = rec.runs.as_table()
    measured = np.array([r["measured_s"] for r in table])
    std = np.array([r["std_s"] for r in table])
    assert len(measured) == len(true_s) == 22
    assert np.all(np.abs(measured - true_s) <= 3 * std), (measured - true_s) / std
    # not a uniformly loose statement: the runs are placed to tens of milliseconds
    assert np.median(std) < 0.1
    # the start: within three of its stated uncertainties
    start = truth["recording"]["offset_s"]
    assert abs(rec.alignment.offset_s - start) <= 3 * rec.alignment.offset_std_s
    # and the plan's timing alone could not place it (a crawl the clock cannot follow)
    assert rec.alignment.rms_um < 1.15 * rec.noise_um
