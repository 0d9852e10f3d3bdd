"""The identified geometry in the trade's terms: squareness and scale mismatch as a
ballbar reads them.

They are figures of the tool's motion relative to the table, which is what the bar
reads: where an axis moves the table, its own positioning error enters with the
opposite sign (a table that travels 10 um too far leaves the tool 10 um short on the
part).

A ballbar reads the machine's linear distortion ``D`` (the ball's position error per
unit of position) only through its symmetric part: with the bar along the unit
direction ``w`` (machine frame) of length ``R``, ``dR = R w^T D w`` beyond the
centring and the bar length.  Of the six numbers of the symmetric part the trace
``D_xx + D_yy + D_zz`` reads like the bar length (``R`` is constant on the sphere),
which leaves five a ballbar can give:

* the squareness of each pair of axes, ``D_xy + D_yx`` (urad = um/m): positive when the
  angle between the two positive axes is less than 90 deg, as a ballbar's squareness;
* two scale mismatches, ``D_xx - D_yy`` and ``D_yy - D_zz`` (um/m); the third,
  ``D_zz - D_xx``, is minus their sum.

Each is defined here as what a least-squares fit of that form reads off the geometry's
predicted reading over the test's own poses, each layer with its own centring and bar
length (as the identification eliminates them): a linear functional of the error
parameters.  Its estimate is that functional of the identified geometry, its
uncertainty the functional's share of the determined combinations' covariance; where
part of it lies in what the data do not determine, the figure is not given a number
and the parameters it would need are named.  On a five-axis machine the bar directions
are the machine frame's, turned by the table, so the figures read the linear axes
together with what the rotary axes' errors add along them.
"""

from __future__ import annotations

import numpy as np

from ..errormodel.chain import sensitivities
from ..errormodel.model import ErrorModel
from ..machine.kinematics import Kinematics
from ..plan.files import PlanFiles
from ..timing.trajectory import axis_values_rad

#: (key, name as the trade says it, unit, what it is); the order of :func:`_columns`
FIGURES = (
    ("squareness_xy", "squareness X-Y", "urad",
     "D_xy + D_yx; positive: the angle between +X and +Y less than 90 deg"),
    ("squareness_yz", "squareness Y-Z", "urad",
     "D_yz + D_zy; positive: the angle between +Y and +Z less than 90 deg"),
    ("squareness_zx", "squareness Z-X", "urad",
     "D_zx + D_xz; positive: the angle between +Z and +X less than 90 deg"),
    ("scale_mismatch_xy", "scale mismatch X-Y", "um/m",
     "X's scale error less Y's, tool relative to table (D_xx - D_yy)"),
    ("scale_mismatch_yz", "scale mismatch Y-Z", "um/m",
     "Y's scale error less Z's, tool relative to table (D_yy - D_zz); Z-X is "
     "minus the sum of the two"),
)


def _columns(w: np.ndarray, radius_mm: np.ndarray) -> np.ndarray:
    """``(n, 5)`` reading in um per urad (um/m) of each figure's distortion; the scale
    columns take ``D_zz = 0`` (the trace reads as bar length)."""
    k = radius_mm * 1e-3
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    # squareness s shears the plane: D_xy = s (D_yx = 0) reads R s wx wy
    return np.column_stack([k * wx * wy, k * wy * wz, k * wz * wx, k * wx ** 2, k * wy ** 2])


def functionals(experiments: list[tuple[PlanFiles, str]], model: ErrorModel,
                scale: np.ndarray, stride_s: float = 0.05) -> np.ndarray:
    """``(5, n_params)``: each figure as a functional of the parameters (in units of
    ``scale``, the prior magnitudes), read by least squares off the predicted reading at
    the test's poses every ``stride_s`` (dwells and repositioning left out), every
    experiment with its own centring and bar length."""
    blocks_B, blocks_J = [], []
    n_exp = len(experiments)
    for k, (plan, program) in enumerate(experiments):
        cfg = plan.config
        kin = Kinematics(cfg.machine)
        traj = plan.trajectory(program)
        pivot = np.array(cfg.ballbar.pivot_mm)
        step = max(1, int(round(stride_s / float(np.median(np.diff(traj.t_s))))))
        rows = np.flatnonzero((traj.phase != "reposition") & (traj.phase != "dwell"))[::step]
        if not len(rows):
            continue
        q = axis_values_rad(traj, kin)[rows]
        J = sensitivities(kin, model, q, pivot) * scale
        p = kin.forward(q)
        d = np.linalg.norm(p - pivot, axis=1)
        u = (p - pivot) / d[:, None]
        rot_w, _ = kin.table_transform(q)
        w = np.einsum("nij,nj->ni", rot_w, u)
        own = np.zeros((len(rows), 4 * n_exp))
        own[:, 4 * k:4 * k + 4] = np.column_stack([u, np.ones(len(rows))])
        blocks_B.append(np.column_stack([_columns(w, d), own]))
        blocks_J.append(J)
    B = np.vstack(blocks_B)
    J = np.vstack(blocks_J)
    # a set-up column no sample reaches (an experiment left out) is dropped by lstsq's
    # minimum norm; the five figures' columns are what matters
    coef, *_ = np.linalg.lstsq(B, J, rcond=None)
    Q = coef[:5].copy()
    Q[4] = coef[4]              # D_yy - D_zz with D_zz = 0
    Q[3] = coef[3] - coef[4]    # D_xx - D_yy
    return Q


def estimate(Q: np.ndarray, x_hat: np.ndarray, Vd: np.ndarray, cov_d: np.ndarray,
             names: tuple[str, ...], share: float = 1.0) -> list[dict]:
    """Each figure's estimate and standard uncertainty (k=1) from the identified
    geometry ``x_hat`` (prior units), the determined directions ``Vd`` and their
    covariance ``cov_d``.  The part of a figure outside the determined directions, read
    at a typical error of every parameter it touches, must stay below ``share`` of its
    standard uncertainty; otherwise the figure is not determined and the parameters
    carrying that part are named."""
    out = []
    for (key, title, unit, meaning), q in zip(FIGURES, Q):
        inside = Vd.T @ q
        rest = q - Vd @ inside
        std = float(np.sqrt(max(inside @ cov_d @ inside, 0.0)))
        typical_rest = float(np.linalg.norm(rest))
        item = {"figure": key, "name": title, "unit": unit, "meaning": meaning}
        if typical_rest <= share * max(std, 1e-12) and np.linalg.norm(q) > 0:
            item.update(estimate=float(q @ x_hat), std=std, determined=True)
        else:
            top = np.argsort(-np.abs(rest))[:4]
            item.update(determined=False, undetermined_typical=typical_rest,
                        needs=[names[i] for i in top if abs(rest[i]) > 0.1 * typical_rest])
        out.append(item)
    return out
