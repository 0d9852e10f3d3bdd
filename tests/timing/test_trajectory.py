"""Timed trajectories hold every axis' limits, sit at the nodes during dwells, and
follow the programmed feed; checked on the exported CSV by finite differences."""

from __future__ import annotations

import re

import numpy as np
import pytest

from sdit_path.config import parse_config, sample_path
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.plan.pipeline import trajectory_files
from sdit_path.timing.limits import PathLimits
from sdit_path.timing.profile import plan_profile
from sdit_path.plan.trajectory_csv import read_csv, to_csv
from sdit_path.timing.trajectory import Timer, sample

from conftest import edit


def test_profile_ends_at_rest_on_the_target():
    prof = plan_profile(123.4, PathLimits(40.0, 900.0, 20000.0, "feed"))
    s, v, a, _, _ = prof.evaluate(np.linspace(0, prof.duration_s, 20001))
    assert s[-1] == pytest.approx(123.4, abs=1e-9) and abs(v[-1]) < 1e-9 and abs(a[-1]) < 1e-6
    assert np.all(np.diff(s) >= -1e-12) and v.max() == pytest.approx(40.0)
    assert np.abs(a).max() <= 900.0 * (1 + 1e-9)


def _random_config(seed: int):
    rng = np.random.default_rng(100 + seed)
    five = seed % 2 == 1
    text = sample_path("bc_table_5axis.toml" if five else "vmc_3axis.toml").read_text()
    text = text[: text.index("[[scene.parts]]")] + text[text.index("[post]"):]
    length = float(rng.uniform(50, 300))
    feed = float(rng.choice([600.0, 2000.0, 5000.0, 12000.0, 20000.0]))
    text = edit(text, "bar_length_mm", f"{length:.3f}")
    text = edit(text, "feed_mm_per_min", f"{feed:.1f}")
    text = edit(text, "track_elevations_deg", str(sorted(rng.choice([0.0, 20.0, 40.0, 60.0], 2,
                                                                      replace=False).tolist())))
    text = edit(text, "nodes_per_track", str(int(rng.integers(3, 7))))
    acc = float(rng.uniform(300, 3000))
    for ax in ("X", "Y", "Z"):
        text = edit(text, "travel_mm", "[-2000.0, 2000.0]", f"machine.axes.{ax}")
        text = edit(text, "max_acceleration_mm_per_s2", f"{acc:.1f}", f"machine.axes.{ax}")
        text = edit(text, "max_jerk_mm_per_s3", f"{acc * rng.uniform(5, 20):.1f}",
                    f"machine.axes.{ax}")
    return parse_config(text, f"timing{seed}.toml")


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_axis_limits_hold_on_the_exported_trajectory(seed):
    cfg = _random_config(seed)
    hemi = partition(cfg)
    timer = Timer(cfg)
    bindings = set()
    for layer in hemi.layers:
        timed = timer.time_layer(PathBuilder(cfg, hemi).layer_path(layer))
        bindings |= {i.profile.limits.binding for i in timed.items if hasattr(i, "geometry")}
        smp = read_csv(to_csv(sample(timed, timer, 1000.0), {}))
        dt = np.diff(smp.t_s)
        assert np.allclose(dt, 1e-3, atol=1e-9)
        for col, name in enumerate(smp.axis_names):
            ax = cfg.machine.axis(name)
            unit = np.degrees(1.0) if ax.is_rotary else 1.0
            x = smp.axes[:, col]
            v = np.diff(x) / 1e-3
            a = np.diff(v) / 1e-3
            j = np.diff(a) / 1e-3
            for what, value, limit in (("velocity", v, ax.max_velocity),
                                       ("acceleration", a, ax.max_acceleration),
                                       ("jerk", j, ax.max_jerk)):
                worst = np.abs(value).max() / (limit * unit)
                assert worst <= 1.01, f"seed {seed} layer {layer.name} {name} {what}: {worst:.4f}"
        # the path never exceeds the feed
        assert smp.speed_mm_per_s.max() <= cfg.test.feed_mm_per_min / 60 + 1e-5  # 5 decimals
    if cfg.test.feed_mm_per_min >= 12000:
        assert any(b != "feed" for b in bindings), bindings  # high feed: curvature binds


@pytest.mark.slow
def test_curvature_binds_at_high_feed_and_limits_still_hold():
    text = sample_path("vmc_3axis.toml").read_text()
    text = text[: text.index("[[scene.parts]]")] + text[text.index("[post]"):]
    text = edit(text, "bar_length_mm", "60.0")
    text = edit(text, "feed_mm_per_min", "20000.0")
    cfg = parse_config(text, "fast.toml")
    hemi = partition(cfg)
    timer = Timer(cfg)
    timed = timer.time_layer(PathBuilder(cfg, hemi).layer_path(hemi.layers[-1]))
    limits = [i.profile.limits for i in timed.items if hasattr(i, "geometry")]
    assert any("curvature" in lim.binding or "jerk" in lim.binding for lim in limits)
    assert max(lim.v_max for lim in limits) <= 20000 / 60


@pytest.fixture(scope="module")
def default_files(default_plan):
    return trajectory_files(default_plan)


@pytest.mark.slow
def test_trajectory_sits_at_the_nodes_during_dwells(default_plan, default_files):
    nodes = {n.id: n.position_mm for n in default_plan.hemisphere.nodes}
    for lp in default_plan.layers:
        prog = next(p for p in default_plan.programs if p.layer == lp.path.layer)
        smp = read_csv(default_files[f"trajectories/{prog.built.program.name}.csv"])
        dwell = smp.phase == "dwell"
        assert dwell.any()
        for node in set(smp.segment[dwell]):
            sel = dwell & (smp.segment == node)
            assert np.abs(smp.ball_mm[sel] - nodes[node]).max() < 1e-6  # as emitted
            assert np.abs(smp.speed_mm_per_s[sel]).max() == 0.0
        # every dwell lasts the dwell time: 2000 samples at 1 kHz per stop
        starts = np.flatnonzero(dwell[1:] & ~dwell[:-1]) + 1
        assert len(starts) + 1 == len(lp.path.dwells)
        assert set(smp.phase) <= {"accelerate", "cruise", "decelerate", "dwell"}


def test_feed_words_equal_the_planned_feed(default_plan):
    """From the move to the start node to the last dwell; the operator's way to the bar
    and back runs at post.approach_feed_mm_per_min."""
    cfg = default_plan.config
    for prog in default_plan.programs:
        text = prog.text[prog.text.index("start at node"):]
        test = text[:text.rindex("G4 ")]
        feeds = {float(m) for m in re.findall(r"(?m)^(?:BSPLINE|G1)\b.*\bF([0-9.]+)", test)}
        assert feeds == {cfg.test.feed_mm_per_min}, (prog.file, feeds)
        rest = prog.text.replace(test, "")
        approach = {float(m) for m in re.findall(r"(?m)^G1\b.*\bF([0-9.]+)", rest)}
        assert approach == {cfg.post.approach_feed_mm_per_min}, (prog.file, approach)


def test_cycle_times_in_the_manifest(default_plan):
    from sdit_path.plan.manifest import manifest

    m = manifest(default_plan)
    for p in m["programs"]:
        assert p["cycle_time_s"] > p["motion_time_s"] > 0
        assert p["trajectory"] == f"trajectories/{p['name']}.csv.gz"


def test_a_ramp_to_the_feed_is_one_profile_not_a_staircase():
    """On a low-curvature transit a speed-up from rest to F5000 spans several 2 mm
    windows: the path acceleration must not fall back to zero at window boundaries
    before the feed is reached (it did when every window started and ended at rest in
    acceleration: 0 to 83 mm/s took ~9 mm instead of ~3.4 mm)."""
    text = sample_path("vmc_3axis.toml").read_text()
    cfg = parse_config(edit(text, "feed_mm_per_min", "5000.0"), "f5000.toml")
    hemi = partition(cfg)
    timer = Timer(cfg)
    timed = timer.time_layer(PathBuilder(cfg, hemi).layer_path(hemi.layers[-1]))
    transits = [i for i in timed.items
                if hasattr(i, "geometry") and ">" in i.geometry.run.pieces[0].id]
    assert transits
    feed = 5000.0 / 60.0
    for run in transits:
        t = np.linspace(0.0, run.profile.duration_s, 200001)
        s, v, a, _, _ = run.profile.evaluate(t)
        top = int(np.argmax(v >= 0.999 * feed))
        assert top > 0, "never reaches the feed"
        ramp = a[: top + 1]
        start = int(np.argmax(ramp > 0.05 * ramp.max()))  # past the first jerk phase
        assert ramp[start:].min() > 0.01 * ramp.max(), run.geometry.run.pieces[0].id
        assert s[top] < 5.0, (run.geometry.run.pieces[0].id, s[top])
