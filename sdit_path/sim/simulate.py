"""The ballbar reading along a program's timed trajectory, for a given error set.

For every trajectory sample the machine axes are where the trajectory says; the
actual ball centre follows from the exact error chain; the bar reads the distance to
the actual pivot centre (nominal pivot plus the ball-centring offset) minus its
length, plus a bar-length offset, Gaussian sensor noise and the instrument's
quantisation.  Samples where the bar is off (repositioning) are dropouts (empty).

The trace file (:func:`sdit_path.reading.recording.trace_csv`): ``# key: value`` lines
(program, sample rate; never the truth), then ``t_s,delta_l_um,segment,phase``.
"""

from __future__ import annotations

import numpy as np

from ..errormodel.chain import actual_ball
from ..errormodel.errorset import ErrorSet
from ..errormodel.model import build_model, values_vector
from ..errors import ConfigError
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..reading.trace import Trace
from ..reading.written import written_deviation_um
from ..timing.trajectory import axis_values_rad


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
    moving = (traj.phase != "dwell") & (traj.phase != "reposition")
    dl = dl + written_deviation_um(plan, program, np.asarray(traj.ball_mm, float), moving)
    rng = np.random.default_rng(seed)
    if noise_um > 0:
        dl = dl + rng.normal(0.0, noise_um, len(dl))
    if quantisation_um > 0:
        dl = np.round(dl / quantisation_um) * quantisation_um
    dl[traj.phase == "reposition"] = np.nan
    rate = 1.0 / float(np.median(np.diff(traj.t_s))) if len(traj.t_s) > 1 else 1000.0
    header = {"program": program, "controller": plan.ran_on or "", "sample_rate_hz": f"{rate:.6g}",
              "bar_length_mm": f"{cfg.ballbar.bar_length_mm:g}", "source": "sdit-path simulate"}
    return Trace(traj.t_s, dl, traj.segment, traj.phase, header)
