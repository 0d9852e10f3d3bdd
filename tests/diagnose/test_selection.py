"""How the diagnosis chooses among effects, on golden_small's first layer (two
sub-segments a sector, so that its period meets the held-out split): the held-out
stretches cover every kind of stretch, a play is sized with everything else in, and the
mounting's two parts are tried together when neither passes alone."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from sdit_path.analyse import DIAGNOSIS
from sdit_path.reading.context import build_context
from sdit_path.diagnose import diagnose
from sdit_path.diagnose.heldout import held_stretches, stretch_numbers
from sdit_path.errormodel.errorset import load_error_set
from sdit_path.plan.files import load_plan
from sdit_path.sim.perturb import Hidden, Recording, perturb

PROGRAM = "GOLD_A"
#: as analyse reads a 1 kHz recording
OPTIONS = DIAGNOSIS


@pytest.fixture(scope="module")
def golden(golden_plans):
    plan = load_plan(golden_plans["fast"])
    return plan, build_context(plan, PROGRAM), load_error_set("paper_table2")


def _diagnose(golden, hidden, seed=1):
    plan, ctx, model = golden
    rec = Recording(lead_s=4.0, tail_s=2.0, clock_ppm=80.0, noise_um=0.25)
    trace, _ = perturb(plan, PROGRAM, model, hidden, rec, seed, ctx)
    return diagnose(plan, PROGRAM, trace, model, OPTIONS, ctx=ctx)


@pytest.mark.slow
def test_held_out_stretches_cover_every_kind(golden):
    """Every third stretch of the program held out every descending half of GOLD_A's
    sectors (period 3: node, rising half, falling half): the fit saw the ball only rise.
    Now a third of each kind - dwells, each sub-segment's place on each pass."""
    _, ctx, _ = golden
    held = held_stretches(ctx, 3)
    seg = ctx.segment
    starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    runs: Counter = Counter()
    kinds: dict[tuple, list[bool]] = {}
    for u, i in enumerate(starts):
        label = str(seg[i])
        kind = ("dwell",) if ctx.phase[i] == "dwell" else (label[-1], runs[label])
        runs[label] += 1
        kinds.setdefault(kind, []).append(bool(held[u]))
    moving = {k: v for k, v in kinds.items() if k != ("dwell",)}
    assert len(moving) == 4, kinds  # first and second half, on each of the two passes
    for kind, flags in kinds.items():
        assert 0 < sum(flags) < len(flags), (kind, flags)
    share = held[stretch_numbers(ctx)].mean()
    assert 0.25 < share < 0.4, share


@pytest.mark.slow
def test_a_play_is_sized_with_the_others_in_and_brings_no_spike(golden):
    """A play operator's width searched when it is chosen, before the bar length is in,
    comes out short, and the ramp it misses after every reversal comes back as a
    high-confidence reversal spike (hard case: test-play-sized-with-the-others).
    Searched again with every other finding in, the play stands alone."""
    d = _diagnose(golden, [Hidden("setup_offset", {"dx_um": -16.0, "dy_um": 5.0, "dz_um": -82.0}),
                           Hidden("bar_length", {"dL_um": -3.2}),
                           Hidden("backlash", {"axis": "Y", "play_um": 9.5})])
    named = {f.effect: f for f in d.findings}
    assert "reversal_spike" not in named, [(f.effect, f.parameters) for f in d.findings]
    play = named["backlash"]
    assert abs(play.parameters["play_Y_um"] - 9.5) < 0.2, play.parameters
    assert abs(play.nonlinear["width_Y_um"] - 9.5) < 0.6, play.nonlinear


@pytest.mark.slow
def test_the_mounting_is_tried_whole_when_neither_part_passes_alone(golden):
    """A set-up offset and a bar length that, on this layer, each fit the fitted
    stretches at the held-out ones' expense (a first geometry estimate had moved part
    of the centring into a constant): neither passed alone, the selection stopped short
    of the servo mismatch behind them and named a play and stick-slip instead."""
    d = _diagnose(golden, [Hidden("setup_offset", {"dx_um": 8.6, "dy_um": -3.3, "dz_um": -11.6}),
                           Hidden("bar_length", {"dL_um": -6.2}),
                           Hidden("servo_mismatch", {"axis": "X", "extra_lag_ms": -1.0})])
    named = [f.effect for f in d.findings]
    assert set(named) == {"setup_offset", "bar_length", "servo_mismatch"}, named
    mismatch = next(f for f in d.findings if f.effect == "servo_mismatch")
    assert abs(mismatch.parameters["lag_Y_minus_X_ms"] - 1.0) < 0.1, mismatch.parameters
    assert abs(next(f for f in d.findings if f.effect == "bar_length").parameters["dL_um"]
               + 6.2) < 0.2


def test_a_finding_whose_every_size_is_within_two_sigma_of_zero_is_not_named_with_confidence():
    from sdit_path.diagnose.ambiguity import judge_confidence
    from sdit_path.diagnose.results import FindingDraft as Finding

    def finding(std):
        f = Finding("vibration", "", {"frequency_hz": 8.0, "compliance_Y_um_per_m_s2": 0.91,
                                      "peak_Y_um": 0.95},
                    {"frequency_hz": 8.0, "damping": 0.24, "axis": "Y"}, ("deflection_Y",),
                    rms_before_um=0.30, rms_after_um=0.28, heldout_rms_before_um=0.30,
                    heldout_rms_after_um=0.28, delta_bic=900.0)
        f.uncertainty = {"frequency_hz": 2.3, "compliance_Y_um_per_m_s2": std,
                         "peak_Y_um": 0.58 * std / 0.91}
        judge_confidence(f)
        return f.confidence

    assert finding(0.03) == "high"
    assert finding(0.91) == "medium"


def test_a_scale_and_a_squareness_this_program_cannot_tell_apart_are_named_together():
    """SDIT5_C 8 of the typical blind set (a 24 urad XZ squareness) was read as a scale
    error of X and Z, the squareness 2 % behind: the finding names both and the program
    that separates them.  A runner-up well behind, or a pair a real machine has both of,
    leaves the findings as they are."""
    from sdit_path.diagnose.ambiguity import judge_confidence, merge_aliased
    from sdit_path.diagnose.results import FindingDraft as Finding

    def finding(effect, runner_up, ratio):
        f = Finding(effect, "", {"X_um_per_m": -147.0}, {}, ("scale_X",), rms_before_um=0.39,
                    rms_after_um=0.25, heldout_rms_before_um=0.36, heldout_rms_after_um=0.25,
                    delta_bic=900.0, runner_up=runner_up, runner_up_ratio=ratio)
        f.uncertainty = {"X_um_per_m": 6.5}
        judge_confidence(f)
        return f

    close = merge_aliased([finding("scale_mismatch", "squareness", 1.024)], {}, None,
                           np.array([]), np.array([]))
    assert close[0].ambiguous_with == ["squareness"]
    assert "direction cosine" in close[0].separate_by
    assert close[0].confidence != "high"
    behind = merge_aliased([finding("scale_mismatch", "squareness", 1.6)], {}, None,
                            np.array([]), np.array([]))
    assert behind[0].ambiguous_with == [] and behind[0].confidence == "high"
    both = merge_aliased([finding("scale_mismatch", "squareness", 3.0),
                           finding("squareness", "scale_mismatch", 4.0)], {}, None,
                          np.array([]), np.array([]))
    assert [f.effect for f in both] == ["scale_mismatch", "squareness"]
    assert all(not f.ambiguous_with for f in both)
