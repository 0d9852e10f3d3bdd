"""An independent generator of measured ballbar recordings, for blind checks.

It shares no model code with what it checks: nothing from ``sdit_path`` is imported.
It reads a plan directory as data (``config.toml`` with ``tomllib``, the timed
trajectory with pandas), has its own forward kinematics (product of exponentials over
the chains the config describes), its own effect models acting on the machine axes,
and its own instrument.  Magnitudes come from the domain brief's table ("typical (bad)"):
the bad ones by default, the typical ones with ``magnitudes="typical"``.

Effects (physics, not the diagnoser's compact models):

- servo lag: every linear axis follows its command through a first-order lag; equal
  lags (``servo_lag``) or different ones (``servo_mismatch``);
- backlash: a play operator on one axis (the axis stands after a reversal until the
  command has taken up the play);
- reversal_spike: after each reversal of one axis, a pulse that rises over a few ms
  (friction breakaway through the velocity loop) and decays over tens of ms;
- stick_slip: while an axis crawls, it sticks (lags further behind its command) until
  the spring force breaks the static friction, then slips forward past the command;
- scale_mismatch, squareness, cyclic_error: position-locked geometry of the machine's
  axes;
- vibration: a structural mode of one axis excited by its acceleration, seen along the
  bar;
- thermal_drift: the spindle walks away from the pivot linearly in time, in the
  machine's frame (it does not turn with a rotary table);
- contour_smoothing: the control's zero-phase path smoothing (passes through stops);
- setup: the pivot and tool ball centring, always present (a set-up residual), plus a
  bar length offset.

Instrument: starts 1-20 s before the program, own clock (+-150 ppm), gain +-0.3 %,
noise 0.1-0.3 um, 0.1 um steps, dropout bursts.
"""

from __future__ import annotations

import gzip
import io
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

EFFECTS = ("servo_lag", "servo_mismatch", "backlash", "reversal_spike", "stick_slip",
           "scale_mismatch", "squareness", "cyclic_error", "vibration", "thermal_drift",
           "contour_smoothing")
#: effects outside any compact library: a diagnosis should leave them unexplained
GAPS = ("mount_slip", "guideway_bump", "cubic_straightness", "vibration_burst")
#: effects that are functions of the pose (geometry), the rest are dynamics or time
POSE_LOCKED = ("scale_mismatch", "squareness", "cyclic_error")
_DIR = {"X": (1, 0, 0), "Y": (0, 1, 0), "Z": (0, 0, 1), "A": (1, 0, 0), "B": (0, 1, 0),
        "C": (0, 0, 1)}


# --------------------------------------------------------------------------- plan data

@dataclass
class PlanData:
    names: list[str]            # axis names in chain order (workpiece then tool)
    rotary: list[bool]
    directions: np.ndarray      # (k, 3)
    points: np.ndarray          # (k, 3)
    workpiece: list[str]
    tool: list[str]
    tool_offset: np.ndarray     # ball relative to the gauge point, every axis at 0
    pivot: np.ndarray
    length_mm: float
    t: np.ndarray               # program time
    q: np.ndarray               # (n, k) commanded axes, mm and rad
    phase: np.ndarray
    duration_s: float


def load(plan_dir: str | Path, program: str) -> PlanData:
    d = Path(plan_dir)
    cfg = tomllib.loads((d / "config.toml").read_text(encoding="utf-8"))
    manifest = json.loads((d / "plan.json").read_text(encoding="utf-8"))
    entry = next(p for p in manifest["programs"] if p["name"] == program)
    raw = (d / entry["trajectory"]).read_bytes()
    if entry["trajectory"].endswith(".gz"):
        raw = gzip.decompress(raw)
    import pandas as pd

    df = pd.read_csv(io.BytesIO(raw), comment="#", dtype={"segment": str, "phase": str},
                     keep_default_na=False)
    m = cfg["machine"]
    work = list(m.get("workpiece_chain", ["X", "Y"]))
    tool = list(m.get("tool_chain", ["Z"]))
    names, rot, dirs, pts, cols = [], [], [], [], []
    for name in work + tool:
        a = m["axes"][name]
        is_rot = a.get("type", "rotary" if name in "ABC" else "linear") == "rotary"
        default = np.array(_DIR[name], float)
        if not is_rot and name in work:
            default = -default
        v = np.array(a.get("direction", default), float)
        dirs.append(v / np.linalg.norm(v))
        pts.append(np.array(a.get("point_mm", [0, 0, 0]), float))
        names.append(name)
        rot.append(is_rot)
        col = df[f"axis_{name}_{'deg' if is_rot else 'mm'}"].to_numpy(float)
        cols.append(np.radians(col) if is_rot else col)
    sd = np.array(m.get("spindle_direction", [0, 0, 1]), float)
    sd /= np.linalg.norm(sd)
    b = cfg["ballbar"]
    return PlanData(names, rot, np.array(dirs), np.array(pts), work, tool,
                    -float(m.get("tool_length_mm", 0.0)) * sd, np.array(b["pivot_mm"], float),
                    float(b["bar_length_mm"]), df["t_s"].to_numpy(float), np.column_stack(cols),
                    df["phase"].to_numpy(object), float(entry["cycle_time_s"]))


def load_motion(plan_dir: str | Path, program: str, motion_csv: str | Path) -> PlanData:
    """The plan's machine, with the commanded motion a real control made of ``program``
    instead of the plan's trajectory: ``validation/linuxcnc_run.py --motion-dir`` writes
    it (control time from the plan's start, every commanded axis per 1 ms servo period;
    a table-frame program commands the ball in the table, a 3-axis machine's axes).
    The machine stands wherever the command does not move; the recording's program
    lasts as long as the control took, its last dwell included."""
    base = load(plan_dir, program)
    import pandas as pd

    df = pd.read_csv(motion_csv)
    cols = []
    for name, rot in zip(base.names, base.rotary):
        col = df[f"axis_{name}"].to_numpy(float)
        cols.append(np.radians(col) if rot else col)
    q = np.column_stack(cols)
    t = df["t_s"].to_numpy(float)
    still = np.r_[True, np.all(np.diff(q, axis=0) == 0, axis=1)]
    phase = np.where(still, "dwell", "cruise").astype(object)
    # the control's last dwell: the programs end with one at the last node
    dwell = float(tomllib.loads((Path(plan_dir) / "config.toml").read_text(encoding="utf-8"))
                  .get("test", {}).get("dwell_s", 2.0))
    n_end = int(round(dwell / float(np.median(np.diff(t)))))
    t = np.r_[t, t[-1] + np.arange(1, n_end + 1) * float(np.median(np.diff(t)))]
    q = np.vstack([q, np.repeat(q[-1:], n_end, axis=0)])
    phase = np.r_[phase, np.full(n_end, "dwell", dtype=object)]
    return PlanData(base.names, base.rotary, base.directions, base.points, base.workpiece,
                    base.tool, base.tool_offset, base.pivot, base.length_mm, t, q, phase,
                    float(t[-1]))


# --------------------------------------------------------------------------- kinematics

def _rot(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations about the unit ``axis`` (Rodrigues)."""
    x, y, z = axis
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]], float)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _chain(pd_: PlanData, q: np.ndarray, which: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) with x_bed = R x_body + p for the body at the end of ``which``."""
    n = len(q)
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    for name in which:
        j = pd_.names.index(name)
        if pd_.rotary[j]:
            Rj = _rot(pd_.directions[j], q[:, j])
            pj = pd_.points[j] - Rj @ pd_.points[j]
        else:
            Rj = np.broadcast_to(np.eye(3), (n, 3, 3))
            pj = q[:, j, None] * pd_.directions[j]
        p = p + np.einsum("nij,nj->ni", R, pj)
        R = R @ Rj
    return R, p


def ball_in_table(pd_: PlanData, q: np.ndarray) -> np.ndarray:
    """Ball centre in the table frame for axis values ``q (n, k)`` (mm, rad)."""
    Rt, pt = _chain(pd_, q, pd_.tool)
    ball_bed = np.einsum("nij,j->ni", Rt, pd_.tool_offset) + pt
    Rw, pw = _chain(pd_, q, pd_.workpiece)
    return np.einsum("nji,nj->ni", Rw, ball_bed - pw)


# --------------------------------------------------------------------------- effects

def _first_order(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """Exact discretisation of a first-order lag, started at rest at x[0]."""
    if tau <= 0:
        return x.copy()
    from scipy.signal import lfilter

    a = math.exp(-dt / tau)
    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * x[0]])
    return y


def _play(x: np.ndarray, width: float) -> np.ndarray:
    """Play operator: the output follows only once the input has crossed the play."""
    out = np.empty_like(x)
    y = x[0]
    h = width / 2
    for i, v in enumerate(x):
        if v - y > h:
            y = v - h
        elif y - v > h:
            y = v + h
        out[i] = y
    return out


def _reversals(v: np.ndarray, t: np.ndarray, threshold: float) -> list[tuple[int, float]]:
    """Indices where the velocity changes sign (ignoring crawls below ``threshold``)
    and the new sign."""
    s = np.where(v > threshold, 1, np.where(v < -threshold, -1, 0))
    out, last = [], 0
    for i in np.flatnonzero(s):
        if last and s[i] != last:
            out.append((int(i), float(s[i])))
        last = s[i]
    return out


@dataclass
class Case:
    effect: str
    params: dict
    excited: bool = True
    notes: dict = field(default_factory=dict)


#: the domain brief's ranges, "typical (bad)": the bad ones by default; ``typical``
#: draws the smaller ones a well-kept machine shows (each case is then scored only where
#: the program excites it above the noise, as always)
RANGES = {
    "bad": {"tau_ms": (20, 40), "mismatch_ms": (1.0, 3.0), "play_um": (4, 12),
            "spike_um": (5, 12), "spike_tau_ms": (15, 40), "stick_um": (1.0, 3.0),
            "scale_um_per_m": (20, 60), "square_urad": (20, 80), "cyclic_um": (0.8, 2.0),
            "vib_um_per_m_s2": (1.0, 4.0), "drift_um_per_h": (15, 40),
            "sigma_ms": (10, 25), "slip_um": (3, 8), "bump_um": (3, 8),
            "burst_um": (2, 5)},
    "typical": {"tau_ms": (20, 50), "mismatch_ms": (0.1, 0.5), "play_um": (1, 5),
                "spike_um": (2, 8), "spike_tau_ms": (10, 60), "stick_um": (0.5, 1.5),
                "scale_um_per_m": (5, 20), "square_urad": (5, 30), "cyclic_um": (0.3, 0.8),
                "vib_um_per_m_s2": (0.3, 1.0), "drift_um_per_h": (1, 10),
                "sigma_ms": (3, 10), "slip_um": (1, 3), "bump_um": (1, 3),
                "burst_um": (0.5, 2)},
}


def draw(effect: str, rng: np.random.Generator, pd_: PlanData,
         magnitudes: str = "bad") -> Case:
    lin = [n for n, r in zip(pd_.names, pd_.rotary) if not r]
    R = RANGES[magnitudes]
    u = lambda a, b: float(rng.uniform(a, b))  # noqa: E731
    r = lambda key: u(*R[key])  # noqa: E731
    sgn = lambda: float(rng.choice([-1, 1]))  # noqa: E731
    if effect == "servo_lag":
        return Case(effect, {"tau_ms": r("tau_ms")})
    if effect == "servo_mismatch":
        a, b = rng.choice(lin, 2, replace=False)
        return Case(effect, {"axis": str(a), "other": str(b), "tau_ms": u(15, 35),
                             "mismatch_ms": sgn() * r("mismatch_ms")})
    if effect == "backlash":
        return Case(effect, {"axis": str(rng.choice(lin)), "play_um": r("play_um")})
    if effect == "reversal_spike":
        return Case(effect, {"axis": str(rng.choice(lin)), "height_um": r("spike_um"),
                             "rise_ms": u(2, 6), "tau_ms": r("spike_tau_ms")})
    if effect == "stick_slip":
        return Case(effect, {"axis": str(rng.choice(lin)), "amplitude_um": r("stick_um"),
                             "crawl_mm_per_s": 200 / 60})
    if effect == "scale_mismatch":
        return Case(effect, {"axis": str(rng.choice(lin)),
                             "um_per_m": sgn() * r("scale_um_per_m")})
    if effect == "squareness":
        return Case(effect, {"pair": str(rng.choice(["XY", "XZ", "YZ"])),
                             "urad": sgn() * r("square_urad")})
    if effect == "cyclic_error":
        return Case(effect, {"axis": str(rng.choice(lin)), "pitch_mm": u(5, 20),
                             "amplitude_um": r("cyclic_um"), "phase": u(0, 2 * math.pi)})
    if effect == "vibration":
        return Case(effect, {"axis": str(rng.choice(lin)), "frequency_hz": u(20, 120),
                             "damping": u(0.02, 0.08), "gain_um_per_m_s2": r("vib_um_per_m_s2")})
    if effect == "thermal_drift":
        v = rng.normal(size=3)
        v *= r("drift_um_per_h") / np.linalg.norm(v)
        return Case(effect, {"um_per_h": [float(x) for x in v]})
    if effect == "contour_smoothing":
        return Case(effect, {"sigma_ms": r("sigma_ms")})
    if effect == "mount_slip":
        v = rng.normal(size=3)
        return Case(effect, {"at": u(0.3, 0.7), "shift_um": [float(x) for x in
                                                             v * r("slip_um") / np.linalg.norm(v)]})
    if effect in ("guideway_bump", "cubic_straightness"):
        a, b = rng.choice(lin, 2, replace=False)
        return Case(effect, {"axis": str(a), "across": str(b), "amplitude_um": sgn() * r("bump_um"),
                             "centre": u(0.2, 0.8), "width_mm": u(3, 10)})
    if effect == "vibration_burst":
        return Case(effect, {"axis": str(rng.choice(lin)), "at": u(0.2, 0.8),
                             "frequency_hz": u(30, 150), "amplitude_um": r("burst_um"),
                             "decay_s": u(0.1, 0.3)})
    raise ValueError(effect)


def apply(case: Case | None, pd_: PlanData, rng: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray, float]:
    """Actual axes ``(n, k)``, an extra ball displacement in the table frame ``(n, 3)``
    (mm) and the following delay the effect adds (s)."""
    q = pd_.q.copy()
    t = pd_.t
    dt = float(np.median(np.diff(t)))
    extra = np.zeros((len(t), 3))
    delay = 0.0
    if case is None:
        return q, extra, delay
    P = case.params
    idx = {n: i for i, n in enumerate(pd_.names)}
    e = case.effect
    if e == "servo_lag":
        for j, r in enumerate(pd_.rotary):
            q[:, j] = _first_order(q[:, j], dt, P["tau_ms"] * 1e-3)
        delay = P["tau_ms"] * 1e-3
    elif e == "servo_mismatch":
        for j, r in enumerate(pd_.rotary):
            tau = P["tau_ms"] + (P["mismatch_ms"] if pd_.names[j] == P["axis"] else 0.0)
            q[:, j] = _first_order(q[:, j], dt, tau * 1e-3)
        delay = (P["tau_ms"] + max(P["mismatch_ms"], 0.0)) * 1e-3
    elif e == "backlash":
        j = idx[P["axis"]]
        q[:, j] = _play(q[:, j], P["play_um"] * 1e-3)
    elif e == "reversal_spike":
        j = idx[P["axis"]]
        v = np.gradient(q[:, j], t)
        pulse = np.zeros(len(t))
        rise, tau = P["rise_ms"] * 1e-3, P["tau_ms"] * 1e-3
        for i, s in _reversals(v, t, 0.05):
            tt = t[i:i + int(8 * tau / dt)] - t[i]
            pulse[i:i + len(tt)] -= s * P["height_um"] * 1e-3 * (1 - np.exp(-tt / rise)) * np.exp(-tt / tau)
        q[:, j] += pulse
        case.excited = bool(_reversals(v, t, 0.05))
    elif e == "stick_slip":
        j = idx[P["axis"]]
        v = np.gradient(q[:, j], t)
        crawl = (np.abs(v) > 1e-4) & (np.abs(v) < P["crawl_mm_per_s"])
        lag, out = 0.0, np.zeros(len(t))
        amp = P["amplitude_um"] * 1e-3
        for i in range(len(t)):
            if crawl[i]:
                # stuck, the command runs on until the lag reaches amp; the slip throws
                # the axis forward, past the command (-0.3 amp), and it sticks again:
                # a saw-tooth in the travel, exact however many teeth one sample holds
                # (at 3 mm/s a 2 um tooth lasts 0.7 ms, shorter than a sample)
                lag = (lag + 0.3 * amp + abs(v[i]) * dt) % (1.3 * amp) - 0.3 * amp
            else:
                lag *= 0.9  # moving freely, the error settles
            out[i] = -np.sign(v[i]) * lag
        q[:, j] += out
        case.excited = bool(crawl.sum() * dt > 1.0)
    elif e == "scale_mismatch":
        j = idx[P["axis"]]
        q[:, j] += P["um_per_m"] * 1e-6 * (q[:, j] - q[0, j])
    elif e == "cyclic_error":
        j = idx[P["axis"]]
        q[:, j] += P["amplitude_um"] * 1e-3 * np.sin(2 * math.pi * q[:, j] / P["pitch_mm"] + P["phase"])
    elif e == "squareness":
        # the guideways of two linear axes not at right angles: moving axis b moves the
        # slide along a as well - on the machine's axes (not in the table's frame, which
        # turns with a rotary table: a squareness does not turn with it)
        a, b = P["pair"]
        ia, ib = idx[a], idx[b]
        q[:, ia] += P["urad"] * 1e-6 * (q[:, ib] - q[0, ib])
    elif e == "vibration":
        j = idx[P["axis"]]
        acc = np.gradient(np.gradient(q[:, j], t), t) * 1e-3  # m/s^2
        w = 2 * math.pi * P["frequency_hz"]
        zeta = P["damping"]
        from scipy.signal import cont2discrete, lfilter

        num, den = [w * w], [1, 2 * zeta * w, w * w]
        b, a, _ = cont2discrete((num, den), dt, method="bilinear")
        x = lfilter(np.ravel(b), a, acc) * P["gain_um_per_m_s2"] * 1e-3
        q[:, j] += x
    elif e == "thermal_drift":
        # the spindle grows in the machine's frame: with a rotary table the drift turns
        # in the table's frame, where the ball is measured from the pivot
        Rw, _ = _chain(pd_, q, pd_.workpiece)
        drift = np.outer(t / 3600.0, np.array(P["um_per_h"]) * 1e-3)
        extra += np.einsum("nji,nj->ni", Rw, drift)
    elif e == "mount_slip":  # the pivot's magnetic mount gives way once
        extra[t >= P["at"] * t[-1]] -= np.array(P["shift_um"]) * 1e-3
    elif e in ("guideway_bump", "cubic_straightness"):  # straightness of one axis
        j, k = idx[P["axis"]], idx[P["across"]]
        x = q[:, j]
        lo, hi = float(x.min()), float(x.max())
        if e == "guideway_bump":
            c = lo + P["centre"] * (hi - lo)
            shape = np.exp(-0.5 * ((x - c) / P["width_mm"]) ** 2)
        else:
            shape = ((x - 0.5 * (lo + hi)) / max(0.5 * (hi - lo), 1e-9)) ** 3
        q[:, k] += P["amplitude_um"] * 1e-3 * shape
    elif e == "vibration_burst":  # a knock: a decaying ring of one axis
        j = idx[P["axis"]]
        t0 = P["at"] * t[-1]
        after = np.maximum(t - t0, 0.0)
        q[:, j] += (t >= t0) * P["amplitude_um"] * 1e-3 * np.sin(
            2 * math.pi * P["frequency_hz"] * after) * np.exp(-after / P["decay_s"])
    elif e == "contour_smoothing":
        from scipy.ndimage import gaussian_filter1d

        s = P["sigma_ms"] * 1e-3 / dt
        for j in range(q.shape[1]):
            q[:, j] = gaussian_filter1d(q[:, j], s, mode="nearest")
    return q, extra, delay


# --------------------------------------------------------------------------- recording

def timing_bound(pd_: PlanData, reading: np.ndarray, ball: np.ndarray, centring: np.ndarray,
                 effect: np.ndarray, noise_um: float, ppm: float) -> tuple[float, float]:
    """Cramer-Rao bound (standard deviations) of the recording's offset (s) and clock
    rate (ppm) from this reading: its own derivative against the noise, with what any
    analysis must estimate alongside left free - a constant (bar length), the three
    centring components, the instrument gain and the effect's amplitude.  No estimator
    can be surer than this; a target tighter than a few times it cannot be met."""
    t = pd_.t
    dr = np.gradient(reading, t)
    k = ppm * 1e-6
    u = (ball - (pd_.pivot + centring)) / pd_.length_mm
    J = np.column_stack([-dr / (1 + k), -dr * t / (1 + k) * 1e-6, np.ones(len(t)), u,
                         reading, effect])
    J = J[:, [0, 1] + [i for i in range(2, J.shape[1]) if np.ptp(J[:, i]) > 1e-9]]
    U, sv, _ = np.linalg.svd(J[:, 2:], full_matrices=False)
    U = U[:, sv > sv[0] * 1e-9]
    G = J[:, :2] - U @ (U.T @ J[:, :2])
    cov = np.linalg.pinv(G.T @ G) * noise_um ** 2
    return float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))


def _rms_where_acting(visible: np.ndarray) -> float:
    """RMS where the signal acts (above a tenth of its peak): a local effect is not
    diluted by the whole trace."""
    if not np.any(visible):
        return 0.0
    acts = np.abs(visible) > 0.1 * np.max(np.abs(visible))
    return float(np.sqrt(np.mean(visible[acts] ** 2)))


def record(pd_: PlanData, case: Case | None, seed: int) -> tuple[str, dict]:
    """CSV text of a measured recording and the truth (never written into the CSV)."""
    rng = np.random.default_rng(seed)
    q, extra, delay = apply(case, pd_, rng)
    ball = ball_in_table(pd_, q) + extra
    centring = rng.normal(size=3)
    centring *= rng.uniform(3, 20) / np.linalg.norm(centring) * 1e-3  # set-up residual, mm
    dL = rng.uniform(-5, 5) * 1e-3
    reading_prog = (np.linalg.norm(ball - (pd_.pivot + centring), axis=1) - pd_.length_mm - dL) * 1e3
    nominal = (np.linalg.norm(ball_in_table(pd_, pd_.q) - pd_.pivot, axis=1) - pd_.length_mm) * 1e3
    lead = float(rng.uniform(1, 20))
    tail = float(rng.uniform(1, 10))
    ppm = float(rng.uniform(-150, 150))
    gain = 1 + float(rng.uniform(-0.003, 0.003))
    noise = float(rng.uniform(0.1, 0.3))
    rate = 1000.0
    # instrument samples at its own clock: t_m = (tau + lead) * (1 + ppm 1e-6)
    n_m = int((lead + pd_.duration_s + tail) * (1 + ppm * 1e-6) * rate)
    t_m = np.arange(n_m) / rate
    tau = t_m / (1 + ppm * 1e-6) - lead
    y = np.interp(tau, pd_.t, reading_prog)  # standing at the first/last pose outside
    y = gain * y + rng.normal(0, noise, n_m)
    y = np.round(y / 0.1) * 0.1
    drop = np.zeros(n_m, bool)
    for _ in range(int(rng.integers(0, 6))):
        s0 = int(rng.integers(0, n_m))
        drop[s0:s0 + int(rng.integers(1, 200))] = True
    lines = ["# source: independent physics generator", "t_s,delta_l_um"]
    lines += [f"{a:.4f}," + ("" if d else f"{b:.1f}") for a, b, d in zip(t_m, y, drop)]
    clean = (np.linalg.norm(ball_in_table(pd_, pd_.q) - (pd_.pivot + centring), axis=1)
             - pd_.length_mm - dL) * 1e3
    # what the effect adds beyond a pure delay of the whole path (which no trace can tell
    # from a later start): a lag shows only through its shape
    common = case.params.get("tau_ms", 0.0) * 1e-3 if case and case.effect in (
        "servo_lag", "servo_mismatch") else 0.0
    visible = reading_prog - np.interp(pd_.t - common, pd_.t, clean)
    visible = visible - np.median(visible)
    # above the noise where it acts (a local effect is not diluted by the whole trace)
    visible_rms = _rms_where_acting(visible)
    # what no change of the set-up reproduces: every analysis must fit the centring and
    # the bar's length, and an effect that moves the reading as they do is not seen
    u = ball_in_table(pd_, pd_.q) - (pd_.pivot + centring)
    u /= np.linalg.norm(u, axis=1)[:, None]
    S = np.column_stack([np.ones(len(u)), u])
    beyond_rms = _rms_where_acting(visible - S @ np.linalg.lstsq(S, visible, rcond=None)[0])
    # timing is read from what the pose dictates (set-up, geometry): a dynamic effect's
    # own timing (when a slip happens, how a lag develops) is not a clock
    pose = reading_prog if case and case.effect in POSE_LOCKED else clean
    crb = timing_bound(pd_, pose, ball, centring, reading_prog - pose, noise, ppm)
    truth = {"effect": case.effect if case else None, "params": case.params if case else {},
             "excited": bool(case.excited and visible_rms >= noise) if case else False,
             "visible_rms_um": visible_rms,
             "excited_beyond_setup": bool(case.excited and beyond_rms >= noise) if case else False,
             "visible_beyond_setup_rms_um": beyond_rms,
             "offset_s": lead * (1 + ppm * 1e-6), "clock_ppm": ppm,
             "following_delay_s": delay, "gain": gain, "noise_um": noise,
             "centring_um": [float(c * 1e3) for c in centring], "bar_offset_um": dL * 1e3,
             "nominal_rms_um": float(np.sqrt(np.mean(nominal ** 2))),
             "offset_bound_s": crb[0], "clock_bound_ppm": crb[1],
             "effect_rms_um": float(np.std(reading_prog))}
    return "\n".join(lines) + "\n", truth


def main() -> None:
    """``python validation/physics_gen.py PLAN PROGRAM``: checks this generator's own
    kinematics against the plan (the commanded trajectory must lie on the sphere)."""
    import sys

    pd_ = load(sys.argv[1], sys.argv[2])
    r = (np.linalg.norm(ball_in_table(pd_, pd_.q) - pd_.pivot, axis=1) - pd_.length_mm) * 1e3
    print(f"{sys.argv[2]}: {len(r)} samples, commanded ball off the sphere by at most "
          f"{np.abs(r).max():.4f} um (this generator's own kinematics)")


if __name__ == "__main__":
    main()
