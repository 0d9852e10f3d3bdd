"""Speed changes in bands: the band formula is what ruckig plans, and a ramp's slow
part uses the budget it has at its own speed while every window's rows still hold."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.timing.limits import Budget, PathLimits
from sdit_path.timing.profile import _band, plan_chain, plan_velocity


@pytest.mark.parametrize("seed", range(4))
def test_band_formula_matches_ruckigs_velocity_profile(seed):
    rng = np.random.default_rng(seed)
    for _ in range(50):
        a_max, j_max = rng.uniform(50, 2000), rng.uniform(500, 50000)
        v0 = rng.uniform(0, 100)
        v1 = v0 + rng.uniform(0.1, 40)
        # end accelerations the band admits: |a1^2 - a0^2| <= 2 j (v1 - v0)
        a0 = min(a_max, rng.uniform(0, 1) * np.sqrt(2 * j_max * (v1 - v0)))
        a1 = min(a_max, rng.uniform(0, 1) * np.sqrt(a0 * a0 + 2 * j_max * (v1 - v0)))
        a0 = min(a0, np.sqrt(a1 * a1 + 2 * j_max * (v1 - v0)))
        length, duration = _band(v0, a0, v1, a1, a_max, j_max)
        lim = PathLimits(v1, a_max, j_max, "feed")
        up = plan_velocity(v0, a0, v1, a1, lim, "test")
        down = plan_velocity(v1, -a1, v0, -a0, lim, "test")
        for prof in (up, down):
            assert prof.length_mm == pytest.approx(length, rel=1e-9, abs=1e-12)
            assert prof.duration_s == pytest.approx(duration, rel=1e-9, abs=1e-12)
            _, v, a, _, _ = prof.evaluate(np.linspace(0.0, prof.duration_s, 2001))
            assert v.min() >= v0 - 1e-9 and v.max() <= v1 + 1e-9
            assert np.abs(a).max() <= a_max * (1 + 1e-12)


def _curved_windows(count: int = 24) -> tuple[Budget, list]:
    # one axis on a 10 mm radius: acceleration left falls with speed, a_max - q'' v^2
    bud = Budget(np.array([1.0]), np.array([0.1]), np.array([0.002]), np.array([1000.0]),
                 np.array([10000.0]), 0.95 * np.sqrt(1000.0 / 0.1), "X curvature")
    return bud, [(2.0, bud)] * count


def test_a_ramp_is_not_held_to_the_budget_of_its_top_speed():
    """The slow part of a speed-up accelerates harder than the budget at the top speed
    allows (the constant-limit planner held the whole ramp to that), and the axis rows
    hold at every instant at the speed the path actually has."""
    bud, windows = _curved_windows()
    chain = plan_chain(windows, "test")
    t = np.linspace(0.0, chain.duration_s, 200001)
    s, v, a, j, _ = chain.evaluate(t)
    assert s[-1] == pytest.approx(48.0, abs=1e-9) and abs(v[-1]) < 1e-9
    top = v.max()
    assert top > 0.9 * bud.v_cap
    a_top, _ = bud.at(top)
    slow = v < 0.4 * top
    assert a[slow].max() > 2.0 * a_top, (a[slow].max(), a_top)
    m1, m2, m3 = 1.0, 0.1, 0.002
    assert np.max(m2 * v ** 2 + m1 * np.abs(a)) <= 1000.0 * (1 + 1e-9)
    assert np.max(m3 * v ** 3 + 3 * m2 * v * np.abs(a) + m1 * np.abs(j)) <= 10000.0 * (1 + 1e-9)
    # the chain is continuous in position, speed and acceleration
    assert np.abs(np.diff(s)).max() <= top * (t[1] - t[0]) * (1 + 1e-6)
    assert np.abs(np.diff(v)).max() <= 1000.0 * (t[1] - t[0]) * (1 + 1e-6)
