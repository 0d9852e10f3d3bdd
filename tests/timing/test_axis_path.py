"""Runs where a rotary axis turns fast are timed by the windows along the machine's axis
path: quicker than along the ball's arc length, within every axis' limits and the feed,
with a path speed column that is the ball's own speed.  (The optimal speed law, which
beats both, is left out here: tests/timing/test_topp.py.)"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import edit

from sdit_path.config import parse_config, sample_path
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.plan.trajectory_csv import read_csv, to_csv
from sdit_path.timing.profile import plan_chain
from sdit_path.timing.trajectory import RunParameter, TimedRun, Timer, sample


@pytest.fixture(scope="module")
def top_layer_f2000():
    text = sample_path("bc_table_5axis.toml").read_text()
    cfg = parse_config(edit(text, "feed_mm_per_min", "2000.0"), "bc_f2000.toml")
    hemi = partition(cfg)
    timer = Timer(cfg, optimal=False)
    layer = hemi.layers[-1]
    return cfg, timer, timer.time_layer(PathBuilder(cfg, hemi).layer_path(layer))


@pytest.mark.slow
def test_curved_runs_are_quicker_along_the_axis_path(top_layer_f2000):
    _, timer, timed = top_layer_f2000
    runs = [i for i in timed.items if isinstance(i, TimedRun)]
    along_axes = [r for r in runs if not r.param.identity]
    assert along_axes, "no run was timed along the axis path"
    for r in along_axes:
        windows, _ = timer.run_windows(r.geometry, r.carry_in, RunParameter(r.geometry.length_mm))
        along_ball = plan_chain(windows, "test").duration_s
        assert r.profile.duration_s < 0.95 * along_ball, (r.profile.duration_s, along_ball)
        # the map covers the run, end to end, and only goes forward
        x = np.linspace(0.0, r.param.length_mm, 5001)
        s = r.param.s(x)
        assert s[0] == pytest.approx(0.0, abs=1e-9)
        assert s[-1] == pytest.approx(r.geometry.length_mm, abs=1e-9)
        assert np.all(np.diff(s) > 0) and np.all(r.param.ds(x) > 0)


def test_axis_path_runs_hold_the_limits_and_the_feed(top_layer_f2000):
    cfg, timer, timed = top_layer_f2000
    smp = read_csv(to_csv(sample(timed, timer, 1000.0), {}))
    for col, name in enumerate(smp.axis_names):
        ax = cfg.machine.axis(name)
        unit = np.degrees(1.0) if ax.is_rotary else 1.0
        v = np.diff(smp.axes[:, col]) / 1e-3
        a = np.diff(v) / 1e-3
        j = np.diff(a) / 1e-3
        for what, value, limit in (("velocity", v, ax.max_velocity),
                                   ("acceleration", a, ax.max_acceleration),
                                   ("jerk", j, ax.max_jerk)):
            assert np.abs(value).max() <= 1.01 * limit * unit, (name, what)
    feed = cfg.test.feed_mm_per_min / 60.0
    assert smp.speed_mm_per_s.max() <= feed + 1e-5
    # the speed column is the ball's speed (central differences of its positions)
    moving = (smp.phase[1:-1] != "dwell") & (smp.phase[1:-1] != "reposition")
    fd = np.linalg.norm(smp.ball_mm[2:] - smp.ball_mm[:-2], axis=1) / 2e-3
    assert np.abs(fd - smp.speed_mm_per_s[1:-1])[moving].max() < 0.01


def test_a_machine_without_rotary_axes_runs_along_the_balls_arc_length():
    cfg = parse_config(sample_path("vmc_3axis.toml").read_text(), "vmc.toml")
    hemi = partition(cfg)
    timer = Timer(cfg)
    timed = timer.time_layer(PathBuilder(cfg, hemi).layer_path(hemi.layers[-1]))
    runs = [i for i in timed.items if isinstance(i, TimedRun)]
    assert runs and all(r.param.identity for r in runs)
    x = np.linspace(0.0, runs[0].param.length_mm, 11)
    assert np.array_equal(runs[0].param.s(x), x)
