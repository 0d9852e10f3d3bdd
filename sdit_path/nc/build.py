"""From a layer path to a controller-neutral :class:`~sdit_path.nc.program.Program`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast
from pathlib import PurePath

import numpy as np

from ..config import Config
from ..errors import PlanError
from ..geometry.hemisphere import Hemisphere
from ..fixed_point import round_to_decimals
from ..geometry.paths import Dwell as PathDwell
from ..geometry.nurbs import BSplineCurve, max_radial_deviation, rounded_on_sphere
from ..geometry.paths import LayerPath, Remount, Run
from ..machine.approach import OperatorSequence
from ..machine.kinematics import Kinematics
from ..machine.schedule import RotarySchedule
from .chords import ChordLimits, CornerModel, on_grid, run_chords
from .five_axis import AxisTrack, round_axis_values, machine_chords, machine_spline, rotary_controls
from ..program_marks import TEST_BEGINS, TEST_ENDS
from .program import (AxisMove, Comment, Dwell, LinearMove, PolylineMove, Program, ProgramStop,
                      SplineMove)
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


def _labels(curve: BSplineCurve, run: Run) -> tuple[tuple[int, str], ...]:
    g = greville(curve.knots, curve.degree)
    return tuple((max(1, int(np.searchsorted(g, piece.u_start - 1e-9))), piece.id)
                 for piece in run.pieces)


def _knot_interval(curve: BSplineCurve, run: Run) -> float:
    intervals = len(curve.interval_knots) - 1
    return max(round(run.length_mm / intervals, 3), 0.001)


def program_frame(config: Config, path_form: str, five_axis: str | None = None) -> str:
    """``table``, ``traori``, ``tcpm`` or ``machine``: see
    :class:`~sdit_path.nc.program.Program`.  ``five_axis``: how the control takes a
    five-axis path (``tcpm``: the ball centre in the table frame with the rotary
    words, its tool-centre-point control on; None: ``post.five_axis_mode`` for a
    native spline, machine axis values for chords)."""
    if config.test.rotary.schedule != "moving":
        return "table"
    if five_axis is not None:
        return five_axis
    if path_form == "spline" and config.post.five_axis_mode == "traori":
        return "traori"
    return "machine"


#: what the operator does at each stop (our text, never the user's)
MOUNT = ("the ballbar is NOT mounted yet: mount it between the pivot and the tool cup, "
         "start the recording, then cycle start")
DISMOUNT = "test done: stop the recording, take the ballbar off, then cycle start to retract"


def opening(operator: OperatorSequence, leg_words, feed: float, where: str) -> list:
    """The approach: Z up alone (from an unknown place), the safe position (the rotary
    axes to their start angles), over the start node, down to it; the mounting stop.
    ``leg_words(point, angles) -> (xyz, rotary words)``: a table-frame point with the
    rotary axes at ``angles`` (name -> rad) as the program writes it."""
    legs = operator.approach
    angles = dict(operator.angles_rad)
    safe_xyz, _ = leg_words(legs[1].end_mm, angles)
    out: list = [Comment("operator sequence: the bar is not mounted; the first two moves "
                         "leave from wherever the machine stands, Z up first"),
                 AxisMove((("Z", float(safe_xyz[2])),), feed)]
    for leg in legs[1:]:
        xyz, rot = leg_words(leg.end_mm, angles)
        out.append(Comment(leg.name))
        out.append(LinearMove(xyz, feed, rot))
    table = ", ".join(f"{n} {math.degrees(v):.3f} deg" for n, v in operator.angles_rad)
    out.append(ProgramStop(f"at {where}{f' ({table})' if table else ''}: {MOUNT}"))
    out.append(Comment(TEST_BEGINS))
    return out


def closing(operator: OperatorSequence, leg_words, end_angles: dict, feed: float) -> list:
    """After the last dwell: the stop to take the bar off, up to the safe height, back
    to the safe position, the rotary axes where the test left them (``end_angles``)."""
    out: list = [Comment(TEST_ENDS), ProgramStop(DISMOUNT)]
    for leg in operator.retract:
        xyz, rot = leg_words(leg.end_mm, end_angles)
        out.append(Comment(leg.name))
        out.append(LinearMove(xyz, feed, rot))
    return out


def machine_grid_floor_mm(kin: Kinematics, track: AxisTrack, hemi: Hemisphere,
                          decimals: int) -> float:
    """The tolerance a machine-axis program on a coarse grid can hold: twice how far the
    ball moves when every axis is off by half a step of its last decimal (their root
    sum of squares: a rotary axis' 0.0001 deg moves a ball 200 mm from it by 0.17 um),
    at the worst of the hemisphere's nodes, rounded up to 0.01 um."""
    half = 0.5 * 10.0 ** (-decimals)
    pts = np.array([n.position_mm for n in hemi.nodes])
    q, _ = track.q(pts, None)
    base = kin.forward(q)
    move = np.zeros(len(pts))
    for i, ax in enumerate(kin.axes):
        dq = np.zeros(q.shape[1])
        dq[i] = math.radians(half) if ax.is_rotary else half
        move += np.linalg.norm(kin.forward(q + dq) - base, axis=1) ** 2
    return math.ceil(2.0 * float(np.sqrt(move.max())) * 1e5) / 1e5


def build_program(path: LayerPath, config: Config, hemi: Hemisphere, controller: str,
                  path_form: str, version: str, corners: CornerModel | None = None,
                  max_decimals: int = 9, five_axis: str | None = None, number: int = 1,
                  operator: OperatorSequence | None = None) -> BuiltProgram:
    """Neutral program of one layer for a controller whose native path form is
    ``path_form`` (``"spline"`` or ``"chords"``); ``corners`` says when that control
    joins two chords at the feed (chords only; None: any turn); ``max_decimals``: the
    most decimals of a millimetre the control reads (``post.decimals`` beyond it are
    not written); ``five_axis``: see :func:`program_frame`; ``operator``: the way to the
    bar before the first dwell and back after the last (None: the program starts at
    the start node, the bar mounted)."""
    post, test = config.post, config.test
    decimals = min(post.decimals, max_decimals)
    feed = test.feed_mm_per_min
    frame = program_frame(config, path_form, five_axis)
    kin = Kinematics(config.machine)
    track = AxisTrack(kin, RotarySchedule(config, kin))
    rot_names = tuple(kin.names[i] for i in kin.rotary)
    lin = list(kin.linear)
    locked = tuple((n, round(math.degrees(v), decimals) + 0.0) for n, v in test.rotary.locked_rad)
    # a spline's control points on a coarse grid (a control reading 4 decimals): the
    # nodes it passes through lie within half a step of the sphere at best
    spline_tol = max(post.spline_tolerance_um * 1e-3, 0.5 * 10.0 ** (-decimals)
                     if decimals < post.decimals else 0.0)
    chord_tol = post.chord_tolerance_um * 1e-3
    curve_tol = post.chord_curve_tolerance_um * 1e-3
    accel = [kin.axes[i].max_acceleration for i in kin.linear]
    name = program_name(post.program_prefix, path.layer)
    deviation: dict[str, float] = {}
    from_curve: dict[str, float] = {}
    turns: list[tuple[float, float, int]] = []  # per table-frame run: worst, limit, above it
    body: list = []
    carry = None

    grid_floor = (machine_grid_floor_mm(kin, track, hemi, decimals)
                  if frame == "machine" and decimals < post.decimals else 0.0)
    chord_tol, spline_tol = max(chord_tol, grid_floor), max(spline_tol, grid_floor)
    written_tol = chord_tol if path_form == "chords" else spline_tol

    def on_sphere(p_table: np.ndarray) -> np.ndarray:
        """A node (or a point of the sphere) as the program writes it: rounded, and
        where the grid is coarse for the tolerance, the grid point nearest the sphere."""
        return on_grid(p_table, hemi.centre_mm, hemi.radius_mm, decimals, written_tol)

    def words(p_table: np.ndarray, carry_in):
        """A point of the table frame as program words: (xyz, rotary words, carry)."""
        if frame == "table":
            return on_sphere(p_table), locked, carry_in
        q, carry_out = track.q(np.asarray(p_table)[None, :], carry_in)
        rot = tuple((n, round(math.degrees(q[0, kin.index[n]]), decimals) + 0.0) for n in rot_names)
        if frame in ("traori", "tcpm"):
            return on_sphere(p_table), rot, carry_out
        return round_to_decimals(q[0, lin], decimals), rot, carry_out

    def note(run: Run, devs) -> None:
        for piece, d in zip(run.pieces, devs):
            deviation[piece.id] = max(deviation.get(piece.id, 0.0), d)

    where = f"node {path.start_node}" if path.start_node else "the start point"
    def leg_words(p_table: np.ndarray, angles: dict):
        """A point off the sphere with the rotary axes held at ``angles`` (rad)."""
        p = np.asarray(p_table, dtype=float)
        if frame == "table":
            return round_to_decimals(p, decimals), locked
        rot = tuple((n, round(math.degrees(angles[n]), decimals) + 0.0) for n in rot_names)
        if frame in ("traori", "tcpm"):
            return round_to_decimals(p, decimals), rot
        q = kin.inverse(p[None, :], {n: np.array([v]) for n, v in angles.items()})[0]
        return round_to_decimals(q[lin], decimals), rot

    if operator is not None:
        body += opening(operator, leg_words, post.approach_feed_mm_per_min, where)
        body.append(Comment(f"start at {where}"))
    else:
        body.append(Comment(f"start at {where}: mount the ballbar here"))
    xyz, rot, carry = words(path.start_mm, carry)
    body.append(LinearMove(xyz, feed, rot))
    current_table = on_sphere(path.start_mm)
    current_q = None
    if frame == "machine":
        current_q = kin.inverse(current_table[None, :], track.angles(current_table[None, :], None)[0])[0]
        current_q = round_axis_values(current_q, kin, decimals)
    for item in path.items:
        if isinstance(item, PathDwell):
            body.append(Dwell(item.seconds, item.node_id))
            continue
        if isinstance(item, Remount):
            skipped = ", ".join(item.skipped) if item.skipped else "none"
            body.append(Comment(f"left out (infeasible, see plan.json): {skipped}"))
            body.append(ProgramStop("remove the ballbar, then cycle start: the machine repositions"))
            target_carry = track.angles(item.to_mm[None, :], carry)[1] if frame != "table" else carry
            for k, p in enumerate(list(item.via_mm) + [item.to_mm]):
                xyz, rot, _ = words(p, carry if k == 0 else target_carry)
                body.append(LinearMove(xyz, feed, rot))
            carry = target_carry
            body.append(ProgramStop("mount the ballbar here, then cycle start"))
            current_table = on_sphere(item.to_mm)
            if frame == "machine":
                current_q = round_axis_values(kin.inverse(current_table[None, :],
                                                 track.angles(current_table[None, :], carry)[0])[0],
                                     kin, decimals)
            continue
        run: Run = item
        label = f"layer {path.layer}"
        run_f = run.feed_mm_per_min  # a re-planned sector at its own feed
        rotary: tuple[tuple[str, np.ndarray], ...] = ()
        if frame in ("table", "traori") and path_form == "spline":
            if frame == "traori":
                ctrl, carry = rotary_controls(run.curve, track, carry, decimals)
                rotary = tuple((n, ctrl[n]) for n in rot_names)
            curve = run.curve
            devs = [p.max_radial_deviation_mm for p in run.pieces]
            if decimals < post.decimals:  # a control that reads fewer decimals than fitted
                cps = curve.control_points_mm.copy()
                cps[0] = current_table
                cps[-1] = on_sphere(cps[-1])
                curve = rounded_on_sphere(BSplineCurve(curve.degree, curve.knots, cps,
                                                       curve.weights),
                                          hemi.centre_mm, hemi.radius_mm, decimals)
                devs = max_radial_deviation(curve, hemi.centre_mm, hemi.radius_mm,
                                            [(p.u_start, p.u_end) for p in run.pieces])
                if max(devs) > spline_tol:
                    raise PlanError(f"{label}: the spline's control points at {decimals} decimals "
                                    f"leave the sphere by {max(devs) * 1e3:.4f} um, over the "
                                    f"{spline_tol * 1e3:g} um limit")
            body.append(SplineMove(curve, run_f, _knot_interval(curve, run),
                                   _labels(curve, run), rotary))
            note(run, devs)
            current_table = curve.control_points_mm[-1]
        elif frame == "machine" and path_form == "spline":
            qcurve, devs, carry = machine_spline(run, track, carry, hemi.centre_mm, hemi.radius_mm,
                                                 spline_tol, decimals, label)
            qctrl = qcurve.control_points_mm
            xyz_curve = BSplineCurve(qcurve.degree, qcurve.knots, qctrl[:, lin])
            rotary = tuple((n, np.degrees(qctrl[:, kin.index[n]])) for n in rot_names)
            body.append(SplineMove(xyz_curve, run_f, _knot_interval(qcurve, run),
                                   _labels(qcurve, run), rotary))
            note(run, devs)
            current_q = qctrl[-1]
        elif frame == "machine":
            q, lengths, labels, devs, offs, carry = machine_chords(
                run, track, carry, hemi.centre_mm, hemi.radius_mm, chord_tol, decimals,
                cast(np.ndarray, current_q), label, curve_tol)
            for piece, off in zip(run.pieces, offs):
                from_curve[piece.id] = max(from_curve.get(piece.id, 0.0), off)
            rotary = tuple((n, np.degrees(q[:, kin.index[n]])) for n in rot_names)
            body.append(PolylineMove(q[:, lin], run_f, labels, rotary,
                                     run_f / np.maximum(lengths, 1e-9)))
            note(run, devs)
            current_q = q[-1]
        else:  # table-frame chords
            end_node = (on_sphere(hemi.node(run.end_node).position_mm)
                        if run.end_node else run.curve.control_points_mm[-1])
            limits = ChordLimits(radial_mm=chord_tol, curve_mm=curve_tol)
            if corners is not None:
                f_s = run_f / 60.0
                limits = ChordLimits(chord_tol, curve_tol, corners.turn_limit_rad(f_s, accel, chord_tol),
                                     corners.shortest_chord_mm(f_s))
            chords = run_chords(run.curve, run.pieces, hemi.centre_mm, hemi.radius_mm, limits,
                                decimals, label, start_mm=current_table, end_mm=end_node)
            for piece, d, off in zip(run.pieces, chords.radial_mm, chords.curve_mm):
                deviation[piece.id] = max(deviation.get(piece.id, 0.0), d)
                from_curve[piece.id] = max(from_curve.get(piece.id, 0.0), off)
            turns.append((chords.max_turn_rad, limits.turn_rad, chords.sharp_corners))
            current_table = chords.points_mm[-1]
            if frame == "tcpm":  # the rotary words of every vertex, the ball kept by the control
                q, carry = track.q(chords.points_mm, carry)
                rotary = tuple((n, round_to_decimals(np.degrees(q[:, kin.index[n]]), decimals) + 0.0)
                               for n in rot_names)
            body.append(PolylineMove(chords.points_mm, run_f, chords.labels, rotary))

    if operator is not None:
        # the rotary axes where the test left them (unwrapped: no turn back)
        end_node = operator.retract[0].points_mm[0]
        end_angles = {n: float(v[0]) for n, v in track.angles(end_node[None, :], carry)[0].items()}
        body += closing(operator, leg_words, end_angles, post.approach_feed_mm_per_min)
    layer = next(la for la in hemi.layers if la.name == path.base_layer)
    worst_um = max(deviation.values()) * 1e3
    c = hemi.centre_mm
    frames = {"table": f"ball centre in the table frame, work offset {post.work_offset}",
              "traori": f"ball centre in the table frame, work offset {post.work_offset}, "
                        f"TRAORI on, rotary axes {' '.join(rot_names)} programmed with it",
              "tcpm": f"ball centre in the table frame, work offset {post.work_offset}, "
                      f"tool centre point control on, rotary axes {' '.join(rot_names)} "
                      f"as machine angles",
              "machine": f"machine axis values {' '.join(kin.names)}, work offset must be zero"}
    extra = ""
    if path_form == "spline":
        held = (f"{post.spline_tolerance_um:g} um" if spline_tol <= post.spline_tolerance_um * 1e-3
                else f"{spline_tol * 1e3:g} um, what the control's increment allows, as "
                     f"post.spline_tolerance_um {post.spline_tolerance_um:g} um lies below it")
        form = (f"path: B-spline degree {post.spline_degree}, uniform knots; max radial deviation "
                f"from the sphere as emitted {worst_um:.4f} um (limit {held};"
                f" needs a control resolution of {decimals} decimals)")
    else:
        tol = (f"{post.chord_tolerance_um:g} um" if chord_tol <= post.chord_tolerance_um * 1e-3
               else f"{chord_tol * 1e3:g} um, what the axes' increment allows, as "
                    f"post.chord_tolerance_um {post.chord_tolerance_um:g} um lies below it")
        form = (f"path: 3-D G1 chords; max radial deviation from the sphere as emitted "
                f"{worst_um:.4f} um (tolerance {tol}, sagitta included)")
        if from_curve:
            extra = (f"chords from the planned curve at most "
                     f"{max(from_curve.values()) * 1e3:.4f} um "
                     f"(tolerance {post.chord_curve_tolerance_um:g} um)")
        if turns and corners is not None:
            worst, limit, sharp = max(turns)[0], min(t[1] for t in turns), sum(t[2] for t in turns)
            extra += (f"; consecutive chords turn at most {math.degrees(worst):.3f} deg"
                      + (f" ({sharp} corners above the {math.degrees(limit):.3f} deg the control "
                         f"joins at the feed: it slows there)" if sharp else
                         f" (the control joins up to {math.degrees(limit):.3f} deg at the feed)"))
    order = list(dict.fromkeys(path.segment_order()))
    what = (f"SDIT re-measure of layer {layer.name} sectors "
            f"{', '.join(dict.fromkeys(sid.split('-')[0] for sid in order))}" if path.remeasure
            else f"SDIT layer {layer.name}")
    header = (
        f"{name}: {what}, track {layer.lower_track} up to "
        f"{layer.upper_track}, machine {config.machine.name}",
        f"generated by sdit-path {version} from {PurePath(config.source).name}",
        f"sphere centre (pivot ball) X{c[0]:.{decimals}f} Y{c[1]:.{decimals}f} "
        f"Z{c[2]:.{decimals}f} in {post.work_offset}, radius {hemi.radius_mm:g} mm (bar length)",
        "programmed point = spindle ball centre: tool length offset of the ballbar cup active",
        f"feed {test.feed_mm_per_min:g} mm/min (G94)"
        + "".join(f", sector {sec} at {f:g}" for sec, f in test.sector_feeds(layer.name)
                  if sec in {sid.split("-")[0] for sid in path.segment_order()})
        + f", dwell {test.dwell_s:g} s at every static node",
        form,
        *((extra,) if path_form != "spline" and extra else ()),
        f"segments {order[0] if path.remeasure else layer.segments[0].id}.."
        f"{order[-1] if path.remeasure else layer.segments[-1].id}, passes "
        f"{' + '.join(test.passes)}, projection {test.projection}",
        f"coordinates: {frames[frame]}",
        (f"start and end: node {path.start_node}; every move stays on the sphere"
         if not path.omitted else
         f"left out as infeasible: {', '.join(path.omitted)} (the bar is remounted around them)"),
        *((f"operator sequence at {post.approach_feed_mm_per_min:g} mm/min: Z up to "
           f"{operator.safe_z_mm:g}, safe position, down to node {path.start_node}, M0 to mount "
           f"the bar; at the end M0, bar off, up (legs checked: plan.json)",)
          if operator is not None else ()),
    ) + ((post.comment,) if post.comment else ())
    program = Program(name=name, controller=controller, layer=path.layer, number=number,
                      header=header,
                      work_offset=post.work_offset, decimals=decimals, frame=frame,
                      tolerance_mm=spline_tol if path_form == "spline" else chord_tol,
                      items=tuple(body))
    return BuiltProgram(program, deviation)


def _test_part(program: Program) -> tuple[list, list, list]:
    """A layer program's items: before its test (the approach and the mounting stop),
    the test, and after it (the stop to take the bar off, the retract)."""
    items = list(program.items)
    begin = next(k for k, i in enumerate(items) if isinstance(i, Comment) and i.text == TEST_BEGINS)
    end = next(k for k, i in enumerate(items) if isinstance(i, Comment) and i.text == TEST_ENDS)
    return items[:begin + 1], items[begin + 1:end], items[end:]


def _poses(items: list) -> list[tuple[np.ndarray, tuple]]:
    """The end pose (xyz, rotary words) of every move of ``items``."""
    out = []
    for i in items:
        if isinstance(i, LinearMove):
            out.append((np.asarray(i.point_mm), tuple(i.rotary_deg)))
        elif isinstance(i, PolylineMove):
            for j, p in enumerate(i.points_mm):
                out.append((p, tuple((n, float(v[j])) for n, v in i.rotary_deg)))
        elif isinstance(i, SplineMove):
            out.append((i.curve.control_points_mm[-1],
                        tuple((n, float(v[-1])) for n, v in i.rotary_deg)))
    return out


def master_program(programs: list[Program], name: str) -> Program | str:
    """One program that runs the layer programs (each with its operator sequence) in
    order with the bar mounted once: the first one's approach and mounting stop, every
    test, a stop between two layers to save one recording and start the next, the last
    one's stop and retract.  A string says why there is none: a layer that does not
    start where the one before it ended (node and rotary words), which the bar would
    not survive."""
    parts = [_test_part(p) for p in programs]
    body: list = list(parts[0][0])
    for k, (program, (_, test, _)) in enumerate(zip(programs, parts)):
        if k:
            before, after = _poses(parts[k - 1][1])[-1], _poses(test)[0]
            if not (np.array_equal(before[0], after[0]) and before[1] == after[1]):
                return (f"{program.name} does not start where {programs[k - 1].name} ends "
                        f"(with the bar mounted): run the layer programs one by one")
            body.append(ProgramStop(f"layer {programs[k - 1].layer} done: stop its recording and "
                                    f"save it; start the recording of layer {program.layer}, then "
                                    f"cycle start"))
        body.append(Comment(f"layer {program.layer} ({program.name})"))
        body += test
    body += parts[-1][2]
    first = programs[0]
    keep = ("generated by", "sphere centre", "programmed point", "feed ", "coordinates:",
            "operator sequence")
    header = (f"{name}: the layer programs {', '.join(p.name for p in programs)} in order, the "
              f"bar mounted once; a stop between two layers to save one recording and start "
              f"the next", *(line for line in first.header if line.startswith(keep)))
    return Program(name=name, controller=first.controller, layer="ALL", header=header,
                   work_offset=first.work_offset, decimals=first.decimals,
                   tolerance_mm=max(p.tolerance_mm for p in programs), frame=first.frame,
                   items=tuple(body), number=0)
