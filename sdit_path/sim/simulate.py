"""The ballbar reading along a program's timed trajectory, for a given error set.

For every trajectory sample the machine axes are where the trajectory says; the
actual ball centre follows from the exact error chain; the bar reads the distance to
the actual pivot centre (nominal pivot plus the ball-centring offset) minus its
length, plus a bar-length offset, Gaussian sensor noise and the instrument's
quantisation.  Samples where the bar is off (repositioning) are dropouts (empty).

The trace file: ``# key: value`` lines (program, sample rate; never the truth), then
``t_s,delta_l_um,segment,phase``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errormodel.chain import actual_ball
from ..errormodel.errorset import ErrorSet
from ..errormodel.model import build_model, values_vector
from ..errors import ConfigError
from ..machine.kinematics import Kinematics
from ..planfiles import PlanFiles


@dataclass(frozen=True, slots=True)
class Trace:
    """``t_s, delta_l_um : (n,)`` (NaN = dropout); labels from the trajectory."""

    t_s: np.ndarray
    delta_l_um: np.ndarray
    segment: np.ndarray
    phase: np.ndarray
    header: dict


def axis_values_rad(traj, kin: Kinematics) -> np.ndarray:
    """Trajectory axis columns as internal values (mm, rad) in kinematics order."""
    q = np.zeros((len(traj.t_s), len(kin.names)))
    for col, name in enumerate(traj.axis_names):
        v = traj.axes[:, col]
        q[:, kin.index[name]] = np.radians(v) if kin.axes[kin.index[name]].is_rotary else v
    return q


def error_values(plan: PlanFiles, errors: ErrorSet):
    """The error model of ``errors`` over the plan's tested travel and its value vector;
    a parameter the machine has not is a :class:`ConfigError` naming the set."""
    model = build_model(plan.config.machine, plan.tested_travel(), errors.options)
    try:
        return model, values_vector(model, errors.as_dict())
    except KeyError as exc:
        raise ConfigError(errors.name, f"parameter {exc.args[0]} is not in the model for this "
                                       f"machine; known: {', '.join(model.names)}") from None


def simulate_trace(plan: PlanFiles, program: str, errors: ErrorSet,
                   centring_um=(0.0, 0.0, 0.0), bar_offset_um: float = 0.0,
                   noise_um: float = 0.0, quantisation_um: float = 0.1,
                   seed: int = 0) -> Trace:
    cfg = plan.config
    kin = Kinematics(cfg.machine)
    traj = plan.trajectory(program)
    model, theta = error_values(plan, errors)
    q = axis_values_rad(traj, kin)
    ball = actual_ball(kin, model, theta, q)
    pivot = np.array(cfg.ballbar.pivot_mm) + np.asarray(centring_um, dtype=float) * 1e-3
    dl = (np.linalg.norm(ball - pivot, axis=1) - cfg.ballbar.bar_length_mm) * 1e3 + bar_offset_um
    rng = np.random.default_rng(seed)
    if noise_um > 0:
        dl = dl + rng.normal(0.0, noise_um, len(dl))
    if quantisation_um > 0:
        dl = np.round(dl / quantisation_um) * quantisation_um
    dl[traj.phase == "reposition"] = np.nan
    rate = 1.0 / float(np.median(np.diff(traj.t_s))) if len(traj.t_s) > 1 else 1000.0
    header = {"program": program, "sample_rate_hz": f"{rate:.6g}",
              "bar_length_mm": f"{cfg.ballbar.bar_length_mm:g}", "source": "sdit-path simulate"}
    return Trace(traj.t_s, dl, traj.segment, traj.phase, header)


def trace_csv(trace: Trace) -> str:
    lines = [f"# {k}: {v}" for k, v in trace.header.items()]
    lines.append("t_s,delta_l_um,segment,phase")
    n = len(trace.t_s)
    table = np.empty((n, 4), dtype=object)
    table[:, 0] = trace.t_s
    table[:, 1] = [("" if not np.isfinite(v) else f"{v:.4f}") for v in trace.delta_l_um]
    table[:, 2] = trace.segment
    table[:, 3] = trace.phase
    lines.append((("%.4f,%s,%s,%s\n" * n)[:-1]) % tuple(table.ravel()))
    return "\n".join(lines) + "\n"
