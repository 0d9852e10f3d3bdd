"""Realistic "measured" traces: the simulated geometry plus hidden effects acting on
the machine (servo filters, play operators, friction pulses, drift, vibration, ...),
recorded by an instrument that starts early, runs on its own clock and drops samples.

The effects are simulated physically on the machine axes and the exact error chain,
not with the diagnosis's regressors.  The truth goes to a separate value (and file);
the trace carries none of it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from ..errormodel.chain import actual_ball
from ..errormodel.errorset import ErrorSet
from ..errormodel.model import ModelOptions, build_model, values_vector
from ..errors import ConfigError
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..reading.context import Context, build_context
from ..reading.trace import Trace

#: the effects of the diagnosis library this simulator has physics for, in the library's
#: order (the seeded draws pick from it by position); the diagnosis never reaches back
#: here, and ``tests/test_architecture.py`` checks that the two name the same effects
IN_LIBRARY = ("setup_offset", "bar_length", "thermal_drift", "servo_lag", "servo_mismatch",
              "backlash", "reversal_spike", "lateral_play", "cyclic_error", "vibration",
              "stick_slip", "squareness", "scale_mismatch", "contour_smoothing")
OUTSIDE = ("bump", "step", "straightness", "vibration_burst")


@dataclass(frozen=True, slots=True)
class Hidden:
    """One hidden effect: ``name`` and its parameters (physical units)."""

    name: str
    params: dict

    @property
    def in_library(self) -> bool:
        return self.name in IN_LIBRARY


@dataclass(frozen=True, slots=True)
class Recording:
    lead_s: float = 5.0
    tail_s: float = 3.0
    clock_ppm: float = 0.0
    rate_hz: float = 1000.0
    noise_um: float = 0.2
    quantisation_um: float = 0.1
    dropout_fraction: float = 0.0002


@dataclass(frozen=True, slots=True)
class Truth:
    effects: tuple[Hidden, ...]
    recording: Recording
    contributions: dict = field(default_factory=dict)  # name -> (n,) um on the trajectory grid


# ------------------------------------------------------------------ drawing by seed

def _logu(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _sign(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


def draw_effect(name: str, rng: np.random.Generator, ctx: Context) -> Hidden:
    """Magnitudes from the domain brief (typical to bad, healthy machining centre)."""
    lin = [ctx.axis_names[j] for j in ctx.linear]
    moving_lin = [ctx.axis_names[j] for j in ctx.linear if np.ptp(ctx.q[:, j]) > 1.0]
    rev = [ctx.axis_names[j] for j in ctx.linear if len(ctx.reversal_times[j])] or moving_lin
    if name == "setup_offset":
        p = {f"d{a}_um": _sign(rng) * _logu(rng, 3.0, 100.0) for a in "xyz"}
    elif name == "bar_length":
        p = {"dL_um": _sign(rng) * _logu(rng, 1.0, 20.0)}
    elif name == "thermal_drift":
        p = {"z_um_per_h": _logu(rng, 10.0, 40.0) * _sign(rng),
             "x_um_per_h": rng.uniform(-10, 10), "y_um_per_h": rng.uniform(-10, 10),
             "warmup_h": rng.uniform(0.5, 2.0), "elapsed_h": rng.uniform(0.0, 1.0)}
    elif name == "servo_lag":
        p = {"kv_per_s": rng.uniform(16.7, 50.0)}
    elif name == "servo_mismatch":
        a = str(rng.choice(moving_lin))
        p = {"axis": a, "extra_lag_ms": _logu(rng, 0.1, 1.5) * _sign(rng)}
    elif name == "backlash":
        p = {"axis": str(rng.choice(rev)), "play_um": _logu(rng, 2.0, 15.0)}
    elif name == "reversal_spike":
        p = {"axis": str(rng.choice(rev)), "height_um": _logu(rng, 2.0, 15.0),
             "tau_ms": _logu(rng, 10.0, 100.0), "rise_ms": rng.uniform(1.0, 4.0)}
    elif name == "lateral_play":
        j = str(rng.choice(rev))
        k = str(rng.choice([a for a in moving_lin if a != j] or lin))
        p = {"reversing_axis": j, "axis": k, "play_um": _logu(rng, 1.5, 6.0)}
    elif name == "cyclic_error":
        p = {"axis": str(rng.choice(moving_lin)), "pitch_mm": rng.uniform(5.0, 20.0),
             "amplitude_um": _logu(rng, 0.4, 2.0), "phase_rad": rng.uniform(0, 2 * np.pi),
             "second_harmonic": rng.uniform(0.0, 0.15)}
    elif name == "vibration":
        p = {"axis": str(rng.choice(lin)), "frequency_hz": _logu(rng, 10.0, 200.0),
             "amplitude_um": _logu(rng, 0.3, 3.0), "phase_rad": rng.uniform(0, 2 * np.pi)}
    elif name == "stick_slip":
        p = {"axis": str(rng.choice(rev)), "amplitude_um": _logu(rng, 0.8, 3.0),
             "period_ms": _logu(rng, 20.0, 150.0)}
    elif name == "squareness":
        planes = [n for n in ("EC0Y", "EB0Z", "EA0Z")]
        p = {"parameter": str(rng.choice(planes)), "urad": _sign(rng) * _logu(rng, 8.0, 60.0)}
    elif name == "scale_mismatch":
        p = {"axis": str(rng.choice(moving_lin)), "um_per_m": _sign(rng) * _logu(rng, 8.0, 40.0)}
    elif name == "contour_smoothing":
        p = {"shortcut_um": _logu(rng, 1.0, 5.0)}
    elif name == "bump":
        p = {"count": int(rng.integers(1, 4)), "height_um": _logu(rng, 3.0, 10.0),
             "width_s": rng.uniform(0.1, 0.6), "seed": int(rng.integers(1 << 30))}
    elif name == "step":
        p = {"height_um": _sign(rng) * _logu(rng, 2.0, 6.0), "at_fraction": rng.uniform(0.2, 0.8)}
    elif name == "straightness":
        p = {"parameter": str(rng.choice(["EYX.P3", "EZX.P3", "EXY.P3", "EZY.P3"])),
             "um": _sign(rng) * _logu(rng, 3.0, 10.0)}
    elif name == "vibration_burst":
        p = {"frequency_hz": _logu(rng, 20.0, 150.0), "amplitude_um": _logu(rng, 1.0, 4.0),
             "duration_s": rng.uniform(1.0, 3.0), "at_fraction": rng.uniform(0.1, 0.9)}
    else:
        raise ConfigError("--effect", f"unknown effect {name!r}; known: "
                                      f"{', '.join(IN_LIBRARY + OUTSIDE)}")
    return Hidden(name, p)


def draw_case(seed: int, ctx: Context, kind: str | None = None) -> tuple[str, list[Hidden]]:
    """A blind case: ``kind`` in none / one / several / outside (drawn when None)."""
    rng = np.random.default_rng([seed, 17])
    if kind is None:
        kind = str(rng.choice(["none", "one", "one", "several", "outside"]))
    if kind == "none":
        return kind, []
    if kind == "one":
        return kind, [draw_effect(str(rng.choice(IN_LIBRARY)), rng, ctx)]
    if kind == "several":
        names = rng.choice(IN_LIBRARY, size=int(rng.integers(2, 4)), replace=False)
        return kind, [draw_effect(str(n), rng, ctx) for n in names]
    if kind == "outside":
        return kind, [draw_effect(str(rng.choice(OUTSIDE)), rng, ctx)]
    raise ValueError(kind)


def draw_recording(seed: int) -> Recording:
    rng = np.random.default_rng([seed, 29])
    return Recording(lead_s=rng.uniform(1.0, 20.0), tail_s=rng.uniform(1.0, 10.0),
                     clock_ppm=rng.uniform(-200.0, 200.0), noise_um=rng.uniform(0.1, 0.3))


def parse_effect(text: str) -> Hidden:
    """``name:key=value,key=value`` (values numbers or axis names)."""
    name, _, rest = text.partition(":")
    params = {}
    for item in filter(None, (x.strip() for x in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise ConfigError("--effect", f"{text!r}: expected key=value, got {item!r}")
        try:
            params[key.strip()] = float(value)
        except ValueError:
            params[key.strip()] = value.strip()
    name = name.strip()
    if name not in IN_LIBRARY + OUTSIDE:
        raise ConfigError("--effect", f"unknown effect {name!r}; known: "
                                      f"{', '.join(IN_LIBRARY + OUTSIDE)}")
    return Hidden(name, params)


# ------------------------------------------------------------------ physics

def _first_order(x: np.ndarray, tau_s: float, dt: float) -> np.ndarray:
    """Output of a first-order lag ``tau_s`` (Tustin) driven by ``x``, starting at rest."""
    if tau_s == 0:
        return x.copy()
    k = 2.0 * tau_s / dt
    y = lfilter([1.0, 1.0], [1.0 + k, 1.0 - k], x - x[0])
    return y + x[0]


def hidden_and_recording(ctx: Context, effects: list[str], seed: int | None,
                         noise_um: float | None = None, lead_s: float | None = None,
                         clock_ppm: float | None = None) -> tuple[list[Hidden], Recording]:
    """What ``perturb`` hides and how it records.  ``effects``: ``name:key=value,...``
    each (the parameters not given drawn, seeded by ``seed`` or 0); none and a ``seed``:
    a whole case drawn from it.  The recording is drawn from ``seed`` (or the defaults),
    with the ``noise_um``, ``lead_s`` and ``clock_ppm`` given kept."""
    if seed is not None and not effects:
        _, hidden = draw_case(seed, ctx)
    else:
        hidden = [parse_effect(e) for e in effects]
    # parameters not given are drawn (seeded), the given ones kept
    rng = np.random.default_rng([seed or 0, 5])
    drawn = [draw_effect(h.name, rng, ctx).params for h in hidden]
    for h, d in zip(hidden, drawn):
        unknown = sorted(set(h.params) - set(d))
        if unknown:
            raise ConfigError("--effect", f"{h.name}: unknown parameter(s) {', '.join(unknown)}; "
                                          f"expected some of {', '.join(d)}")
    hidden = [Hidden(h.name, {**d, **h.params}) for h, d in zip(hidden, drawn)]
    rec = draw_recording(seed) if seed is not None else Recording()
    changes = {k: v for k, v in (("noise_um", noise_um), ("lead_s", lead_s),
                                 ("clock_ppm", clock_ppm)) if v is not None}
    return hidden, dataclasses.replace(rec, **changes)


def _play(x: np.ndarray, width: float, first_dir: float) -> np.ndarray:
    y = np.empty_like(x)
    h = width / 2.0
    cur = x[0] - h * first_dir
    for i, xi in enumerate(x.tolist()):
        if cur < xi - h:
            cur = xi - h
        elif cur > xi + h:
            cur = xi + h
        y[i] = cur
    return y


def _axis(ctx: Context, name: str) -> int:
    try:
        return ctx.axis_names.index(str(name))
    except ValueError:
        raise ConfigError("--effect", f"axis {name!r} is not a machine axis "
                                      f"({', '.join(ctx.axis_names)})") from None


def _smooth_axes(ctx: Context, q: np.ndarray, window_mm: float) -> np.ndarray:
    out = q.copy()
    h = window_mm / 2.0
    run_id = ctx.run_id()
    for rid in range(int(run_id.max()) + 1):
        sel = np.flatnonzero(run_id == rid)
        if len(sel) < 3:
            continue
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(ctx.ball_mm[sel], axis=0), axis=1))]
        for j in range(q.shape[1]):
            x = q[sel, j]
            cum = np.r_[0.0, np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(s))]
            lo, hi = np.clip(s - h, 0, s[-1]), np.clip(s + h, 0, s[-1])
            out[sel, j] = (np.interp(hi, s, cum) - np.interp(lo, s, cum)) / np.maximum(hi - lo, 1e-12)
    return out


def perturb(plan: PlanFiles, program: str, model: ErrorSet | None, effects: list[Hidden],
            recording: Recording, seed: int = 0, ctx: Context | None = None
            ) -> tuple[Trace, Truth]:
    """The measured trace (instrument time) and the truth (kept apart)."""
    cfg = plan.config
    kin = Kinematics(cfg.machine)
    ctx = ctx or build_context(plan, program)
    t = ctx.t_s
    dt = float(np.median(np.diff(t)))
    n = ctx.n
    # geometry: the model's values plus hidden geometric effects
    values = dict(model.as_dict()) if model else {}
    opts = model.options if model else ModelOptions(squareness=False, location=False)
    geo: dict[str, float] = {}
    for e in effects:
        if e.name == "squareness":
            geo[e.params["parameter"]] = geo.get(e.params["parameter"], 0.0) + float(e.params["urad"])
        elif e.name == "scale_mismatch":
            a = str(e.params["axis"])
            lo, hi = plan.tested_travel()[a]
            geo[f"E{a}{a}.P1"] = float(e.params["um_per_m"]) * (hi - lo) / 2.0 * 1e-3
        elif e.name == "straightness":
            geo[str(e.params["parameter"])] = float(e.params["um"])
    order = max(opts.linear_order, 3 if any(k.endswith(".P3") for k in geo) else
                (1 if geo else 0))
    opts = ModelOptions(opts.linear_basis, order, opts.rotary_order,
                        opts.squareness or any(k[2] == "0" for k in geo), opts.location)
    emodel = build_model(cfg.machine, plan.tested_travel(), opts)

    def reading(q, extra_geo, pivot_shift_mm, dl_um):
        vals = dict(values)
        for k, v in extra_geo.items():
            vals[k] = vals.get(k, 0.0) + v
        theta = values_vector(emodel, vals)
        ball = actual_ball(kin, emodel, theta, q)
        piv = ctx.pivot_mm + pivot_shift_mm
        return (np.linalg.norm(ball - piv, axis=1) - cfg.ballbar.bar_length_mm) * 1e3 + dl_um

    q0 = ctx.q
    zero_shift = np.zeros((n, 3))
    base = reading(q0, {}, zero_shift, 0.0)

    def contribution(e: Hidden) -> np.ndarray:
        q = q0.copy()
        shift = np.zeros((n, 3))
        dl = np.zeros(n)
        g: dict[str, float] = {}
        p = e.params
        if e.name == "setup_offset":
            shift += np.array([p["dx_um"], p["dy_um"], p["dz_um"]]) * 1e-3
        elif e.name == "bar_length":
            dl += p["dL_um"]
        elif e.name == "thermal_drift":
            th = t / 3600.0 + p["elapsed_h"]
            warm = p["warmup_h"] * (1 - np.exp(-th / p["warmup_h"]))
            warm -= p["warmup_h"] * (1 - np.exp(-p["elapsed_h"] / p["warmup_h"]))
            lin = t / 3600.0
            shift -= np.column_stack([p["x_um_per_h"] * lin, p["y_um_per_h"] * lin,
                                      p["z_um_per_h"] * warm]) * 1e-3
        elif e.name == "servo_lag":
            for j in range(q.shape[1]):
                q[:, j] = _first_order(q0[:, j], 1.0 / p["kv_per_s"], dt)
        elif e.name == "servo_mismatch":
            j = _axis(ctx, p["axis"])
            lag = float(p["extra_lag_ms"]) * 1e-3
            if lag >= 0:
                q[:, j] = _first_order(q0[:, j], lag, dt)
            else:  # the other axes lag instead
                for k in range(q.shape[1]):
                    if k != j:
                        q[:, k] = _first_order(q0[:, k], -lag, dt)
        elif e.name == "backlash":
            j = _axis(ctx, p["axis"])
            q[:, j] = _play(q0[:, j], p["play_um"] * 1e-3, ctx.direction[0, j])
        elif e.name == "reversal_spike":
            j = _axis(ctx, p["axis"])
            since, d = ctx.since_reversal_s(np.arange(ctx.n), j), ctx.direction[:, j]
            ok = np.isfinite(since)
            tt = np.where(ok, since, 0.0)
            tau, rise = p["tau_ms"] * 1e-3, p["rise_ms"] * 1e-3
            shape = (np.exp(-tt / tau) - np.exp(-tt / rise)) / (1 - rise / tau)
            q[:, j] -= np.where(ok, d * p["height_um"] * 1e-3 * shape, 0.0)
        elif e.name == "lateral_play":
            j, k = _axis(ctx, p["reversing_axis"]), _axis(ctx, p["axis"])
            d = ctx.direction[:, j]
            step = p["play_um"] * 1e-3 / 2.0 * d
            q[:, k] += _first_order(step, 0.01, dt)
        elif e.name == "cyclic_error":
            j = _axis(ctx, p["axis"])
            ph = 2 * np.pi * q0[:, j] / p["pitch_mm"] + p["phase_rad"]
            q[:, j] += p["amplitude_um"] * 1e-3 * (np.sin(ph) + p["second_harmonic"] * np.sin(2 * ph))
        elif e.name == "vibration":
            pass  # time-locked: added at the instrument's sample times
        elif e.name == "stick_slip":
            j = _axis(ctx, p["axis"])
            v = np.abs(ctx.qdot[:, j])
            slow = (v < 200.0 / 60.0) & ctx.moving
            enter = np.flatnonzero(np.diff(np.r_[False, slow]).astype(bool) & slow)
            last = np.full(n, -1)
            last[enter] = enter
            last = np.maximum.accumulate(last)
            since = t - t[np.maximum(last, 0)]
            x = since / (p["period_ms"] * 1e-3)
            saw = 2.0 * (x - np.floor(x)) - 1.0
            q[:, j] += np.where(slow, p["amplitude_um"] * 1e-3 * saw, 0.0)
        elif e.name == "contour_smoothing":
            window = math.sqrt(24.0 * float(np.median(ctx.length_mm)) * p["shortcut_um"] * 1e-3)
            q = _smooth_axes(ctx, q0, window)
        elif e.name == "squareness":
            g[str(p["parameter"])] = float(p["urad"])
        elif e.name == "straightness":
            g[str(p["parameter"])] = float(p["um"])
        elif e.name == "scale_mismatch":
            a = str(p["axis"])
            lo, hi = plan.tested_travel()[a]
            g[f"E{a}{a}.P1"] = float(p["um_per_m"]) * (hi - lo) / 2.0 * 1e-3
        elif e.name == "bump":
            r = np.random.default_rng(int(p["seed"]))
            for _ in range(int(p["count"])):
                moving = np.flatnonzero(ctx.moving)
                c = t[moving[int(r.integers(len(moving)))]]
                dl += p["height_um"] * np.exp(-0.5 * ((t - c) / p["width_s"]) ** 2)
        elif e.name == "step":
            dl += np.where(t >= p["at_fraction"] * t[-1], p["height_um"], 0.0)
        elif e.name == "vibration_burst":
            pass
        return reading(q, g, shift, 0.0) - base + dl

    contributions = {e.name: contribution(e) for e in effects}
    total = base + sum(contributions.values()) if contributions else base.copy()
    # the instrument: its own clock, an early start, noise, quantisation, dropouts
    rng = np.random.default_rng([seed, 41])
    k = recording.clock_ppm * 1e-6
    t_end = recording.lead_s + t[-1] * (1 + k) + recording.tail_s
    tm = np.arange(int(t_end * recording.rate_hz) + 1) / recording.rate_hz
    tau = (tm - recording.lead_s) / (1 + k)
    y = np.interp(tau, t, total)
    taui = np.clip(tau, t[0], t[-1])
    idx = np.clip(np.searchsorted(t, taui), 0, n - 1)
    for e in effects:
        p = e.params
        if e.name == "vibration":
            j = _axis(ctx, p["axis"])
            add = ctx.gain[idx, j] * p["amplitude_um"] * np.sin(2 * np.pi * p["frequency_hz"] * tau
                                                                + p["phase_rad"])
            y += add
            contributions["vibration"] = np.interp(t, taui, add)
        elif e.name == "vibration_burst":
            c = p["at_fraction"] * t[-1]
            add = p["amplitude_um"] * np.sin(2 * np.pi * p["frequency_hz"] * tau) * np.exp(
                -0.5 * ((tau - c) / (p["duration_s"] / 4)) ** 2)
            y += add
            contributions["vibration_burst"] = np.interp(t, taui, add)
    if recording.noise_um > 0:
        y += rng.normal(0.0, recording.noise_um, len(y))
    if recording.quantisation_um > 0:
        y = np.round(y / recording.quantisation_um) * recording.quantisation_um
    if recording.dropout_fraction > 0:
        y[rng.random(len(y)) < recording.dropout_fraction] = np.nan
    on_path = (tau >= t[0]) & (tau <= t[-1])
    reposition = np.zeros(len(y), dtype=bool)
    reposition[on_path] = ctx.phase[idx[on_path]] == "reposition"
    y[reposition] = np.nan
    header = {"sample_rate_hz": f"{recording.rate_hz:g}",
              "bar_length_mm": f"{cfg.ballbar.bar_length_mm:g}",
              "source": "sdit-path perturb (hidden effects withheld)"}
    empty = np.full(len(y), "", dtype=object)
    trace = Trace(tm, y, empty, empty, header)
    return trace, Truth(tuple(effects), recording, contributions)


def truth_json(truth: Truth) -> dict:
    rec = truth.recording
    return {"effects": [{"effect": e.name, "in_library": e.in_library, "parameters": e.params}
                        for e in truth.effects],
            "recording": {"offset_s": rec.lead_s, "clock_ppm": rec.clock_ppm,
                          "noise_um": rec.noise_um, "rate_hz": rec.rate_hz}}
