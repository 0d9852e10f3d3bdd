"""Forward and inverse kinematics of the configured chain, vectorised over poses.

Every axis is a screw given in the bed frame with all axes at 0 (product of
exponentials): a linear axis translates the bodies it carries by ``v * direction``, a
rotary axis turns them by ``v`` about the line through ``point_mm`` along
``direction``.  With every axis at 0 the table frame is the bed frame and the spindle
gauge point is at the bed origin, so

    T_table(q) = prod_{workpiece chain} exp(xi_i q_i)
    T_tool(q)  = prod_{tool chain}      exp(xi_j q_j)
    ball_bed   = T_tool(q) @ tip,   tip = -tool_length * spindle_direction
    ball_table = T_table(q)^-1 @ ball_bed.

Inverse kinematics takes the ball centre in the table frame and the rotary angles (a
rotary schedule chooses them) and solves the three linear axes: with the rotary
angles fixed the relation is affine in the linear axes, a 3x3 solve per pose.

Axis values are in mm (linear) and rad (rotary); arrays are ``(n, n_axes)`` in the
order of :attr:`Kinematics.names` (workpiece chain, then tool chain).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..config import Axis, MachineConfig


def _skew(d: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])


def rotation_about(direction: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations ``(n, 3, 3)`` by ``angle (n,)`` about a unit ``direction``."""
    k = _skew(direction)
    k2 = k @ k
    a = np.asarray(angle, dtype=float)[:, None, None]
    return np.eye(3) + np.sin(a) * k + (1.0 - np.cos(a)) * k2


class Kinematics:
    """The machine's two branches as screws; see the module docstring."""

    def __init__(self, machine: MachineConfig):
        self.machine = machine
        self.axes: tuple[Axis, ...] = tuple(machine.axis(n) for n in
                                            machine.workpiece_chain + machine.tool_chain)
        self.names = tuple(a.name for a in self.axes)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.workpiece = tuple(self.index[n] for n in machine.workpiece_chain)
        self.tool = tuple(self.index[n] for n in machine.tool_chain)
        self.linear = tuple(i for i, a in enumerate(self.axes) if not a.is_rotary)
        self.rotary = tuple(i for i, a in enumerate(self.axes) if a.is_rotary)
        self.tip_mm = -machine.tool_length_mm * np.array(machine.spindle_direction)
        self._dir = [np.array(a.direction) for a in self.axes]
        self._point = [np.array(a.point_mm) for a in self.axes]

    # ------------------------------------------------------------------ transforms

    def _axis_transform(self, i: int, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation ``(n, 3, 3)`` and translation ``(n, 3)`` of axis ``i``."""
        n = len(values)
        d = self._dir[i]
        if self.axes[i].is_rotary:
            rot = rotation_about(d, values)
            c = self._point[i]
            return rot, c - rot @ c
        return np.broadcast_to(np.eye(3), (n, 3, 3)), values[:, None] * d

    def chain_transforms(self, q: np.ndarray, chain: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Bed -> body transform after each axis of ``chain``: list of (R, t)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        n = len(q)
        rot = np.broadcast_to(np.eye(3), (n, 3, 3))
        trans = np.zeros((n, 3))
        out = []
        for i in chain:
            r_i, t_i = self._axis_transform(i, q[:, i])
            trans = trans + np.einsum("nij,nj->ni", rot, t_i)
            rot = rot @ r_i
            out.append((rot, trans))
        return out

    def _end_of(self, q: np.ndarray, chain: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        transforms = self.chain_transforms(q, chain)
        if transforms:
            return transforms[-1]
        n = len(np.atleast_2d(q))
        return np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3))

    def table_transform(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bed -> table frame: rotation ``(n, 3, 3)``, translation ``(n, 3)``."""
        return self._end_of(q, self.workpiece)

    def tool_transform(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bed -> spindle frame."""
        return self._end_of(q, self.tool)

    def body_transforms(self, q: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Bed -> body for ``bed`` and every axis body (the body an axis moves)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        n = len(q)
        out = {"bed": (np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3)))}
        for chain in (self.workpiece, self.tool):
            for i, rt in zip(chain, self.chain_transforms(q, chain)):
                out[self.names[i]] = rt
        return out

    # ------------------------------------------------------------------ kinematics

    def tool_ball_bed(self, q: np.ndarray) -> np.ndarray:
        rot, trans = self.tool_transform(q)
        return np.einsum("nij,j->ni", rot, self.tip_mm) + trans

    def forward(self, q: np.ndarray) -> np.ndarray:
        """Ball centre ``(n, 3)`` in the table frame for axis values ``q (n, n_axes)``."""
        rot, trans = self.table_transform(q)
        ball = self.tool_ball_bed(q)
        return np.einsum("nji,nj->ni", rot, ball - trans)

    def inverse(self, points_mm, rotary_rad: Mapping[str, np.ndarray]) -> np.ndarray:
        """Axis values ``(n, n_axes)`` that put the ball centre at ``points_mm (n, 3)``
        (table frame) with the rotary axes at ``rotary_rad`` (name -> ``(n,)``)."""
        p = np.atleast_2d(np.asarray(points_mm, dtype=float))
        n = len(p)
        q = np.zeros((n, len(self.axes)))
        for i in self.rotary:
            name = self.names[i]
            if name not in rotary_rad:
                raise KeyError(f"no angle given for rotary axis {name}")
            q[:, i] = np.broadcast_to(np.asarray(rotary_rad[name], dtype=float), (n,))
        # with the linear axes at 0: where the table puts p, and where the tool ball is
        rot_w, trans_w = self.table_transform(q)
        target = np.einsum("nij,nj->ni", rot_w, p) + trans_w
        ball = self.tool_ball_bed(q)
        # each linear axis adds q_i * (its direction, turned by the axes before it)
        columns = np.zeros((n, 3, 3))
        for col, i in enumerate(self.linear):
            chain = self.workpiece if i in self.workpiece else self.tool
            before = chain[: chain.index(i)]
            if before:
                rot_before = self.chain_transforms(q, before)[-1][0]
                d = np.einsum("nij,j->ni", rot_before, self._dir[i])
            else:
                d = np.broadcast_to(self._dir[i], (n, 3))
            columns[:, :, col] = d if i in self.workpiece else -d
        rhs = ball - target
        lin = np.linalg.solve(columns, rhs[:, :, None])[:, :, 0]
        for col, i in enumerate(self.linear):
            q[:, i] = lin[:, col]
        return q
