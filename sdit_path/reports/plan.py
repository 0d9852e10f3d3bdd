"""A plan as the console shows it: one row per layer, the blocks and the largest radial
deviation of every controller's program."""

from __future__ import annotations

from rich.table import Table

from ..nc.registry import get_postprocessor
from ..nc.words import count_blocks
from ..plan.pipeline import PlanResult


def plan_table(result: PlanResult) -> Table:
    """The plan's summary table (title: machine, sphere radius, feed, dwell)."""
    cfg = result.config
    table = Table(title=f"{cfg.machine.name}: R {result.hemisphere.radius_mm:g} mm, "
                        f"F{cfg.test.feed_mm_per_min:g}, dwell {cfg.test.dwell_s:g} s",
                  title_justify="left")
    for col in ("layer", "segments", "dwells", "cycle (s)"):
        table.add_column(col, justify="right" if col != "layer" else "left")
    for c in cfg.post.controllers:
        short = get_postprocessor(c).short
        table.add_column(f"{short} blocks", justify="right")
        table.add_column(f"{short} max dev (um)", justify="right")
    for path in result.paths:
        timed = next(la.timed for la in result.layers if la.path is path)
        row = [path.layer, str(len(set(path.segment_order()))), str(len(path.dwells)),
               f"{timed.duration_s:.1f}" if timed else "-"]
        for c in cfg.post.controllers:
            p = next(x for x in result.programs if x.layer == path.layer and x.controller == c)
            row += [str(count_blocks(p.text)), f"{p.built.max_deviation_mm * 1e3:.4f}"]
        table.add_row(*row)
    return table
