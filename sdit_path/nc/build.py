"""From a layer path to a controller-neutral :class:`~sdit_path.nc.program.Program`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import PurePath

import numpy as np

from ..config import Config
from ..geometry.hemisphere import Hemisphere
from ..geometry.nurbs import round_to_decimals
from ..geometry.paths import Dwell as PathDwell
from ..geometry.paths import LayerPath, Remount, Run
from .chords import chords_for_range
from .program import Comment, Dwell, LinearMove, PolylineMove, Program, ProgramStop, SplineMove
from .text import program_name


@dataclass(frozen=True, slots=True)
class BuiltProgram:
    """A neutral program and what it achieves: the largest radial deviation from the
    sphere per piece (segment or transit id), in mm, as it will be emitted."""

    program: Program
    piece_deviation_mm: dict[str, float]

    @property
    def max_deviation_mm(self) -> float:
        return max(self.piece_deviation_mm.values())


def greville(knots: np.ndarray, degree: int) -> np.ndarray:
    """Greville abscissae of the control points ``(n,)``."""
    n = len(knots) - degree - 1
    return np.array([knots[j + 1: j + degree + 1].mean() for j in range(n)])


def _spline_move(run: Run, feed: float) -> SplineMove:
    curve = run.curve
    g = greville(curve.knots, curve.degree)
    labels = []
    for piece in run.pieces:
        j = int(np.searchsorted(g, piece.u_start - 1e-9))
        labels.append((max(1, j), piece.id))
    intervals = len(curve.interval_knots) - 1
    knot_interval = max(round(run.length_mm / intervals, 3), 0.001)
    return SplineMove(curve, feed, knot_interval, tuple(labels))


def build_program(path: LayerPath, config: Config, hemi: Hemisphere, controller: str,
                  path_form: str, version: str) -> BuiltProgram:
    """Neutral program of one layer for a controller whose native path form is
    ``path_form`` (``"spline"`` or ``"chords"``)."""
    post, test = config.post, config.test
    decimals = post.decimals
    feed = test.feed_mm_per_min
    name = program_name(post.program_prefix, path.layer)
    deviation: dict[str, float] = {}
    body: list = []
    start = round_to_decimals(path.start_mm, decimals)
    where = f"node {path.start_node}" if path.start_node else "the start point"
    body.append(Comment(f"start at {where}: mount the ballbar here"))
    body.append(LinearMove(start, feed))
    current = start
    for item in path.items:
        if isinstance(item, PathDwell):
            body.append(Dwell(item.seconds, item.node_id))
            continue
        if isinstance(item, Remount):
            skipped = ", ".join(item.skipped) if item.skipped else "none"
            body.append(Comment(f"left out (infeasible, see plan.json): {skipped}"))
            body.append(ProgramStop("remove the ballbar, then cycle start: the machine repositions"))
            for p in item.via_mm:
                body.append(LinearMove(round_to_decimals(p, decimals), feed))
            body.append(LinearMove(round_to_decimals(item.to_mm, decimals), feed))
            body.append(ProgramStop("mount the ballbar here, then cycle start"))
            current = round_to_decimals(item.to_mm, decimals)
            continue
        if path_form == "spline":
            body.append(_spline_move(item, feed))
            for piece in item.pieces:
                deviation[piece.id] = max(deviation.get(piece.id, 0.0), piece.max_radial_deviation_mm)
            current = item.curve.control_points_mm[-1]
            continue
        points, labels = [], []
        end_node = (round_to_decimals(hemi.node(item.end_node).position_mm, decimals)
                    if item.end_node else item.curve.control_points_mm[-1])
        for k, piece in enumerate(item.pieces):
            last = k == len(item.pieces) - 1
            verts, dev = chords_for_range(
                item.curve, piece.u_start, piece.u_end, hemi.centre_mm, hemi.radius_mm,
                post.chord_tolerance_um * 1e-3, decimals, f"layer {path.layer}, {piece.id}",
                start_mm=current, end_mm=end_node if last else None)
            labels.append((sum(len(p) for p in points), piece.id))
            points.append(verts)
            current = verts[-1]
            deviation[piece.id] = max(deviation.get(piece.id, 0.0), dev)
        body.append(PolylineMove(np.vstack(points), feed, tuple(labels)))

    layer = next(la for la in hemi.layers if la.name == path.layer)
    worst_um = max(deviation.values()) * 1e3
    c = hemi.centre_mm
    if path_form == "spline":
        form = (f"path: B-spline degree {post.spline_degree}, uniform knots; max radial deviation "
                f"from the sphere as emitted {worst_um:.4f} um (limit {post.spline_tolerance_um:g} um;"
                f" needs a control resolution of {decimals} decimals)")
    else:
        form = (f"path: 3-D G1 chords; max radial deviation from the sphere as emitted "
                f"{worst_um:.4f} um (tolerance {post.chord_tolerance_um:g} um, sagitta included)")
    header = (
        f"{name}: SDIT layer {layer.name}, track {layer.lower_track} up to "
        f"{layer.upper_track}, machine {config.machine.name}",
        f"generated by sdit-path {version} from {PurePath(config.source).name}",
        f"sphere centre (pivot ball) X{c[0]:.{decimals}f} Y{c[1]:.{decimals}f} "
        f"Z{c[2]:.{decimals}f} in {post.work_offset}, radius {hemi.radius_mm:g} mm (bar length)",
        "programmed point = spindle ball centre: tool length offset of the ballbar cup active",
        f"feed {feed:g} mm/min (G94), dwell {test.dwell_s:g} s at every static node",
        form,
        f"segments {layer.segments[0].id}..{layer.segments[-1].id}, passes "
        f"{' + '.join(test.passes)}, projection {test.projection}",
        (f"start and end: node {path.start_node}; every move stays on the sphere"
         if not path.omitted else
         f"left out as infeasible: {', '.join(path.omitted)} (the bar is remounted around them)"),
    ) + ((post.comment,) if post.comment else ())
    program = Program(name=name, controller=controller, layer=path.layer, header=header,
                      work_offset=post.work_offset, decimals=decimals,
                      tolerance_mm=(post.spline_tolerance_um if path_form == "spline"
                                    else post.chord_tolerance_um) * 1e-3,
                      items=tuple(body))
    return BuiltProgram(program, deviation)
