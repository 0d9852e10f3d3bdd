"""A plan as the console shows it: one row per layer (segments, dwells, cycle time),
then one row per controller (the blocks of each layer's program, the largest radial
deviation from the sphere as emitted, the tolerance it holds), narrow enough for an
80-column terminal with the six built-in controllers."""

from __future__ import annotations

from rich.console import Group
from rich.table import Table

from ..nc.registry import get_postprocessor
from ..nc.words import count_blocks
from ..plan.pipeline import PlanResult


def plan_table(result: PlanResult) -> Group:
    """The plan's summary (title: machine, sphere radius, feed, dwell)."""
    cfg = result.config
    layers = Table(title=f"{cfg.machine.name}: R {result.hemisphere.radius_mm:g} mm, "
                         f"F{cfg.test.feed_mm_per_min:g}, dwell {cfg.test.dwell_s:g} s",
                   title_justify="left")
    for col in ("layer", "segments", "dwells", "cycle (s)"):
        layers.add_column(col, justify="right" if col != "layer" else "left")
    for path in result.paths:
        timed = next(la.timed for la in result.layers if la.path is path)
        layers.add_row(path.layer, str(len(set(path.segment_order()))), str(len(path.dwells)),
                       f"{timed.duration_s:.1f}" if timed else "-")
    programs = Table(title="programs: blocks per layer, largest radial deviation from the "
                           "sphere as emitted", title_justify="left")
    programs.add_column("controller", no_wrap=True)
    names = [p.layer for p in result.paths if p.items]
    for name in names:
        programs.add_column(name, justify="right")
    programs.add_column("max dev (um)", justify="right")
    programs.add_column("tol (um)", justify="right")
    for c in cfg.post.controllers:
        progs = [next(x for x in result.programs if x.layer == name and x.controller == c)
                 for name in names]
        if not progs:
            continue
        programs.add_row(get_postprocessor(c).short,
                         *(str(count_blocks(p.text)) for p in progs),
                         f"{max(p.built.max_deviation_mm for p in progs) * 1e3:.4f}",
                         f"{max(p.built.program.tolerance_mm for p in progs) * 1e3:g}")
    return Group(layers, programs)
