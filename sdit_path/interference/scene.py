"""The collision scene: machine parts from the config plus the ballbar itself.

Every part hangs on a body of the kinematic chain (``bed`` or the body an axis moves)
and is placed as it sits with every axis at 0, in the bed frame.  Primitives are exact
python-fcl shapes; STL meshes are read with trimesh and become fcl BVH models.
sdit-path adds three parts of its own: ``pivot_ball`` (on the table), ``tool_ball``
(on the spindle) and ``bar``, the tube between the two ball surfaces, which is posed
afresh for every pose.

Checked pairs: every tool-side part against every workpiece-side part (parts on the
same side move together and are the machine's own business), and the bar against
every part but its two balls; minus ``scene.allowed_contacts``.

fcl's GJK answers wrongly, by millimetres and on the unsafe side, when two flat faces
are exactly parallel and aligned (coaxial cylinders cap to cap: 181 mm reported for
170 mm), and machines are full of such alignments.  Every part is therefore turned by
a fixed, distinct rotation of ``JITTER_RAD`` about its own centre, which removes the
degeneracy, and the bound of what that turn can change, ``JITTER_RAD * (r_a + r_b)``,
is subtracted from every distance: reported clearances are conservative, within a few
micrometres of the truth (tests compare against hand-computed distances).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import fcl
import numpy as np

from ..config import Config, ScenePart
from ..errors import ConfigError
from ..machine.kinematics import Kinematics


#: Tilt given to every part to keep fcl's GJK out of degenerate alignments (rad).
JITTER_RAD = 1e-5
#: Allowance for GJK's own convergence tolerance (mm).
GJK_ALLOWANCE_MM = 1e-4


def _jitter(k: int) -> np.ndarray:
    """A fixed rotation by ``JITTER_RAD`` about the k-th of a spiral of axes."""
    golden = np.pi * (3.0 - np.sqrt(5.0))
    z = 1.0 - 2.0 * ((k * 0.618034 + 0.25) % 1.0)
    r = np.sqrt(1.0 - z * z)
    axis = np.array([r * np.cos(golden * (k + 1)), r * np.sin(golden * (k + 1)), z])
    kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(JITTER_RAD) * kx + (1 - np.cos(JITTER_RAD)) * kx @ kx


def rotation_z_to(axis) -> np.ndarray:
    """A rotation taking +Z to the unit vector ``axis``."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, a)
    c = float(z @ a)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k * (1.0 / (1.0 + c))


def rotations_z_to(axes: np.ndarray) -> np.ndarray:
    """Vectorised :func:`rotation_z_to` for unit vectors ``(n, 3)`` -> ``(n, 3, 3)``."""
    a = np.asarray(axes, dtype=float)
    n = len(a)
    c = a[:, 2]
    k = np.zeros((n, 3, 3))
    # v = z x a = (-a_y, a_x, 0)
    k[:, 0, 2], k[:, 1, 2] = a[:, 0], a[:, 1]
    k[:, 2, 0], k[:, 2, 1] = -a[:, 0], -a[:, 1]
    flip = c < -1 + 1e-9
    scale = np.where(flip, 0.0, 1.0 / np.where(flip, 1.0, 1.0 + c))
    out = np.eye(3) + k + (k @ k) * scale[:, None, None]
    out[flip] = np.diag([1.0, -1.0, -1.0])
    return out


@dataclass
class Part:
    """A posed collision object.  ``rot_home``/``pos_home`` place it in its body frame;
    ``radius_mm`` bounds its points' distance from ``pos_home``."""

    name: str
    body: str
    obj: fcl.CollisionObject
    rot_home: np.ndarray
    pos_home: np.ndarray
    radius_mm: float
    side: str  # "tool", "work" or "bar"
    exact: bool  # signed distance available (primitives)
    shape: str = "mesh"
    size_mm: tuple[float, ...] = ()


def _geometry(part: ScenePart, base_dir: Path) -> tuple[object, float, bool]:
    s = part.size_mm
    if part.shape == "box":
        return fcl.Box(*s), 0.5 * float(np.linalg.norm(s)), True
    if part.shape == "cylinder":
        return fcl.Cylinder(s[0], s[1]), float(np.hypot(s[0], s[1] / 2)), True
    if part.shape == "capsule":
        return fcl.Capsule(s[0], s[1]), s[0] + s[1] / 2, True
    if part.shape == "sphere":
        return fcl.Sphere(s[0]), s[0], True
    import trimesh

    path = (base_dir / part.mesh_file) if not Path(part.mesh_file).is_absolute() else Path(part.mesh_file)
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many kinds; name the file either way
        raise ConfigError(f"{path}", f"scene part {part.name!r}: cannot read the mesh: {exc}") from None
    if len(mesh.faces) == 0:
        raise ConfigError(f"{path}", f"scene part {part.name!r}: the mesh has no faces")
    bvh = fcl.BVHModel()
    bvh.beginModel(len(mesh.vertices), len(mesh.faces))
    bvh.addSubModel(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int32))
    bvh.endModel()
    return bvh, float(np.linalg.norm(mesh.vertices, axis=1).max()), False


class Scene:
    """Parts, the pairs to check, and their clearance over many poses."""

    def __init__(self, config: Config, kinematics: Kinematics):
        self.kin = kinematics
        m = config.machine
        base_dir = Path(config.source).resolve().parent
        table_body = m.workpiece_chain[-1] if m.workpiece_chain else "bed"
        tool_body = m.tool_chain[-1] if m.tool_chain else "bed"
        tool_side = set(m.tool_chain)
        self.parts: list[Part] = []
        for sp in config.scene.parts:
            geom, radius, exact = _geometry(sp, base_dir)
            rot = np.eye(3) if sp.shape == "mesh" else rotation_z_to(sp.axis)
            pos = np.array(sp.position_mm, dtype=float)
            if sp.shape == "mesh":  # mesh vertices are in the bed frame; position shifts them
                radius += float(np.linalg.norm(pos))
                pos_home = pos
            else:
                pos_home = pos
            self.parts.append(Part(sp.name, sp.body, fcl.CollisionObject(geom, fcl.Transform()),
                                   rot, pos_home, radius, "tool" if sp.body in tool_side else "work",
                                   exact, sp.shape, tuple(sp.size_mm)))
        b = config.ballbar
        r_ball = b.ball_diameter_mm / 2
        self.parts.append(Part("pivot_ball", table_body, fcl.CollisionObject(fcl.Sphere(r_ball), fcl.Transform()),
                               np.eye(3), np.array(b.pivot_mm), r_ball, "work", True, "sphere", (r_ball,)))
        self.parts.append(Part("tool_ball", tool_body, fcl.CollisionObject(fcl.Sphere(r_ball), fcl.Transform()),
                               np.eye(3), kinematics.tip_mm.copy(), r_ball, "tool", True, "sphere", (r_ball,)))
        bar_len = b.bar_length_mm - b.ball_diameter_mm
        self.parts.append(Part("bar", "bar", fcl.CollisionObject(fcl.Cylinder(b.bar_diameter_mm / 2, bar_len),
                                                                  fcl.Transform()),
                               np.eye(3), np.zeros(3), float(np.hypot(b.bar_diameter_mm / 2, bar_len / 2)),
                               "bar", True, "cylinder", (b.bar_diameter_mm / 2, bar_len)))
        self.pivot_mm = np.array(b.pivot_mm)
        self.ball_radius_mm = r_ball
        self._bar_len = bar_len
        allowed = {frozenset(p) for p in config.scene.allowed_contacts}
        names = [p.name for p in self.parts]
        self.pairs: list[tuple[int, int]] = []
        for i, a in enumerate(self.parts):
            for j in range(i + 1, len(self.parts)):
                c = self.parts[j]
                if frozenset((a.name, c.name)) in allowed:
                    continue
                sides = {a.side, c.side}
                if sides == {"tool", "work"}:
                    self.pairs.append((i, j))
                elif "bar" in sides and len(sides) == 2:
                    other = c if a.side == "bar" else a
                    if other.name not in ("pivot_ball", "tool_ball"):
                        self.pairs.append((i, j))
        self.pair_names = [(names[i], names[j]) for i, j in self.pairs]
        self._req = fcl.DistanceRequest(enable_signed_distance=True)
        self._jit = [_jitter(k) for k in range(len(self.parts))]
        for p, jit in zip(self.parts, self._jit):
            if p.body != "bar":
                p.rot_home = p.rot_home @ jit
        self._allowance = np.array([JITTER_RAD * (self.parts[i].radius_mm + self.parts[j].radius_mm)
                                    + GJK_ALLOWANCE_MM for i, j in self.pairs])

    # ------------------------------------------------------------------ posing

    def part_poses(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """World rotation ``(n, 3, 3)`` and position ``(n, 3)`` of every part."""
        bodies = self.kin.body_transforms(q)
        out = []
        for p in self.parts:
            if p.body == "bar":
                rot_w, trans_w = self.kin.table_transform(q)
                pivot = np.einsum("nij,j->ni", rot_w, self.pivot_mm) + trans_w
                ball = self.kin.tool_ball_bed(q)
                d = ball - pivot
                d = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
                bar = next(k for k, x in enumerate(self.parts) if x.body == "bar")
                out.append((rotations_z_to(d) @ self._jit[bar], 0.5 * (pivot + ball)))
                continue
            rot_b, trans_b = bodies[p.body]
            out.append((rot_b @ p.rot_home, np.einsum("nij,j->ni", rot_b, p.pos_home) + trans_b))
        return out

    @staticmethod
    def _point_distance(part: Part, rot: np.ndarray, pos: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """Distance ``(n,)`` from points ``(n, 3)`` to ``part`` posed at (rot, pos), zero
        inside; exact for primitives, a bounding sphere for meshes."""
        local = np.einsum("nji,nj->ni", rot, pts - pos)
        if part.shape == "box":
            half = np.array(part.size_mm) / 2
            return np.linalg.norm(np.maximum(np.abs(local) - half, 0.0), axis=1)
        if part.shape == "cylinder":
            r, half = part.size_mm[0], part.size_mm[1] / 2
            radial = np.maximum(np.hypot(local[:, 0], local[:, 1]) - r, 0.0)
            axial = np.maximum(np.abs(local[:, 2]) - half, 0.0)
            return np.hypot(radial, axial)
        if part.shape == "capsule":
            r, half = part.size_mm[0], part.size_mm[1] / 2
            z = np.clip(local[:, 2], -half, half)
            return np.maximum(np.linalg.norm(local - np.stack([0 * z, 0 * z, z], 1), axis=1) - r, 0.0)
        if part.shape == "sphere":
            return np.maximum(np.linalg.norm(local, axis=1) - part.size_mm[0], 0.0)
        return np.maximum(np.linalg.norm(local, axis=1) - part.radius_mm, 0.0)

    def lower_bounds(self, poses: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """A lower bound ``(n, n_pairs)`` of every clearance, from the exact distance of
        the smaller part's bounding sphere to the larger part (vectorised)."""
        n = len(poses[0][1])
        out = np.empty((n, len(self.pairs)))
        for c, (a, b) in enumerate(self.pairs):
            big, small = (a, b) if self.parts[a].radius_mm >= self.parts[b].radius_mm else (b, a)
            rot_s, pos_s = poses[small]
            rot_b, pos_b = poses[big]
            d = self._point_distance(self.parts[big], rot_b, pos_b, pos_s)
            out[:, c] = d - self.parts[small].radius_mm - self._allowance[c] - 1e-6
        return out

    def _spheres(self, poses, i: int, pair: int) -> float | None:
        """The signed distance of two spheres, from their centres (fcl's signed distance
        does not return for two spheres with one centre); None for other shapes."""
        a, b = self.pairs[pair]
        pa, pb = self.parts[a], self.parts[b]
        if pa.shape != "sphere" or pb.shape != "sphere":
            return None
        d = float(np.linalg.norm(poses[a][1][i] - poses[b][1][i]))
        return d - pa.size_mm[0] - pb.size_mm[0] - float(self._allowance[pair])

    def exact(self, poses: list[tuple[np.ndarray, np.ndarray]], i: int, pair: int) -> float:
        """fcl distance of ``pair`` at pose ``i`` (conservative, see the module)."""
        spheres = self._spheres(poses, i, pair)
        if spheres is not None:
            return spheres
        a, b = self.pairs[pair]
        for k in (a, b):
            rot, pos = poses[k]
            self.parts[k].obj.setTransform(fcl.Transform(rot[i], pos[i]))
        return fcl.distance(self.parts[a].obj, self.parts[b].obj, self._req,
                            fcl.DistanceResult()) - self._allowance[pair]

    def clearances(self, q: np.ndarray) -> np.ndarray:
        """Distance ``(n, n_pairs)`` in mm for every pose and checked pair; zero or
        negative is a collision (signed for primitives, -1 for a mesh overlap)."""
        q = np.atleast_2d(q)
        poses = self.part_poses(q)
        n = len(q)
        out = np.empty((n, len(self.pairs)))
        moving = [k for k, p in enumerate(self.parts) if p.body != "bed"]
        static = [k for k, p in enumerate(self.parts) if p.body == "bed"]
        for k in static:
            rot, pos = poses[k]
            self.parts[k].obj.setTransform(fcl.Transform(rot[0], pos[0]))
        objs = [p.obj for p in self.parts]
        req = self._req
        for i in range(n):
            for k in moving:
                rot, pos = poses[k]
                objs[k].setTransform(fcl.Transform(rot[i], pos[i]))
            for c, (a, b) in enumerate(self.pairs):
                spheres = self._spheres(poses, i, c)
                out[i, c] = (spheres + self._allowance[c] if spheres is not None else
                             fcl.distance(objs[a], objs[b], req, fcl.DistanceResult()))
        return out - self._allowance

    def nearest_points(self, q: np.ndarray, pair: int) -> tuple[np.ndarray, np.ndarray]:
        """Nearest (or deepest) points, bed frame, of ``pair`` at one pose ``q``."""
        poses = self.part_poses(np.atleast_2d(q))
        a, b = self.pairs[pair]
        for k in (a, b):
            rot, pos = poses[k]
            self.parts[k].obj.setTransform(fcl.Transform(rot[0], pos[0]))
        res = fcl.DistanceResult()
        fcl.distance(self.parts[a].obj, self.parts[b].obj,
                     fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True), res)
        return np.array(res.nearest_points[0]), np.array(res.nearest_points[1])
