"""The chain with its errors: the exact transform product, and the first-order
sensitivity of the bar reading to every parameter.

Exact: for every axis, in chain order, ``T <- T . L_K . M_K(q_K) . E_K(q_K)`` with
``L_K`` the location error about the axis point (rotary axes), ``M_K`` the nominal
motion (its direction tilted by squareness, for linear axes) and ``E_K`` the component
errors as an exact rigid motion (rotation by the error vector).  The ball in the table
frame is ``T_table^-1 T_tool tip``.

First order: an error twist (delta, eps) applied in a body frame (R, o) moves the
tool ball relative to the table by ``s (R delta + (R eps) x (ball - o))`` with s = +1
on the tool branch and -1 on the workpiece branch; the bar reads its projection on the
bar direction.  So with ``w`` the bar direction in the bed frame, a translation
component k has sensitivity ``s (R^T w)_k`` and a rotation component ``s (R^T (r x w))_k``
(``r = ball - o``).  Tests check that the two agree to second order.
"""

from __future__ import annotations

import numpy as np

from ..machine.kinematics import Kinematics, rotation_about
from .model import SQUARENESS, ErrorModel

_E = np.eye(3)


def _small_rotation(eps: np.ndarray) -> np.ndarray:
    """Exact rotations ``(n, 3, 3)`` by rotation vectors ``eps (n, 3)`` (Rodrigues:
    ``cos a I + (sin a / a) [eps]x + ((1 - cos a) / a^2) eps eps^T``, written out element
    by element; the second ratio as ``2 sin^2(a/2) / a^2``, which does not cancel for the
    small angles of machine errors; both 1 and 1/2 at a = 0)."""
    eps = np.asarray(eps, dtype=float)
    x, y, z = eps[:, 0], eps[:, 1], eps[:, 2]
    angle = np.sqrt(x * x + y * y + z * z)
    turned = angle > 0
    s = np.divide(np.sin(angle), angle, out=np.ones_like(angle), where=turned)
    half = 0.5 * angle
    h = np.divide(np.sin(half), half, out=np.ones_like(angle), where=turned)
    c = 0.5 * h * h
    co = np.cos(angle)
    r = np.empty((len(eps), 3, 3))
    cxy, cxz, cyz = c * x * y, c * x * z, c * y * z
    r[:, 0, 0] = co + c * x * x
    r[:, 1, 1] = co + c * y * y
    r[:, 2, 2] = co + c * z * z
    r[:, 0, 1], r[:, 1, 0] = cxy - s * z, cxy + s * z
    r[:, 0, 2], r[:, 2, 0] = cxz + s * y, cxz - s * y
    r[:, 1, 2], r[:, 2, 1] = cyz - s * x, cyz + s * x
    return r


def _split(model: ErrorModel, theta: np.ndarray):
    """Constant parts: squareness rotation vectors per axis and location twists."""
    square = {}
    location = {}
    for p, v in zip(model.parameters, theta):
        if v == 0.0:
            continue
        if p.kind == "squareness":
            axis, rot = SQUARENESS[p.name]
            square.setdefault(axis, np.zeros(3))[rot] += v * p.scale
        elif p.kind == "location":
            twist = location.setdefault(p.axis, np.zeros(6))
            twist[p.component] += v * p.scale
    return square, location


def actual_ball(kin: Kinematics, model: ErrorModel, theta: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Exact ball centre ``(n, 3)`` in the table frame with errors ``theta`` (um, urad)."""
    from .model import component_errors

    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = len(q)
    comp = component_errors(model, theta, q, kin.index)
    square, location = _split(model, theta)

    def chain(indices):
        rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        trans = np.zeros((n, 3))
        for i in indices:
            ax = kin.axes[i]
            name = ax.name
            d = np.array(ax.direction)
            if name in location:  # L: about the axis point, in the current frame
                c = np.array(ax.point_mm)
                tw = location[name]
                r_l = _small_rotation(tw[None, 3:])[0]  # constant: one rotation
                t_l = tw[:3] + c - r_l @ c
                trans = trans + rot @ t_l
                rot = rot @ r_l
            if ax.is_rotary:
                r_m = rotation_about(d, q[:, i])
                c = np.array(ax.point_mm)
                t_m = c - np.einsum("nij,j->ni", r_m, c)
                trans = trans + np.einsum("nij,nj->ni", rot, t_m)
                rot = rot @ r_m
            else:  # a translation: the orientation stays
                if name in square:
                    d = _small_rotation(square[name][None, :])[0] @ d
                trans = trans + np.einsum("nij,nj->ni", rot, q[:, i:i + 1] * d)
            e = comp[name]
            if e.any():
                r_e = _small_rotation(e[:, 3:])
                trans = trans + np.einsum("nij,nj->ni", rot, e[:, :3])
                rot = rot @ r_e
        return rot, trans

    rot_w, trans_w = chain(kin.workpiece)
    rot_t, trans_t = chain(kin.tool)
    ball = np.einsum("nij,j->ni", rot_t, kin.tip_mm) + trans_t
    return np.einsum("nji,nj->ni", rot_w, ball - trans_w)


def sensitivities(kin: Kinematics, model: ErrorModel, q: np.ndarray, pivot_mm: np.ndarray
                  ) -> np.ndarray:
    """First-order d(bar reading)/d(parameter) ``(n, n_params)``, in um per um or urad."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = len(q)
    p_nom = kin.forward(q)
    u = p_nom - pivot_mm
    u /= np.linalg.norm(u, axis=1)[:, None]
    rot_w, _ = kin.table_transform(q)
    w = np.einsum("nij,nj->ni", rot_w, u)  # bar direction, bed frame
    ball = kin.tool_ball_bed(q)
    frames = {}
    for chain, sign in ((kin.workpiece, -1.0), (kin.tool, 1.0)):
        prev = (np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3)))
        for i, rt in zip(chain, kin.chain_transforms(q, chain)):
            frames[kin.names[i]] = (rt, prev, sign)
            prev = rt
    J = np.zeros((n, len(model.parameters)))
    cache: dict = {}

    def component_sens(axis: str, k: int, which: str) -> np.ndarray:
        key = (axis, k, which)
        if key in cache:
            return cache[key]
        (rot, org), (rot_p, org_p), sign = frames[axis]
        if which == "loc":
            ax = kin.axes[kin.index[axis]]
            rot, org = rot_p, org_p + np.einsum("nij,j->ni", rot_p, np.array(ax.point_mm))
        if k < 3:
            val = sign * np.einsum("nji,nj->ni", rot, w)[:, k]
        else:
            r = ball - org
            val = sign * np.einsum("nji,nj->ni", rot, np.cross(r, w))[:, k - 3]
        cache[key] = val
        return val

    for col, p in enumerate(model.parameters):
        if p.kind == "component":
            qa = q[:, kin.index[p.axis]]
            J[:, col] = component_sens(p.axis, p.component, "comp") * model.basis_values(p, qa) \
                * p.scale * 1e3
        elif p.kind == "location":
            J[:, col] = component_sens(p.axis, p.component, "loc") * p.scale * 1e3
        else:  # squareness: the axis' translation turns by eps x d, times its position
            axis, rot_index = SQUARENESS[p.name]
            ax = kin.axes[kin.index[axis]]
            (_, _), (rot_p, _), sign = frames[axis]
            tilt = np.cross(_E[rot_index], np.array(ax.direction))
            along = np.einsum("nji,nj->ni", rot_p, w) @ tilt
            J[:, col] = sign * along * q[:, kin.index[axis]] * p.scale * 1e3
    return J
