"""The planning pipeline: config -> partition -> layer paths -> poses (kinematics,
reachability, interference) -> neutral programs -> controller text, linted.
Nothing here touches the file system."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .. import __version__
from ..config import Config
from ..errors import LintError, PlanError
from ..geometry.hemisphere import Hemisphere, partition
from ..geometry.paths import LayerPath, PathBuilder
from ..interference.check import Clearance, run_clearances
from ..interference.scene import Scene
from ..machine.approach import Leg, OperatorSequence, operator_sequence
from ..machine.kinematics import Kinematics
from ..machine.poses import RunPoses, layer_poses
from ..machine.reach import PieceCheck, Violation, reach_violations
from ..nc.build import BuiltProgram, build_program, master_program
from ..nc.registry import get_postprocessor
from ..nc.text import program_name
from ..timing.control import control_layer
from ..timing.linuxcnc_tp import ControlLimits, simulate, stretches
from ..timing.trajectory import TimedLayer, Timer, sample
from .configure import check_config
from .trajectory_csv import to_csv


@dataclass(frozen=True, slots=True)
class PlannedProgram:
    """One linted program text, ready to be written at ``file`` (relative path)."""

    file: str
    controller: str
    layer: str
    text: str
    built: BuiltProgram


@dataclass(frozen=True, slots=True)
class LegCheck:
    """The verdict on one leg of the operator sequence: the smallest clearance between
    the tool's side and the table's side along it (the bar not mounted) and the pair,
    and what makes it infeasible (travel, collision); an unchecked leg (its start
    unknown) has none."""

    leg: Leg
    min_clearance_mm: float | None
    clearance_pair: tuple[str, str] | None
    violations: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class LayerPlan:
    """A layer's path as programmed, its poses, and the verdict on every piece it was
    planned with (including pieces then left out); the operator's way to the bar and
    back with the verdict on every leg (None: ``post.operator_sequence = false``)."""

    path: LayerPath
    poses: tuple[RunPoses, ...]
    checks: tuple[PieceCheck, ...]
    timed: TimedLayer | None = None
    operator: OperatorSequence | None = None
    leg_checks: tuple[LegCheck, ...] = ()


@dataclass(frozen=True, slots=True)
class PlanResult:
    """``masters``: per controller one program that runs the layer programs in order
    with the bar mounted once (with the operator sequence); ``no_master``: why a
    controller has none."""

    config: Config
    hemisphere: Hemisphere
    layers: tuple[LayerPlan, ...]
    programs: tuple[PlannedProgram, ...]
    masters: tuple[PlannedProgram, ...] = ()
    no_master: tuple[tuple[str, str], ...] = ()

    @property
    def paths(self) -> tuple[LayerPath, ...]:
        return tuple(la.path for la in self.layers)


def check_layer(path: LayerPath, config: Config, kin: Kinematics, scene: Scene
                ) -> tuple[tuple[RunPoses, ...], tuple[PieceCheck, ...]]:
    """Poses along ``path`` and a reach + interference verdict per piece id."""
    poses = layer_poses(path, config, kin)
    found: dict[str, list[Violation]] = {}
    kinds: dict[str, str] = {}
    clear: dict[str, Clearance] = {}
    for rp in poses:
        viol = reach_violations(rp, config, kin)
        cl, coll = run_clearances(rp, scene, config.check.safety_clearance_mm)
        for k, piece in enumerate(rp.run.pieces):
            kinds[piece.id] = piece.kind
            found.setdefault(piece.id, [])
            found[piece.id] += viol.get(k, []) + coll.get(k, [])
            if k in cl and (piece.id not in clear or cl[k].value_mm < clear[piece.id].value_mm):
                clear[piece.id] = cl[k]
    checks = []
    for pid, v in found.items():
        # one violation per kind and subject: the worst
        worst: dict[tuple[str, str], Violation] = {}
        for x in v:
            key = (x.kind, x.subject)
            if key not in worst or x.overshoot > worst[key].overshoot:
                worst[key] = x
        c = clear.get(pid)
        hard = tuple(x for x in worst.values() if x.kind != "rotary_rate")
        soft = tuple(x for x in worst.values() if x.kind == "rotary_rate")
        checks.append(PieceCheck(pid, kinds[pid], hard,
                                 None if c is None else c.value_mm, None if c is None else c.pair,
                                 None if c is None else c.ball_mm, soft))
    return poses, tuple(checks)


def check_legs(seq: OperatorSequence, config: Config, kin: Kinematics, scene: Scene
               ) -> tuple[LegCheck, ...]:
    """Travel and clearance along every leg whose start is known (the bar not
    mounted: its pairs are left out)."""
    keep = [k for k, pair in enumerate(scene.pair_names) if "bar" not in pair]
    safety = config.check.safety_clearance_mm
    out = []
    for leg in (*seq.approach, *seq.retract):
        if not leg.checked:
            out.append(LegCheck(leg, None, None, ()))
            continue
        bad = []
        for j, ax in enumerate(kin.axes):
            m = config.check.angle_margin_rad if ax.is_rotary else config.check.travel_margin_mm
            lo, hi = ax.travel[0] + m, ax.travel[1] - m
            v = leg.q[:, j]
            if v.min() < lo - 1e-12 or v.max() > hi + 1e-12:
                worst = v.min() if v.min() < lo else v.max()
                bad.append(f"{ax.name} {ax.to_display(worst):.3f} {ax.unit} outside its travel "
                           f"[{ax.to_display(lo):g}, {ax.to_display(hi):g}] {ax.unit} (margins "
                           f"included)")
        clear, pair = None, None
        if keep:
            c = scene.clearances(leg.q)[:, keep]
            i, k = np.unravel_index(int(np.argmin(c)), c.shape)
            clear, pair = float(c[i, k]), scene.pair_names[keep[k]]
            if clear < safety:
                at = ", ".join(f"{x:.1f}" for x in leg.points_mm[i])
                bad.append(f"collision {pair[0]}/{pair[1]}: clearance {clear:.3f} mm < {safety:g} "
                           f"mm safety with the ball at ({at}) mm")
        out.append(LegCheck(leg, clear, pair, tuple(bad)))
    return tuple(out)


def lint_limits(config: Config, kin: Kinematics, frame: str) -> dict[str, tuple[float, float]]:
    """Travel limits to lint the programmed words against, in the programmed frame
    (mm and deg): every axis for machine-axis programs; the rotary axes under TRAORI;
    for table-frame programs the linear limits too, shifted into the table frame when
    it is a pure translation of the machine axes (the exact check is the kinematic
    one, upstream)."""
    limits = {ax.name: tuple(ax.to_display(v) for v in ax.travel) for ax in kin.axes
              if ax.is_rotary}
    if frame == "machine":
        return {ax.name: tuple(ax.to_display(v) for v in ax.travel) for ax in kin.axes}
    if frame in ("traori", "tcpm"):
        return limits
    probe = np.vstack([np.zeros(3), np.eye(3)])
    angles = {n: np.full(4, v) for n, v in config.test.rotary.locked_rad}
    q = kin.inverse(probe, angles)
    lin = list(kin.linear)
    if not np.allclose(q[1:, lin] - q[0, lin], np.eye(3), atol=1e-12):
        return limits
    for col, i in enumerate(lin):
        lo, hi = kin.axes[i].travel
        limits["XYZ"[col]] = (lo - q[0, i], hi - q[0, i])
    return limits


def post_layer(path: LayerPath, config: Config, hemi: Hemisphere,
               controller: str, number: int = 1,
               operator: OperatorSequence | None = None) -> PlannedProgram:
    """Build, render and lint one layer program (``number``: its place in the plan,
    for controls that number their programs; ``operator``: the way to the bar and
    back); raises :class:`LintError` on failure."""
    post = get_postprocessor(controller)
    built = build_program(path, config, hemi, controller, post.path_form, __version__,
                          corners=getattr(post, "corners", None),
                          max_decimals=getattr(post, "max_decimals", 9),
                          five_axis=getattr(post, "five_axis", None), number=number,
                          operator=operator)
    text = post.render(built.program)
    file = f"{controller}/{built.program.name}{post.extension}"
    problems = post.lint(text, lint_limits(config, Kinematics(config.machine), built.program.frame))
    if problems:
        raise LintError(file, problems)
    return PlannedProgram(file, controller, path.layer, text, built)


def _with_operator_sequence(layers: list[LayerPlan], config: Config, hemi: Hemisphere,
                            kin: Kinematics, scene: Scene) -> list[LayerPlan]:
    """Every programmed layer with its way to the bar and back, checked; a leg out of
    travel or too close is a :class:`PlanError` naming the layer, the leg and why."""
    out, bad = [], []
    for lp in layers:
        if not lp.path.items:
            out.append(lp)
            continue
        dwells = lp.path.dwells
        end = hemi.node(dwells[-1].node_id).position_mm if dwells else lp.path.start_mm
        seq = operator_sequence(config, kin, lp.path.start_mm, end)
        legs = check_legs(seq, config, kin, scene)
        bad += [f"layer {lp.path.layer}, {c.leg.name}: {v}" for c in legs for v in c.violations]
        out.append(replace(lp, operator=seq, leg_checks=legs))
    if bad:
        err = PlanError(f"the operator's way to the bar and back is not clear ({len(bad)} "
                        f"problem(s)); move post.safe_position_mm, or set "
                        f"post.operator_sequence = false and approach by hand")
        err.details = bad
        raise err
    return out


def _infeasible_message(bad: list[tuple[str, PieceCheck]]) -> PlanError:
    names = [c.piece_id for _, c in bad]
    shown = ", ".join(names[:12]) + (f" and {len(names) - 12} more" if len(names) > 12 else "")
    err = PlanError(f"{len(names)} infeasible piece(s): {shown}; pass --skip-infeasible to leave "
                    f"them out (plan.json then says why)")
    err.details = [f"layer {layer}, {c.piece_id}: {c.violations[0].describe()}" for layer, c in bad]
    return err


def plan(config: Config, on_step: Callable[[str], None] | None = None,
         skip_infeasible: bool = False) -> PlanResult:
    """Plan, check and post every layer for every configured controller.

    Infeasible segments (travel, rotary rate, collision) raise :class:`PlanError`
    naming all of them, unless ``skip_infeasible``: then each layer is planned again
    without them.  ``on_step`` is called after each unit of work (see
    :func:`step_count`).  ``config`` is checked by the stages first
    (:func:`~sdit_path.plan.configure.check_config`).
    """
    check_config(config)
    hemi = partition(config)
    kin = Kinematics(config.machine)
    scene = Scene(config, kin)
    builder = PathBuilder(config, hemi)
    layers, bad = [], []
    for layer in hemi.layers:
        path = builder.layer_path(layer)
        poses, checks = check_layer(path, config, kin, scene)
        infeasible = [c for c in checks if not c.feasible]
        if infeasible and skip_infeasible:
            excluded = frozenset(c.piece_id for c in infeasible)
            path = builder.layer_path(layer, excluded)
            poses, rechecked = check_layer(path, config, kin, scene)
            still = [c for c in rechecked if not c.feasible]
            if still:  # a shortened run can differ by nanometres; never let it through
                bad += [(layer.name, c) for c in still]
            checks = tuple(rechecked) + tuple(infeasible)
        else:
            bad += [(layer.name, c) for c in infeasible]
        layers.append(LayerPlan(path, poses, checks))
        if on_step:
            on_step(f"layer {layer.name} planned and checked")
    for layer in hemi.layers:
        sectors = config.test.remeasure_sectors(layer.name)
        if not sectors:
            continue
        path = builder.remeasure_path(layer, sectors)
        poses, checks = check_layer(path, config, kin, scene)
        bad += [(path.layer, c) for c in checks if not c.feasible]
        layers.append(LayerPlan(path, poses, checks))
        if on_step:
            on_step(f"re-measure program of layer {layer.name} planned and checked")
    if bad:
        raise _infeasible_message(bad)
    if config.post.operator_sequence:
        layers = _with_operator_sequence(layers, config, hemi, kin, scene)
    # a LinuxCNC-timed plan replaces every run's timing by the control's: the
    # windows' plan gives it its structure, the optimal speed law would be wasted
    timer = Timer(config, kin, optimal=config.timing.control != "linuxcnc")
    timed_layers, programs = [], []
    for number, lp in enumerate(layers, start=1):
        posted = {}
        for controller in config.post.controllers:
            if lp.path.items:
                posted[controller] = post_layer(lp.path, config, hemi, controller, number,
                                                lp.operator)
                programs.append(posted[controller])
            if on_step:
                on_step(f"layer {lp.path.layer} posted for {controller}")
        timed = timer.time_layer(lp.path) if lp.path.items else None
        if timed is not None and config.timing.control == "linuxcnc":
            timed = linuxcnc_timed(timed, posted["linuxcnc"], config, kin)
        timed_layers.append(replace(lp, timed=timed))
    masters, no_master = _masters(timed_layers, programs, config)
    return PlanResult(config, hemi, tuple(timed_layers), tuple(programs), masters, no_master)


def _masters(layers: list[LayerPlan], programs: list[PlannedProgram], config: Config
             ) -> tuple[tuple[PlannedProgram, ...], tuple[tuple[str, str], ...]]:
    """Per controller the master program of the layer programs (re-measure programs
    aside), linted, or why there is none."""
    if not config.post.operator_sequence:
        return (), ()
    order = [lp.path.layer for lp in layers if lp.path.items and not lp.path.remeasure]
    if len(order) < 2:
        return (), ()
    kin = Kinematics(config.machine)
    masters, why = [], []
    for controller in config.post.controllers:
        post = get_postprocessor(controller)
        progs = [next(p for p in programs if p.controller == controller and p.layer == layer)
                 for layer in order]
        name = program_name(config.post.program_prefix, "ALL")
        built = master_program([p.built.program for p in progs], name)
        if isinstance(built, str):
            why.append((controller, built))
            continue
        text = post.render(built)
        file = f"{controller}/{name}{post.extension}"
        problems = post.lint(text, lint_limits(config, kin, built.frame))
        if problems:
            raise LintError(file, problems)
        deviation = {k: v for p in progs for k, v in p.built.piece_deviation_mm.items()}
        masters.append(PlannedProgram(file, controller, "ALL", text,
                                      BuiltProgram(built, deviation)))
    return tuple(masters), tuple(why)


def linuxcnc_timed(timed: TimedLayer, program: PlannedProgram, config: Config,
                   kin: Kinematics) -> TimedLayer:
    """``timed`` as LinuxCNC 2.9 runs ``program`` (its LinuxCNC text): the planner's
    model (:mod:`~sdit_path.timing.linuxcnc_tp`) moves through every stretch between
    dwells, servo period by servo period, with the machine's axis limits as the
    control's INI limits; the ball keeps to the planned paths at the control's pace."""
    table = program.built.program.frame == "table"
    axes = ("X", "Y", "Z") if table else tuple(kin.names)
    limits = ControlLimits.from_machine(config.machine, axes)
    rotary = np.array([not table and kin.axes[kin.index[a]].is_rotary for a in axes])
    paths = []
    try:
        found = stretches(program.text, axes)
    except ValueError as exc:
        raise PlanError(f"{program.file}: the LinuxCNC timing model cannot read it: {exc}") from exc
    for stretch in found:
        sim = simulate(stretch, limits)
        moving = np.flatnonzero(sim.moving)
        if not len(moving):
            continue
        pos = np.vstack([sim.start[None, :], sim.position[moving[0]:moving[-1] + 1]])
        if table:
            paths.append(pos)
            continue
        q = np.zeros((len(pos), len(kin.names)))
        for col, name in enumerate(axes):
            q[:, kin.index[name]] = np.radians(pos[:, col]) if rotary[col] else pos[:, col]
        paths.append(kin.forward(q))
    try:
        return control_layer(timed, paths, limits.servo_period_s)
    except ValueError as exc:
        raise PlanError(f"{program.file}: {exc}") from exc


def step_count(config: Config) -> int:
    """Units of work :func:`plan` reports (plus one per trajectory file written by
    :func:`trajectory_files`)."""
    per_layer = 1 + len(config.post.controllers)
    if config.timing.export_trajectories:
        per_layer += 1
    remeasure = len({s[0] for s in config.test.remeasure})
    return (len(config.test.track_elevations_deg) + remeasure) * per_layer


def trajectory_files(result: PlanResult, on_step: Callable[[str], None] | None = None
                     ) -> dict[str, str]:
    """``trajectories/<program>.csv`` for every programmed layer (one per layer: the
    controllers run the same timed path)."""
    cfg = result.config
    if not cfg.timing.export_trajectories:
        return {}
    timer = Timer(cfg)
    files = {}
    for lp in result.layers:
        if lp.timed is None:
            continue
        prog = next(p for p in result.programs if p.layer == lp.path.layer)
        name = prog.built.program.name
        samples = sample(lp.timed, timer, cfg.timing.sample_rate_hz)
        header = {"program": name, "layer": lp.path.layer,
                  "sample_rate_hz": f"{cfg.timing.sample_rate_hz:g}",
                  "feed_mm_per_min": f"{cfg.test.feed_mm_per_min:g}",
                  "cycle_time_s": f"{lp.timed.duration_s:.4f}",
                  "frame": "ball_* in the table frame; axis_* machine axis values",
                  "generator": f"sdit-path {__version__}"}
        files[f"trajectories/{name}.csv"] = to_csv(samples, header)
        if on_step:
            on_step(f"trajectory of layer {lp.path.layer} written")
    return files
