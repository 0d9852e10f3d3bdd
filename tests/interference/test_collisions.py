from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from sdit_path.config import load_config, parse_config, sample_path
from sdit_path.errors import PlanError
from sdit_path.interference.scene import Scene
from sdit_path.machine.kinematics import Kinematics
from sdit_path.plan.pipeline import plan

from conftest import edit


def test_default_sample_is_clear_with_the_expected_tightest_pair(default_plan):
    cl = [(c.min_clearance_mm, c.clearance_pair, c.piece_id) for la in default_plan.layers
          for c in la.checks]
    assert all(c.feasible for la in default_plan.layers for c in la.checks)
    worst = min(cl)
    # the horizontal bar's end disc (radius 6) passes 4 mm under the tool holder,
    # which starts 10 mm above the ball centre
    assert 4.0 - 0.01 <= worst[0] <= 4.0
    # ... and as far above the pivot stand's top (40 mm) when horizontal: a tie
    assert set(worst[1]) in ({"bar", "tool_holder"}, {"bar", "pivot_stand"})


def test_clearance_is_exact_for_a_known_pose(default_config):
    """Ball straight above the pivot: the holder is 10 mm above the tool ball, the
    tool ball 150 mm above the pivot; table top at z=0, pivot stand top at z=40."""
    kin = Kinematics(default_config.machine)
    scene = Scene(default_config, kin)
    q = kin.inverse(np.array([[0.0, 0.0, 200.0]]), {})
    d = {frozenset(k): v for k, v in zip(scene.pair_names, scene.clearances(q)[0])}
    # conservative (never above the truth) and within 10 um of it; the coaxial
    # holder/stand pair is the alignment that plain fcl gets wrong by 1.17 mm
    for pair, truth in ((("tool_ball", "table"), 200 - 6.35),
                        (("tool_holder", "pivot_stand"), 210 - 40),
                        (("bar", "pivot_stand"), 200 - 6.35 - 137.3 - 40)):
        got = d[frozenset(pair)]
        assert truth - 0.01 <= got <= truth, (pair, got, truth)
    assert frozenset(("bar", "pivot_ball")) not in d and frozenset(("pivot_stand", "table")) not in d


def test_colliding_sample_is_caught_with_pair_and_location():
    cfg = load_config(sample_path("vmc_3axis_collision.toml"))
    with pytest.raises(PlanError) as err:
        plan(cfg)
    assert "infeasible piece(s): A1-1, A1-3" in str(err.value)
    first = err.value.details[0]
    assert first.startswith("layer A, A1-1: collision pivot_collar/bar")
    assert "at ball (150.000, 0.000, 50.000) mm" in first and "contact near" in first


@pytest.mark.slow
def test_skip_infeasible_leaves_them_out_and_marks_why(tmp_path):
    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "sdit_path", "plan",
                        str(sample_path("vmc_3axis_collision.toml")), "--out", str(out),
                        "--skip-infeasible", "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "plan.json").read_text())
    seg = {s["id"]: s for s in m["segments"]}
    assert seg["A1-1"]["status"] == "omitted" and not seg["A1-1"]["check"]["feasible"]
    assert "pivot_collar/bar" in seg["A1-1"]["check"]["violations"][0]
    assert seg["A1-2"]["status"] == "planned" and seg["A1-2"]["check"]["feasible"]
    assert m["layers"][0]["omitted"][:2] == ["A1-1", "A1-3"]
    text = (out / "sinumerik840d" / "SDIT_A.MPF").read_text()
    assert "; A1-1" not in text and "; A1-2" in text and "M0" in text
    prog = next(p for p in m["programs"] if p["file"] == "sinumerik840d/SDIT_A.MPF")
    assert "A1-1" not in prog["segment_order"] and prog["remounts"] == 10


@pytest.mark.slow
def test_a_bulky_spindle_nose_is_caught(default_text):
    """A nose hanging below the ball swallows the bar."""
    text = default_text.replace('size_mm = [50.0, 150.0]\nposition_mm = [0.0, 0.0, 173.0]',
                                'size_mm = [50.0, 150.0]\nposition_mm = [0.0, 0.0, 30.0]')
    with pytest.raises(PlanError) as err:
        plan(parse_config(text, "nose.toml"))
    assert err.value.details[0].startswith("layer A, A1-1: collision spindle_nose/bar")


@pytest.mark.slow
def test_unreachable_rotary_schedule_names_axis_and_overshoot():
    text = sample_path("bc_table_5axis.toml").read_text()
    text = edit(text, "tilt_at_pole_deg", "150.0")
    with pytest.raises(PlanError) as err:
        plan(parse_config(text, "tilt.toml"))
    assert any("B 1" in d and "exceeds its limit 119 deg" in d for d in err.value.details)


@pytest.mark.parametrize("sample", ["bc_table_5axis.toml", "vmc_3axis_collision.toml"])
def test_bounded_search_equals_the_exhaustive_scan(sample):
    """The lower-bound pruning never changes the answer: per piece, the minimum
    clearance equals the minimum over every pose and every pair computed by fcl."""
    from sdit_path.geometry.hemisphere import partition
    from sdit_path.geometry.paths import PathBuilder
    from sdit_path.interference.check import run_clearances
    from sdit_path.machine.poses import layer_poses

    cfg = load_config(sample_path(sample))
    hemi = partition(cfg)
    kin = Kinematics(cfg.machine)
    scene = Scene(cfg, kin)
    path = PathBuilder(cfg, hemi).layer_path(hemi.layers[0])
    for rp in layer_poses(path, cfg, kin)[:4]:
        found, _ = run_clearances(rp, scene, cfg.check.safety_clearance_mm)
        full = scene.clearances(rp.q)
        lower = scene.lower_bounds(scene.part_poses(rp.q))
        assert (lower <= full + 1e-9).all()            # the bound is a bound
        for k, clearance in found.items():
            assert clearance.value_mm == pytest.approx(full[rp.piece == k].min(), abs=1e-9)
