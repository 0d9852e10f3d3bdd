"""The time-optimal speed law (sdit_path.timing.topp): quicker than the windows where a
crest binds, every limit held between its cells, its motion consistent with itself,
and a law shared by runs that are mirror images or run backwards."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sdit_path.config import load_config, sample_path
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder, Run
from sdit_path.timing import topp
from sdit_path.timing.profile import plan_chain
from sdit_path.timing.topp import SpeedLaw
from sdit_path.timing.trajectory import RunGeometry, RunParameter, Timer


@pytest.fixture(scope="module")
def crest_run():
    """The first S-curve of the top layer of the 3-axis sample at F5000, where the
    windows' plan crosses the crest at a speed set by the jerk of the axis along it."""
    base = load_config(sample_path("vmc_3axis.toml"))
    cfg = dataclasses.replace(base, test=dataclasses.replace(base.test, feed_mm_per_min=5000.0))
    hemi = partition(cfg)
    path = PathBuilder(cfg, hemi).layer_path(hemi.layers[-1])
    run = next(i for i in path.items if isinstance(i, Run) and i.pieces[0].id.startswith("E1"))
    timer = Timer(cfg)
    geo = RunGeometry(run)
    return cfg, timer, geo


def test_the_speed_law_beats_the_windows_on_a_crest(crest_run):
    _, timer, geo = crest_run
    prof, param, _ = timer.time_run(geo, None, "crest")
    windows, _ = timer.run_windows(geo, None, RunParameter(geo.length_mm))
    chain = plan_chain(windows, "crest")
    assert isinstance(prof, SpeedLaw) and param.identity
    # the independent reference (bench/timing_optimum.py, IPOPT) takes 0.851 s here
    assert prof.duration_s < 0.90 * chain.duration_s, (prof.duration_s, chain.duration_s)
    assert prof.length_mm == pytest.approx(geo.length_mm, abs=1e-9)


def test_the_law_moves_as_its_derivatives_say(crest_run):
    _, timer, geo = crest_run
    law, _, _ = timer.time_run(geo, None, "crest")
    t = np.linspace(0.0, law.duration_s, 200001)
    s, v, a, j, _ = law.evaluate(t)
    dt = t[1] - t[0]
    assert s[0] == 0.0 and s[-1] == pytest.approx(law.length_mm, abs=1e-9)
    assert v[0] == pytest.approx(0.0, abs=1e-9) and v[-1] == pytest.approx(0.0, abs=1e-6)
    assert np.all(np.diff(s) >= -1e-12)
    # speed and acceleration are the derivatives of position and speed
    assert np.abs(np.gradient(s, dt)[1:-1] - v[1:-1]).max() < 1e-3
    assert np.abs(np.gradient(v, dt)[1:-1] - a[1:-1]).max() < 0.5
    # the jerk integrates to the acceleration (it jumps at cell edges)
    integrated = a[0] + np.concatenate([[0.0], np.cumsum(0.5 * (j[1:] + j[:-1]) * dt)])
    assert np.abs(integrated - a).max() < 0.01 * np.abs(a).max()


def test_every_limit_holds_between_the_cells(crest_run):
    """Axis velocity, acceleration and jerk through the run's exact derivatives, 40
    points per cell (the solver holds them at the cells' ends and checks nine)."""
    cfg, timer, geo = crest_run
    law, _, _ = timer.time_run(geo, None, "crest")
    jet = timer.run_jet(geo, None, law.s, points=41)
    k = np.repeat(np.arange(len(law.c)), 41)
    f = np.tile(jet.frac, len(law.c))
    tau = _time_in_cell(law, k, f)
    s, v, a, j = law.state(k, tau)
    q1, q2, q3 = (q.reshape(-1, q.shape[-1]) for q in (jet.q1, jet.q2, jet.q3))
    v_, a_, j_ = v[:, None], a[:, None], j[:, None]
    vel = np.abs(q1 * v_) / timer.v_lim
    acc = np.abs(q2 * v_ ** 2 + q1 * a_) / timer.a_lim
    jerk = np.abs(q3 * v_ ** 3 + 3 * q2 * v_ * a_ + q1 * j_) / timer.j_lim
    assert vel.max() <= 1.0 and acc.max() <= 1.0
    assert jerk.max() <= 1.0, jerk.max()
    assert jerk.max() > 0.95  # and the jerk is what binds
    assert v.max() <= cfg.test.feed_mm_per_min / 60.0


def _time_in_cell(law: SpeedLaw, k: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Time after the start of cell k at which the law is ``frac`` of the way across."""
    target = law.s[k] + frac * (law.s[k + 1] - law.s[k])
    lo, hi = np.zeros(len(k)), law.t[k + 1] - law.t[k]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = law.state(k, mid)[0] < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def test_a_law_runs_backwards_as_the_reversed_path(crest_run):
    _, timer, geo = crest_run
    law, _, _ = timer.time_run(geo, None, "crest")
    back = law.reversed()
    t = np.linspace(0.0, law.duration_s, 2001)
    s, v, a, j, _ = law.evaluate(t)
    sb, vb, ab, jb, _ = back.evaluate(law.duration_s - t)
    assert back.duration_s == pytest.approx(law.duration_s, rel=1e-12)
    assert np.abs(sb - (law.length_mm - s)).max() < 1e-9
    assert np.abs(vb - v).max() < 1e-6
    assert np.abs(ab + a).max() < 1e-3


def test_a_law_is_taken_again_only_where_it_holds(crest_run):
    """A law found for one run serves another on the same cells if it keeps that run's
    limits; with the jerk limit halved it does not."""
    _, timer, geo = crest_run
    law, _, _ = timer.time_run(geo, None, "crest")
    jet = timer.run_jet(geo, None, law.s)
    args = (timer.v_lim, timer.a_lim)
    assert topp.holds(law, jet, *args, timer.j_lim, timer.feed)
    assert not topp.holds(law, jet, *args, 0.5 * timer.j_lim, timer.feed)
    assert not topp.holds(law, jet, *args, timer.j_lim, 0.9 * timer.feed)


def test_feed_bound_runs_keep_the_windows_plan():
    """At the samples' F600 nothing but the feed binds: no programme is solved."""
    cfg = load_config(sample_path("vmc_3axis.toml"))
    hemi = partition(cfg)
    timer = Timer(cfg)
    path = PathBuilder(cfg, hemi).layer_path(hemi.layers[-1])
    timed = timer.time_layer(path)
    assert not any(isinstance(getattr(i, "profile", None), SpeedLaw) for i in timed.items)
    assert not timer._laws
