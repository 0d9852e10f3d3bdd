from __future__ import annotations

import subprocess
import sys

import matplotlib.image as mpimg
import numpy as np
import pytest

from sdit_path.output import MARKER

from conftest import DATA


@pytest.mark.slow
def test_preview_writes_three_readable_pictures_per_layer(tmp_path):
    out = tmp_path / "prev"
    r = subprocess.run([sys.executable, "-m", "sdit_path", "preview", str(DATA / "golden_small.toml"),
                        "--out", str(out), "--feed", "3000", "-q"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in out.iterdir() if p.name != MARKER)
    assert names == sorted(f"GOLD_{layer}_{kind}.png" for layer in "AB"
                           for kind in ("speed", "axes", "hemisphere"))
    assert (out / MARKER).is_file()
    for p in out.glob("*.png"):
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        img = mpimg.imread(p)
        assert img.shape[0] > 300 and img.shape[1] > 600
        assert np.std(img[..., :3]) > 0.05            # not a blank canvas


def test_preview_rejects_a_bad_feed(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sdit_path", "preview", "--out", str(tmp_path / "x"),
                        "--feed", "-5"], capture_output=True, text=True)
    assert r.returncode == 2 and "--feed: expected a feed in [1, 1e6] mm/min" in r.stderr


@pytest.mark.slow
def test_preview_says_which_timing_it_shows(tmp_path):
    """The pictures and the command name the timing model: ours or LinuxCNC's planner."""
    text = (DATA / "golden_small.toml").read_text(encoding="utf-8")
    text = text.replace('controllers = ["sinumerik840d", "linuxcnc"]', 'controllers = ["linuxcnc"]')
    (tmp_path / "c").mkdir()
    config = tmp_path / "c" / "golden_small.toml"
    config.write_text(text + '\n[timing]\ncontrol = "linuxcnc"\n', encoding="utf-8")
    r = subprocess.run([sys.executable, "-m", "sdit_path", "preview", str(config),
                        "--out", str(tmp_path / "prev")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    said = " ".join(r.stdout.split())  # rich wraps at the terminal's width
    assert 'timing: LinuxCNC 2.9 planner model, timing.control = "linuxcnc"' in said

    from sdit_path.config import load_config
    from sdit_path.plan.pipeline import plan
    from sdit_path.plan.preview import preview

    modelled = preview(plan(load_config(config)))
    assert modelled.timing == "LinuxCNC 2.9 planner model"
    assert "without a jerk limit" in modelled.note  # said under its axis pictures
    assert preview(plan(load_config(DATA / "golden_small.toml"))).timing == "our jerk-limited plan"


@pytest.mark.slow
def test_preview_of_a_written_plan_draws_its_trajectories_without_planning(golden_plans,
                                                                         tmp_path):
    from sdit_path.plan.files import load_plan
    from sdit_path.plan.preview import preview_of_plan

    plan = load_plan(golden_plans["fast"])
    pv = preview_of_plan(plan)
    assert [lp.program for lp in pv.layers] == ["GOLD_A", "GOLD_B"]
    for lp in pv.layers:  # the trajectories as written, not planned again
        assert lp.samples is plan.trajectory(lp.program)
    out = tmp_path / "prev"
    r = subprocess.run([sys.executable, "-m", "sdit_path", "preview", "--plan",
                        str(golden_plans["fast"]), "--out", str(out), "-q"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert len(list(out.glob("*.png"))) == 6
    # the plan's feed is fixed: --feed with --plan is refused in one line
    r = subprocess.run([sys.executable, "-m", "sdit_path", "preview", "--plan",
                        str(golden_plans["fast"]), "--out", str(tmp_path / "x"), "--feed", "900"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "not with --plan" in r.stderr and "Traceback" not in r.stderr
