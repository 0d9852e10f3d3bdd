"""What a preview shows of a plan: every planned layer's timed trajectory sampled, the
axes' limits, and the sphere with its tracks and static nodes (drawn by
:mod:`sdit_path.reports.preview`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..timing.trajectory import Samples, Timer, sample
from .files import PlanFiles
from .pipeline import PlanResult


@dataclass(frozen=True, slots=True)
class LayerPreview:
    """One layer's program (``program``, ``layer``, ``cycle_s``) and its trajectory
    sampled (``samples``)."""

    program: str
    layer: str
    cycle_s: float
    samples: Samples


@dataclass(frozen=True, slots=True)
class Preview:
    """``layers`` in the plan's order; ``limits``: axis -> (velocity, acceleration, jerk)
    limits in mm or deg (per s, s^2, s^3); ``centre_mm``, ``radius_mm``, ``tracks_deg``
    (elevations) and ``nodes`` ((id, position)) of the sphere; ``feed_mm_per_min``;
    ``timing``: whose motion the trajectories are (see :data:`TIMING_TITLES`), ``note``
    what their axis pictures need said (:data:`TIMING_NOTES`)."""

    layers: tuple[LayerPreview, ...]
    limits: dict[str, tuple[float, float, float]]
    centre_mm: np.ndarray
    radius_mm: float
    tracks_deg: tuple[float, ...]
    nodes: tuple[tuple[str, np.ndarray], ...]
    feed_mm_per_min: float
    timing: str
    note: str = ""


#: what each ``timing.control`` shows, in a few words for the pictures' titles
TIMING_TITLES = {"jerk_limited": "our jerk-limited plan",
                 "linuxcnc": "LinuxCNC 2.9 planner model"}

#: what the axis pictures of each timing need said beside their limit lines
TIMING_NOTES = {"jerk_limited": "",
                "linuxcnc": "LinuxCNC 2.9 plans without a jerk limit: the jerk panels set its "
                            "motion against the machine's jerk limits, which it does not "
                            "observe. It keeps each axis' acceleration along its chords; shown "
                            "on the planned curve, whose direction differs from a chord's by a "
                            "fraction of a degree, an axis that moves little may read a few "
                            "percent over at a ramp."}


def preview(result: PlanResult, rate_hz: float = 1000.0) -> Preview:
    """The preview of a planned ``result``: each timed layer sampled at ``rate_hz``."""
    cfg = result.config
    timer = Timer(cfg)
    hemi = result.hemisphere
    limits = {}
    for ax in timer.kin.axes:
        scale = np.degrees(1.0) if ax.is_rotary else 1.0
        limits[ax.name] = (ax.max_velocity * scale, ax.max_acceleration * scale,
                           ax.max_jerk * scale)
    layers = []
    for lp in result.layers:
        if lp.timed is None:
            continue
        name = next(p.built.program.name for p in result.programs if p.layer == lp.path.layer)
        layers.append(LayerPreview(name, lp.path.layer, lp.timed.duration_s,
                                   sample(lp.timed, timer, rate_hz)))
    return Preview(tuple(layers), limits, hemi.centre_mm, hemi.radius_mm,
                   tuple(float(np.degrees(t.elevation_rad)) for t in hemi.tracks),
                   tuple((n.id, n.position_mm) for n in hemi.nodes), cfg.test.feed_mm_per_min,
                   TIMING_TITLES[cfg.timing.control], TIMING_NOTES[cfg.timing.control])


def preview_of_plan(plan: PlanFiles) -> Preview:
    """The preview of a plan as written (``plan``'s directory): its trajectories read
    back, not planned again."""
    cfg = plan.config
    limits = {}
    for ax in cfg.machine.axes:
        scale = np.degrees(1.0) if ax.kind == "rotary" else 1.0
        limits[ax.name] = (ax.max_velocity * scale, ax.max_acceleration * scale,
                           ax.max_jerk * scale)
    m = plan.manifest
    layers = []
    for p in m.get("programs", ()):
        if p.get("controller") != plan.ran_on or "layer" not in p:
            continue
        layers.append(LayerPreview(p["name"], p["layer"], float(p["cycle_time_s"]),
                                   plan.trajectory(p["name"])))
    sphere = m["sphere"]
    return Preview(tuple(layers), limits, np.array(sphere["centre_mm"], float),
                   float(sphere["radius_mm"]),
                   tuple(float(t["elevation_deg"]) for t in m.get("tracks", ())),
                   tuple((n["id"], np.array(n["position_mm"], float)) for n in m["nodes"]),
                   float(m["test"]["feed_mm_per_min"]), TIMING_TITLES[cfg.timing.control],
                   TIMING_NOTES[cfg.timing.control])
