"""The operator's way to the bar and back: a checked approach from the safe position,
a stop to mount the bar and start the recording, the same at the end, and a master
program per controller that runs the layers with the bar mounted once."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from sdit_path.config import parse_config
from sdit_path.errors import PlanError
from sdit_path.nc.registry import get_postprocessor
from sdit_path.plan.manifest import manifest
from sdit_path.plan.pipeline import plan
from sdit_path.program_marks import TEST_BEGINS, TEST_ENDS

from conftest import DATA


def small(text_edit=lambda t: t):
    text = (DATA / "golden_small.toml").read_text()
    return parse_config(text_edit(text), "golden_small.toml")


@pytest.fixture(scope="module")
def small_plan():
    return plan(small())


def test_every_program_takes_the_operator_to_the_bar_and_back(small_plan):
    cfg = small_plan.config
    for prog in small_plan.programs:
        text = prog.text.lower()
        begins, ends = text.index(TEST_BEGINS), text.index(TEST_ENDS)
        before, test, after = text[:begins], text[begins:ends], text[ends:]
        # one stop before the test (mount the bar), one after (take it off), none inside
        assert before.count("\nm0\n") == 1 and "mount it between the pivot" in before
        assert after.count("\nm0\n") == 1 and "take the ballbar off" in after
        assert "\nm0\n" not in test
        # the first move raises Z alone
        first = next(line for line in prog.text.splitlines() if line.startswith(("G1 ", "G01 ")))
        assert first.split()[1].startswith("Z") and len(first.split()) == 3, first
        assert f"F{cfg.post.approach_feed_mm_per_min:g}" in first


def test_plan_json_lists_every_leg_with_its_clearance(small_plan):
    m = manifest(small_plan)
    for layer in m["layers"]:
        seq = layer["operator_sequence"]
        legs = seq["legs"]
        assert [leg["phase"] for leg in legs] == ["approach"] * 4 + ["retract"] * 2
        assert [leg["checked"] for leg in legs] == [False, False, True, True, True, True]
        for leg in legs[2:]:
            assert leg["min_clearance_mm"] >= small_plan.config.check.safety_clearance_mm
            assert leg["violations"] == [] and len(leg["clearance_pair"]) == 2
        # down to the start node: it ends where the test begins
        node = next(n for n in m["nodes"] if n["id"] == "A-1")
        assert legs[3]["to_mm"] == node["position_mm"]
        assert seq["safe_z_mm"] == pytest.approx(40.0 + 100.0 + 50.0)


def test_a_safe_position_that_hits_the_pivot_is_refused_naming_the_leg():
    cfg = small(lambda t: t + "\n")
    text = cfg.text.replace('chord_curve_tolerance_um = 100.0',
                            'chord_curve_tolerance_um = 100.0\nsafe_position_mm = [10.0, -20.0, 40.0]')
    with pytest.raises(PlanError) as err:
        plan(parse_config(text, "bad.toml"))
    assert "safe_position_mm" in str(err.value)
    assert any("over the start node at the safe height: collision" in d and "pivot_ball" in d
               for d in err.value.details), err.value.details


def test_without_the_operator_sequence_the_program_starts_at_the_node():
    text = (DATA / "golden_small.toml").read_text().replace(
        'chord_curve_tolerance_um = 100.0', 'chord_curve_tolerance_um = 100.0\noperator_sequence = false')
    result = plan(parse_config(text, "off.toml"))
    assert not result.masters
    for prog in result.programs:
        assert "\nM0\n" not in prog.text and TEST_BEGINS not in prog.text.lower()
    assert "operator_sequence" not in manifest(result)["layers"][0]


def test_the_master_program_runs_every_layer_with_the_bar_mounted_once(small_plan):
    layers = [p for p in small_plan.programs if p.controller == "linuxcnc"]
    for master in small_plan.masters:
        post = get_postprocessor(master.controller)
        assert not post.lint(master.text, {})
        progs = [p for p in small_plan.programs if p.controller == master.controller]
        text = master.text.lower()
        # one mounting stop, one stop between two layers, one to take the bar off
        assert text.count("\nm0\n") == 1 + (len(progs) - 1) + 1
        assert text.count("mount it between the pivot") == 1
        assert "start the recording of layer b" in text
        dwell = {"sinumerik840d": "\ng4 f2\n", "linuxcnc": "\ng4 p2\n"}[master.controller]
        assert text.count(dwell) == sum(p.text.lower().count(dwell) for p in progs)
    assert len(small_plan.masters) == len(small_plan.config.post.controllers)
    assert len(layers) == 2


@pytest.mark.oracle
def test_the_linuxcnc_interpreter_runs_the_master_and_the_approach(small_plan, tmp_path):
    if shutil.which("rs274") is None:
        pytest.skip("LinuxCNC's interpreter is not installed")
    from linuxcnc_oracle import interpret, ok

    master = next(m for m in small_plan.masters if m.controller == "linuxcnc")
    f = tmp_path / "all.ngc"
    f.write_text(master.text)
    result, message, rec = interpret(str(f))
    assert ok(result), message
    cfg = small_plan.config
    h = small_plan.hemisphere
    p = np.array([x[1:4] for x in rec.feeds])
    # off the sphere only before the test begins and after it ends
    lines = np.array([x[0] for x in rec.feeds])
    marks = {text.strip().lower(): line for line, text in rec.comments}
    inside = (lines > marks[TEST_BEGINS]) & (lines < marks[TEST_ENDS])
    r = np.abs(np.linalg.norm(p - h.centre_mm, axis=1) - h.radius_mm)
    assert r[inside].max() <= cfg.post.chord_tolerance_um * 1e-3
    assert r[~inside].max() > 10.0  # the approach, off the sphere
    assert len(rec.dwells) == sum(len(la.path.dwells) for la in small_plan.layers)
