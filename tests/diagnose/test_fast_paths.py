"""The faster ways the alignment and the diagnosis compute what they computed before
(issue 16's benchmark): each against the way it replaced, on golden_small's GOLD_A."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.diagnose import align as align_mod
from sdit_path.diagnose.align import coarse, generic_columns, refine
from sdit_path.reading.context import build_context
from sdit_path.diagnose.columns import TrialModel, expected_reading
from sdit_path.diagnose.effects.generic import alignment_columns
from sdit_path.diagnose.effects import Samples, ServoMismatch, Vibration, linear_axes
from sdit_path.diagnose.effects.vibration import _mode_response
from sdit_path.errormodel.errorset import load_error_set
from sdit_path.plan.files import load_plan
from sdit_path.sim.perturb import Hidden, Recording, perturb

PROGRAM = "GOLD_A"


@pytest.fixture(scope="module")
def recorded(golden_plans):
    plan = load_plan(golden_plans["fast"])
    ctx = build_context(plan, PROGRAM)
    model = load_error_set("paper_table2")
    hidden = [Hidden("setup_offset", {"dx_um": 6.0, "dy_um": -4.0, "dz_um": 9.0}),
              Hidden("servo_mismatch", {"axis": "X", "extra_lag_ms": 1.0})]
    trace, _ = perturb(plan, PROGRAM, model, hidden,
                       Recording(lead_s=3.5, tail_s=2.0, clock_ppm=-70.0, noise_um=0.2), 3, ctx)
    expected = expected_reading(plan, ctx, model)
    X = generic_columns(ctx, expected, alignment_columns(plan, ctx))
    return plan, ctx, expected, X, np.asarray(trace.t_s, float), np.asarray(trace.delta_l_um, float)


@pytest.mark.slow
def test_the_direct_correlation_finds_what_the_transforms_found(recorded, monkeypatch):
    """A lead of seconds leaves a few dozen offsets: the coarse search correlates them
    with one matrix product; forced to the transforms it must find the same minima."""
    _, ctx, _, X, t_m, y = recorded
    direct = coarse(ctx, X, t_m, y, candidates=5)
    monkeypatch.setattr(align_mod, "DIRECT_CORRELATION", 0)
    transform = coarse(ctx, X, t_m, y, candidates=5)
    assert len(direct) == len(transform) == 5
    for (o1, p1), (o2, p2) in zip(direct, transform):
        assert abs(o1 - o2) < 1e-9 and p1 == p2, (direct, transform)
    step_ppm = 0.01 / ctx.duration_s * 1e6  # the rate grid's step
    assert abs(direct[0][0] - 3.5) < 0.05 and abs(direct[0][1] + 70.0) <= step_ppm, direct


@pytest.mark.slow
def test_gauss_newton_stops_at_a_hundredth_of_the_uncertainty(recorded, monkeypatch):
    """Stopping once a step is below 1 % of the timing's uncertainty lands within 2 % of
    it from where the search went on to rounding, with fewer residual evaluations."""
    _, ctx, _, X, t_m, y = recorded
    calls = []
    fit = align_mod._fit_rms
    monkeypatch.setattr(align_mod, "_fit_rms", lambda *a: calls.append(1) or fit(*a))
    quick = refine(ctx, X, t_m, y, 3.47, -20.0)
    n_quick = len(calls)
    calls.clear()
    full = refine(ctx, X, t_m, y, 3.47, -20.0, tolerance=0.0)
    assert n_quick <= len(calls), (n_quick, len(calls))
    assert abs(quick.offset_s - full.offset_s) < 0.02 * full.offset_std_s + 1e-6
    assert abs(quick.clock_ppm - full.clock_ppm) < 0.02 * full.clock_std_ppm + 0.01
    assert abs(quick.offset_s - 3.5) < 0.005, quick


def test_a_profiled_lag_overwrites_the_same_matrix(recorded):
    """The timing profile of a lag builds its model once and overwrites the lag's
    columns: every trial's matrix equals the one built afresh."""
    plan, ctx, expected, _, _, _ = recorded
    fixed = alignment_columns(plan, ctx, pose_only=True)
    allg = Samples(np.arange(ctx.n), ctx.t_s)
    eff = ServoMismatch()
    model = TrialModel(ctx, expected, fixed)
    for lag in (0.0, 10.0, 40.0, 3.0):
        cols = eff.columns(ctx, allg, {"common_lag_ms": lag})[0]
        fresh = generic_columns(ctx, expected, np.column_stack([fixed, cols]))
        assert np.array_equal(model.with_columns(cols), fresh), lag


def test_a_profile_leaves_open_what_fits_alike():
    """Along a timing parameter's profile, a value whose fit is worse by dchi2 <= 9 at
    a distance d leaves d / sqrt(max(dchi2, 1)) open, for the parameter and for what the
    finding fitted there; a value worse by more says nothing."""
    from sdit_path.diagnose.align import Alignment
    from sdit_path.diagnose.timing_profiles import _opened

    n, rms = 10_000, 0.2

    def fit(dchi2: float) -> Alignment:
        return Alignment(0.0, 0.0, 1e-3, 1.0, rms * np.sqrt(1.0 + dchi2 / n))

    fits = {2.0: fit(0.0), 3.0: fit(4.0), 1.0: fit(0.25), 9.0: fit(16.0)}
    found = {2.0: {"common_lag_ms": 2.0, "lag_Y_minus_X_ms": -0.80},
             3.0: {"common_lag_ms": 3.0, "lag_Y_minus_X_ms": -0.84},
             1.0: {"common_lag_ms": 1.0, "lag_Y_minus_X_ms": -0.79},
             9.0: {"common_lag_ms": 9.0, "lag_Y_minus_X_ms": -2.0}}
    out = _opened("common_lag_ms", 2.0, fits, found, n)
    assert out.std.keys() == {"common_lag_ms", "lag_Y_minus_X_ms"}
    assert out.std["common_lag_ms"] == pytest.approx(1.0)  # 1.0 fits alike: 1 ms away
    assert out.std["lag_Y_minus_X_ms"] == pytest.approx(0.02)  # 3.0: 0.04 at sqrt(4)
    # the slope through 1, 2 and 3 (9 fits worse, and is no neighbour)
    assert out.slope == pytest.approx({"lag_Y_minus_X_ms": np.polyfit(
        [1.0, 2.0, 3.0], [-0.79, -0.80, -0.84], 1)[0]})
    # read around another value, the distances and the worse fit's excess are from there
    # (1.0 fits better than 3.0 by 3.75: 2 ms at sqrt(3.75)); 9 is its neighbour
    there = _opened("common_lag_ms", 3.0, fits, found, n)
    assert there.std["common_lag_ms"] == pytest.approx(2.0 / np.sqrt(3.75), rel=1e-3)
    assert there.slope == pytest.approx({"lag_Y_minus_X_ms": np.polyfit(
        [1.0, 2.0, 3.0, 9.0], [-0.79, -0.80, -0.84, -2.0], 1)[0]})


@pytest.mark.slow
def test_a_profiled_lag_keeps_what_its_profile_leaves_open(recorded):
    """A servo mismatch's common lag profiled with the timing: the finding keeps, for
    the read-out, what the profile leaves open of the common lag and of the lag
    differences fitted along it (GOLD_A, X lagging 1 ms)."""
    from sdit_path.diagnose.effects.generic import pose_blocks
    from sdit_path.diagnose.results import FindingDraft
    from sdit_path.diagnose.timing_profiles import profile_timing

    plan, ctx, expected, X, t_m, y = recorded
    al = refine(ctx, X, t_m, y, 3.5, -70.0)
    eff = ServoMismatch()
    nl = {"common_lag_ms": 3.0, "second_order_lag_Y": -1.0, "second_order_lag_Z": -1.0}
    f = FindingDraft("servo_mismatch", eff.title, {}, nl, (),
                     0.0, 0.0, 0.0, 0.0, 0.0)
    profile_timing(ctx, [eff], expected, t_m, y, pose_blocks(plan, ctx), [f], al, None)
    opened = f.profile.std
    lags = [k for k in opened if k.startswith("lag_")]
    assert len(lags) == 2 and "common_lag_ms" in opened, opened
    # the lag is read within a sample (1 ms) of the truth, and a value a sample away
    # fits about as well: at least that much of it is open
    assert abs(f.nonlinear["common_lag_ms"] - 1.0) <= 1.0, f.nonlinear
    assert 0.4 <= opened["common_lag_ms"] <= 3.0, opened
    # the lag differences move along it, by far less than the 1 ms they are
    assert all(0.0 < opened[k] < 0.05 for k in lags), opened
    assert all(abs(f.profile.slope[k]) < 0.05 for k in lags), f.profile.slope


@pytest.mark.slow
def test_the_timing_s_uncertainty_is_carried_into_the_findings(recorded):
    """The read-out's findings take in what the timing's uncertainty carries: the
    change of each parameter between the fits with the start (then the clock) moved
    each way by its uncertainty, as the recording split afresh at those timings gives
    it; a lag difference moves with the start, the set-up far less."""
    import dataclasses

    from sdit_path.diagnose.effects import SetupOffset
    from sdit_path.diagnose.fitting import solve
    from sdit_path.diagnose.heldout import split_recording
    from sdit_path.diagnose.options import Options
    from sdit_path.diagnose.readout import _timing_spill

    plan, ctx, expected, X, t_m, y = recorded
    al = dataclasses.replace(refine(ctx, X, t_m, y, 3.5, -70.0), offset_std_s=1e-3,
                             clock_std_ppm=2.0)
    mismatch = ServoMismatch()
    nl = {"common_lag_ms": 1.0, "second_order_lag_Y": -1.0, "second_order_lag_Z": -1.0}
    chosen = [(SetupOffset(), {}, SetupOffset().columns(
        ctx, Samples(np.arange(3), ctx.t_s[:3]), {})[1]),
        (mismatch, nl, mismatch.columns(ctx, Samples(np.arange(3), ctx.t_s[:3]), nl)[1])]
    widths = [len(labels) for _, _, labels in chosen]
    slices = [slice(0, widths[0]), slice(widths[0], sum(widths))]
    opt = Options()
    split = split_recording(ctx, expected, t_m, y, al, opt)
    carried = _timing_spill(ctx, chosen, slices, expected, split.tau, split.gap, al)

    def fitted(moved):
        sp = split_recording(ctx, expected, t_m, y, moved, opt)
        S = Samples(sp.idx, sp.tau)
        beta = solve(np.column_stack([e.columns(ctx, S, n)[0] for e, n, _ in chosen]), sp.gap)
        return [e.parameters(beta[sl], lab, n, ctx) for (e, n, lab), sl in zip(chosen, slices)]

    want = [{} for _ in chosen]
    for move in ({"offset_s": 1e-3}, {"clock_ppm": 2.0}):
        up = fitted(dataclasses.replace(al, **{k: getattr(al, k) + v for k, v in move.items()}))
        down = fitted(dataclasses.replace(al, **{k: getattr(al, k) - v for k, v in move.items()}))
        for k, (a, b) in enumerate(zip(up, down)):
            for name, v in a.items():
                if isinstance(v, float) and name not in nl:
                    want[k][name] = want[k].get(name, 0.0) + ((v - b[name]) / 2) ** 2
    for got, exp in zip(carried, want):
        assert got.keys() >= exp.keys()
        for name, v in exp.items():
            # (the samples at the program's ends fall inside or out of a split afresh)
            assert np.sqrt(got[name]) == pytest.approx(np.sqrt(v), rel=0.05, abs=2e-4), (
                name, got[name], v)
    lag = np.sqrt(carried[1]["lag_Y_minus_X_ms"])
    assert 1e-4 < lag < 0.05, lag  # moves with a millisecond of start, by far less than 1 ms


def test_every_mode_at_once_reads_as_each_axis_alone(recorded):
    """A structural mode's columns, every axis filtered at once and read with one
    interpolation, against each axis filtered and interpolated on its own."""
    _, ctx, _, _, _, _ = recorded
    vib = Vibration()
    rng = np.random.default_rng(5)
    idx = np.sort(rng.choice(ctx.n - 1, 5000, replace=False))
    s = Samples(idx, ctx.t_s[idx] + 0.37e-3)
    dt = float(ctx.t_s[1] - ctx.t_s[0])
    for f_hz, zeta in ((9.0, 0.02), (83.0, 0.05), (240.0, 0.12)):
        got = vib._mode_columns(ctx, s, f_hz, zeta)
        want = np.column_stack([
            ctx.gain[idx, j] * np.interp(s.tau_s, ctx.t_s,
                                         _mode_response(vib._acc(ctx, j), dt, f_hz, zeta))
            for j in linear_axes(ctx)])
        scale = np.abs(want).max()
        assert scale > 0 and np.abs(got - want).max() <= 1e-9 * scale, (f_hz, zeta)


def test_the_ripple_search_sums_what_the_sines_gave():
    """The cyclic error's pitch search from complex sums stepped by multiplication gives
    the projection gains of the sine and cosine columns it replaced, to rounding."""
    from sdit_path.diagnose.effects.base import gain2 as _gain2, ripple_gains as _ripple_gains
    rng = np.random.default_rng(2)
    for span in (40.0, 400.0):
        x = rng.uniform(-span / 2, span / 2, 4000)
        g = rng.uniform(-1.0, 1.0, 4000)
        r = 0.3 * g * np.sin(2 * np.pi * x / 7.3 + 0.4) + rng.normal(0.0, 0.2, 4000)
        inv = np.arange(1 / 25, 1 / 4, 1 / (8 * span))
        ph = 2 * np.pi * x[None, :] * inv[:, None]
        sines = _gain2(g * np.sin(ph), g * np.cos(ph), r)
        sums = _ripple_gains(x, g, r, inv)
        assert np.abs(sums - sines).max() <= 1e-12 * sines.max()
        assert int(np.argmax(sums)) == int(np.argmax(sines))
        assert abs(1 / inv[int(np.argmax(sums))] - 7.3) < 0.3


# -- memory (issue 50): what is kept is bounded, and the numbers are the same -----------


@pytest.mark.parametrize("m", [1, 2, 3, 5, 8, 9, 11, 65, 76])
def test_column_rms_is_the_whole_matrix_mean_to_the_bit(m):
    X = np.random.default_rng(m).normal(size=(50_003, m)) * np.geomspace(1e-3, 1e3, m)
    assert np.array_equal(align_mod.column_rms(X), np.sqrt(np.mean(X * X, axis=0)))


def test_the_generic_columns_are_the_stacked_blocks_with_flat_ones_dropped(recorded):
    plan, ctx, expected = recorded[:3]
    extra = alignment_columns(plan, ctx)
    extra[:, 3] = 0.0  # flat: dropped
    X = generic_columns(ctx, expected, extra)
    base, spread = align_mod._generic_base(ctx)
    full = np.column_stack([expected[:, None], base, extra])
    keep = np.concatenate([[True], spread > 1e-9, np.ptp(extra, axis=0) > 1e-9])
    assert X.shape[1] == full.shape[1] - int((~keep).sum()) < full.shape[1]
    want = full[:, keep]
    assert np.array_equal(X, want)
    assert X.flags.f_contiguous == want.flags.f_contiguous  # BLAS sums in its layout's order


def test_a_context_cache_lets_the_least_recently_used_go_beyond_its_bound():
    from sdit_path.reading.context import ArrayCache

    cache = ArrayCache(limit_bytes=3 * 8000)
    for k in range(3):
        cache[k] = np.zeros(1000)
    assert cache[0] is not None  # 0 used: 1 is now the least recently used
    cache[3] = np.zeros(1000)
    assert list(cache) == [2, 0, 3] and cache.nbytes() <= cache.limit_bytes
    cache["big"] = np.zeros(10_000)  # alone beyond the bound: the newest stays
    assert list(cache) == ["big"]
    nested = cache.setdefault("pose", {})
    nested["a"] = np.zeros(10)
    assert cache["pose"] is nested


def test_an_effects_memo_keeps_the_newest_within_its_bytes(monkeypatch):
    from sdit_path.diagnose.effects import base

    monkeypatch.setattr(base, "MEMO_BYTES", 2 * 8000)
    cache: dict = {}
    made = []
    ctx = object()

    def make(v):
        made.append(v)
        return np.full(1000, v)

    for v in (1.0, 2.0, 3.0, 3.0):
        assert base.memo(cache, ctx, v, lambda: make(v))[0] == v
    assert made == [1.0, 2.0, 3.0] and len(cache) == 2


def test_sampling_a_tall_matrix_block_by_block_is_the_same_arithmetic():
    from sdit_path.reading.context import sample_at

    rng = np.random.default_rng(0)
    t = np.arange(60_000) * 1e-3
    X = rng.normal(size=(len(t), 5))
    tau = np.sort(rng.uniform(-1.0, 70.0, 40_001))
    x = np.clip(tau / 1e-3, 0.0, len(t) - 1.000001)
    i = x.astype(int)
    f = (x - i)[:, None]
    want = X[i] * (1 - f) + X[np.minimum(i + 1, len(t) - 1)] * f
    assert np.array_equal(sample_at(t, X, tau), want)
    assert np.array_equal(sample_at(t, X[:, 2], tau), want[:, 2])


def test_workers_are_started_as_memory_allows():
    from sdit_path.parallel import jobs_within, resident_mb

    here = resident_mb()
    assert here > 0
    assert jobs_within(None, 1e9, 4) == 4  # no bound
    assert jobs_within(here + 1000, 400, 4) == 2  # two fit beside this process
    assert jobs_within(here + 100, 400, 4) == 1  # one at least
    assert jobs_within(here + 1e6, 400, 3) == 3  # never more than asked


@pytest.mark.slow
def test_the_reversal_state_read_at_samples_is_what_every_sample_held(recorded):
    """The time since each axis' last reversal and its position there, read from the
    reversal indices at the samples asked for, are the arrays the context held for every
    sample (inf and NaN before the first reversal)."""
    from sdit_path.reading.context import reversals

    _, ctx, *_ = recorded
    assert sum(len(r) for r in ctx.reversal_index) >= 3
    every = np.arange(ctx.n)
    some = np.random.default_rng(4).integers(0, ctx.n, 300)
    for j in range(ctx.q.shape[1]):
        _, last = reversals(ctx.direction[:, j])
        ok = last >= 0
        since = np.full(ctx.n, np.inf)
        since[ok] = ctx.t_s[ok] - ctx.t_s[last[ok]]
        at = np.full(ctx.n, np.nan)
        at[ok] = ctx.q[last[ok], j]
        assert np.array_equal(ctx.since_reversal_s(every, j), since)
        assert np.array_equal(ctx.position_at_reversal(every, j), at, equal_nan=True)
        assert np.array_equal(ctx.since_reversal_s(some, j), since[some])
        flips = ctx.reversal_index[j]  # where the direction changes, and only there
        assert np.array_equal(flips, np.flatnonzero(np.diff(ctx.direction[:, j])) + 1)


def test_a_long_programs_context_made_where_read_is_the_context_held_whole(recorded,
                                                                           monkeypatch):
    """A program longer than TALL_ROWS keeps its bar directions, axis rates, gains and
    run edges as their recipe (reading/rows.py), its directions as int8 and its labels
    as codes: forced on
    GOLD_A, every value read the ways the effects read them (rows, rows of a column,
    whole columns, the whole array) is the held array's to the bit."""
    import dataclasses

    from sdit_path.reading import context as context_mod
    from sdit_path.reading.rows import Rows, RunEdge

    plan, whole = recorded[0], recorded[1]
    monkeypatch.setattr(context_mod, "TALL_ROWS", 0)
    tall = build_context(plan, PROGRAM)
    rows = np.r_[0, 1, 2, np.random.default_rng(3).integers(0, whole.n, 500), whole.n - 2,
                 whole.n - 1]
    made = []
    for f in dataclasses.fields(whole):
        a, b = getattr(whole, f.name), getattr(tall, f.name)
        if isinstance(b, (Rows, RunEdge)):
            made.append(f.name)
        if f.name == "written_um" and not a.any():
            assert len(b) == 0  # none: what every reader takes for zeros
            continue
        if not isinstance(a, np.ndarray) or a.dtype == object or len(a) != whole.n:
            continue
        assert np.array_equal(np.asarray(b), a) and np.array_equal(b[rows], a[rows]), f.name
        assert np.array_equal(b[rows[5]], a[rows[5]]), f.name
        if a.ndim == 2:
            for j in range(a.shape[1]):
                assert np.array_equal(b[:, j], a[:, j]) and np.array_equal(b[rows, j], a[rows, j])
            assert np.array_equal(b[:, [2, 0]], a[:, [2, 0]]), f.name
    assert set(made) == {"u", "qdot", "gain", "run_start_mm", "run_end_mm", "u_bed"}
    assert tall.direction.dtype == np.int8
    for name in ("segment", "phase"):  # held as codes of their labels
        a, b = getattr(whole, name), getattr(tall, name)
        assert not isinstance(b, np.ndarray) and b[rows[5]] == a[rows[5]]
        assert np.array_equal(b[rows], a[rows]) and np.array_equal(np.asarray(b), a)
        assert np.array_equal(b[5:-3], a[5:-3])
        for label in ("dwell", "nothing of the sort", str(a[rows[7]])):
            assert np.array_equal(b == label, a == label)
            assert np.array_equal(b != label, a != label)
    assert tall.reversal_index and all(np.array_equal(p, q) for p, q in
                                        zip(tall.reversal_index, whole.reversal_index))
    assert tall.observable == whole.observable


def test_a_long_programs_effects_read_what_they_read_on_the_context_held_whole(
        recorded, monkeypatch):
    """The effects whose columns read a tall program's context where it is made (the
    rates, gains, directions, reversals, labels) or filter it a block at a time (a
    mode's response, the lags, the smoothing) give the columns they give on the context
    held whole, to the bit: forced on GOLD_A, at the samples of a recording, and on
    every sample made a block of samples at a time."""
    from sdit_path.diagnose import effects
    from sdit_path.diagnose.columns import every_sample
    from sdit_path.reading import context as context_mod

    plan, ctx, _, _, t_m, _ = recorded
    monkeypatch.setattr(context_mod, "TALL_ROWS", 0)
    tctx = build_context(plan, PROGRAM)
    tau = np.sort(np.random.default_rng(5).uniform(0.0, float(ctx.t_s[-1]), 3000))
    s = Samples(context_mod.nearest_samples(ctx, tau), tau)
    x = ctx.axis_names
    hints = {f"second_order_lag_{a}": 0.3 + 0.2 * i for i, a in enumerate(x[1:3])}
    cases = [(effects.ServoMismatch(), {}), (effects.ServoMismatch(), {"common_lag_ms": 1.7}),
             (effects.ServoMismatch(), {"common_lag_ms": 1.7, **hints}),
             (effects.ServoMismatch(), {"common_lag_ms": 0.0, **hints}),
             (effects.ServoLag(), {"tau_ms": 12.0}),
             (effects.ContourSmoothing(), {"sigma_ms": 8.0}),
             (effects.ContourSmoothing(), {"window_mm": 3.0}),
             (effects.ReversalSpike(), {"tau_ms": 25.0, "onset_mm_s": 0.05}),
             (effects.Backlash(), {f"width_{a}_um": 6.5 for a in x[:3]}),
             (effects.LateralPlay(), {}), (effects.StickSlip(), None),
             (effects.ThermalDrift(), {}), (effects.SetupOffset(), {})]
    for eff, nl in cases:
        nl = eff.search(ctx, s, np.random.default_rng(6).normal(size=len(tau))) \
            if nl is None else nl
        a, b = eff.columns(ctx, s, nl)[0], type(eff)().columns(tctx, s, nl)[0]
        assert np.array_equal(a, b), (eff.name, nl)
        # on every sample, a block of samples at a time (what the timing's model reads)
        whole = eff.columns(ctx, Samples(np.arange(ctx.n), ctx.t_s), nl)[0]
        assert np.array_equal(every_sample(type(eff)(), tctx, nl)[0], whole), (eff.name, nl)
    for axes in (None, [linear_axes(ctx)[1]]):
        a = Vibration()._mode_columns(ctx, s, 37.0, 0.05, axes=axes)
        assert np.array_equal(a, Vibration()._mode_columns(tctx, s, 37.0, 0.05, axes=axes))


@pytest.mark.slow
def test_a_long_programs_model_made_where_read_is_the_model_held_whole(recorded, monkeypatch):
    """A tall program (longer than TALL_ROWS) has its generic and alignment columns made
    at the rows read (diagnose/tall.py: the pose blocks interpolated from their grid,
    the generic base and the dynamic blocks each at those samples): forced on GOLD_A,
    every row is the row of the model held whole, a product with it the same to
    rounding, the coarse search's column scales and block means the same to rounding,
    and the alignment the same to far below its uncertainty."""
    from sdit_path.diagnose.effects import generic
    from sdit_path.diagnose.fitting import noise_estimate
    from sdit_path.diagnose.tall import Interpolated, Made, RowModel
    from sdit_path.reading import context as context_mod

    plan, ctx, expected, X, t_m, y = recorded
    whole = generic_columns(ctx, expected, generic.alignment_blocks(plan, ctx), consume=True)
    monkeypatch.setattr(context_mod, "TALL_ROWS", 0)
    tctx = build_context(plan, PROGRAM)
    assert tctx.tall and not ctx.tall
    blocks = generic.alignment_blocks(plan, tctx)
    pose = [b for b in blocks if isinstance(b, Interpolated)]
    made = [b for b in blocks if isinstance(b, Made)]
    assert len(pose) + len(made) == len(blocks) and pose and made
    for b in pose + made:
        assert np.array_equal(b.spread(), np.ptp(b.full(), axis=0))
    tall = generic_columns(tctx, expected, blocks, consume=True)
    assert isinstance(tall, RowModel) and tall.shape == whole.shape
    assert isinstance(tall.parts[tall.generic - 1], Made)  # the generic base
    rows = np.r_[0, 1, 17, np.random.default_rng(1).integers(0, ctx.n, 500), ctx.n - 1]
    assert np.array_equal(tall[rows], whole[rows])
    assert np.array_equal(tall[ctx.n - 1], whole[ctx.n - 1])
    # its generic part is what the coarse search of a long program reads
    assert np.array_equal(tall.generic_part()[rows], generic_columns(ctx, expected)[rows])
    beta = np.random.default_rng(2).normal(size=whole.shape[1])
    assert np.allclose(tall @ beta, whole @ beta, rtol=0, atol=1e-12 * np.abs(whole).max())
    assert np.allclose(tall.product_at(rows, beta), (whole @ beta)[rows], rtol=0,
                       atol=1e-12 * np.abs(whole).max())
    unit = align_mod.column_rms(whole)
    assert np.allclose(tall.column_rms(), unit, rtol=1e-12)
    per, nb = 100, ctx.n // 100
    means = np.column_stack([align_mod._block_mean(whole[:, a] / unit[a], np.ones(ctx.n),
                                                   np.arange(nb + 1) * per)[0]
                             for a in range(whole.shape[1])])
    assert np.allclose(tall.block_means(per, nb, unit), means, rtol=0, atol=1e-10)
    # the model's rate where the timing reads it, made at those rows alone
    tau = np.sort(np.random.default_rng(4).uniform(ctx.t_s[0], ctx.t_s[-1], 2000))
    assert np.allclose(align_mod._rate_at(tctx, tall, beta, tau),
                       align_mod._rate_at(ctx, whole, beta, tau), rtol=1e-9,
                       atol=1e-9 * np.abs(whole @ beta).max())
    ok = np.isfinite(y)
    noise = noise_estimate(y[ok], t_m[ok])
    a = align_mod.align(ctx, expected, t_m, y, model=whole, extra=True, noise_um=noise)
    b = align_mod.align(tctx, expected, t_m, y,
                        extra=lambda: generic.alignment_blocks(plan, tctx), noise_um=noise)
    assert abs(a.offset_s - b.offset_s) < 1e-3 * a.offset_std_s
    assert abs(a.clock_ppm - b.clock_ppm) < 1e-3 * a.clock_std_ppm
