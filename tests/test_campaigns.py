"""Bounded, seeded samples of the validation campaigns (``validation/``), each asserting
the campaign's own targets on its sample.  The whole campaigns and their current
figures are in ``docs/validation/``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hostile_cases import RECORDING_CASES

pytestmark = pytest.mark.campaign

VALIDATION = Path(__file__).resolve().parents[1] / "validation"


def run(script: str, *args: str, timeout: int = 900) -> str:
    r = subprocess.run([sys.executable, str(VALIDATION / script), *args], capture_output=True,
                       text=True, timeout=timeout)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    return r.stdout


def test_self_check_names_the_hidden_effect_and_nothing_on_clean_traces(plan_f1500, tmp_path):
    """``perturb_selfcheck`` on four seeded cases of the plan the diagnosis tests read
    (two clean traces, a set-up offset, a bar length): top-1 at least 0.90 of the cases
    with one hidden effect, false findings on clean traces at most 0.05 of them, the
    held-out gap above the noise shrinking by at least 70 % where the effect is named."""
    out = tmp_path / "selfcheck.json"
    run("perturb_selfcheck.py", "--cases", "4", "--jobs", "2", "--plan", str(plan_f1500),
        "--json", str(out))
    rows = json.loads(out.read_text())
    clean = [r for r in rows if r["kind"] == "none"]
    one = [r for r in rows if r["kind"] == "one"]
    assert clean and one
    assert sum(r["false_finding"] for r in clean) / len(clean) <= 0.05, clean
    assert sum(r["top1"] for r in one) / len(one) >= 0.90, one
    shrink = [r["heldout_shrink_above_noise"] for r in one if "heldout_shrink_above_noise" in r]
    assert shrink and min(shrink) >= 0.70, one


def test_analyse_blind_recovers_the_geometry_names_the_effect_and_refuses_strangers(tmp_path):
    """``analyse_blind`` on its first seeded case (golden_small, random geometry, a
    hidden servo lag in both programs, refusals of recordings of another plan with the same
    program names, given unnamed and named): every determined combination within three of
    its standard uncertainties, the effect named in each recording (a contour smoothing,
    which one feed cannot tell from a lag, named with it counts), start and clock within
    their bounds, every stranger refused with one line.  (A recording of another feed and
    one named as another program: tests/identify/test_analyse.py.)"""
    out = tmp_path / "ablind.json"
    run("analyse_blind.py", "--cases", "1", "--seed", "1", "--json", str(out), "--work",
        str(tmp_path / "work"), "--refusals", "plan", timeout=1500)
    (case,) = json.loads(out.read_text())
    assert case["within_3"] == case["combinations"] > 0
    for r in case["recordings"]:
        assert r["right"] or r["in_ambiguous"], r
        assert r["offset_ok"] and r["clock_ok"], r
    assert len(case["refusals"]) == 2, case["refusals"]
    assert all(x["refused"] for x in case["refusals"]), case["refusals"]


def test_hostile_campaign_ends_every_case_in_one_line_or_a_result():
    """A bounded sample of the hostile-input campaign: mutated configs planned end to
    end, mutated recordings and the named bad ones identified and diagnosed, edited plan
    directories simulated, identified and diagnosed, each in its own process: no
    traceback, signal, hang or second error line, no exit 0 where a refusal is due."""
    out = run("hostile_campaign.py", "--cases", "3", "--seed", "3", "--timeout", "300")
    assert "config: 3 case(s)" in out and "plan: 3 case(s): refused 3" in out, out
    assert f"recording: {3 + len(RECORDING_CASES)} case(s)" in out, out
    assert "tracebacks: 0, wrong exits 0: 0, signals: 0, hangs: 0" in out, out
    assert int(re.search(r"failures: (\d+)", out).group(1)) == 0, out
