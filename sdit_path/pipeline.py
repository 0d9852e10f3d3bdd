"""The planning pipeline: config -> partition -> layer paths -> neutral programs ->
controller text, linted.  Nothing here touches the file system."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from . import __version__
from .config import Config
from .errors import LintError
from .geometry.hemisphere import Hemisphere, partition
from .geometry.paths import LayerPath, PathBuilder, check_travel
from .nc.build import BuiltProgram, build_program
from .nc.registry import get_postprocessor


@dataclass(frozen=True, slots=True)
class PlannedProgram:
    """One linted program text, ready to be written at ``file`` (relative path)."""

    file: str
    controller: str
    layer: str
    text: str
    built: BuiltProgram


@dataclass(frozen=True, slots=True)
class PlanResult:
    config: Config
    hemisphere: Hemisphere
    paths: tuple[LayerPath, ...]
    programs: tuple[PlannedProgram, ...]


def travel_limits(config: Config) -> dict[str, tuple[float, float]]:
    return {ax.name: ax.travel_mm for ax in config.machine.axes}


def post_layer(path: LayerPath, config: Config, hemi: Hemisphere,
               controller: str) -> PlannedProgram:
    """Build, render and lint one layer program; raises :class:`LintError` on failure."""
    post = get_postprocessor(controller)
    built = build_program(path, config, hemi, controller, post.path_form, __version__)
    text = post.render(built.program)
    file = f"{controller}/{built.program.name}{post.extension}"
    problems = post.lint(text, travel_limits(config))
    if problems:
        raise LintError(file, problems)
    return PlannedProgram(file, controller, path.layer, text, built)


def plan(config: Config, on_step: Callable[[str], None] | None = None) -> PlanResult:
    """Plan every layer and post it for every configured controller.

    ``on_step`` is called after each unit of work with a short description (the CLI
    drives a progress bar with it); the total is :func:`step_count`.
    """
    hemi = partition(config)
    builder = PathBuilder(config, hemi)
    paths, programs = [], []
    for layer in hemi.layers:
        path = builder.layer_path(layer)
        check_travel(path, config)
        paths.append(path)
        if on_step:
            on_step(f"layer {layer.name} planned")
        for controller in config.post.controllers:
            programs.append(post_layer(path, config, hemi, controller))
            if on_step:
                on_step(f"layer {layer.name} posted for {controller}")
    return PlanResult(config, hemi, tuple(paths), tuple(programs))


def step_count(config: Config) -> int:
    return len(config.test.track_elevations_deg) * (1 + len(config.post.controllers))
