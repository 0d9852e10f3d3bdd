"""The sweep the timing benchmarks share: every layer of a config at each feed."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

from sdit_path.config import Config
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.timing.trajectory import Timer


def layers_at_feeds(base: Config, feeds: str, layers: str = "") -> Iterator[tuple]:
    """``(feed, config, timer, path)`` for every layer (or those named in ``layers``,
    e.g. ``"D,E"``) at every feed of ``feeds`` (``"600,2000,5000"``, mm/min); one timer
    per feed."""
    wanted = set(layers.split(",")) if layers else None
    for feed in [float(f) for f in feeds.split(",")]:
        cfg = dataclasses.replace(base, test=dataclasses.replace(base.test, feed_mm_per_min=feed))
        hemi = partition(cfg)
        timer = Timer(cfg)
        builder = PathBuilder(cfg, hemi)
        for layer in hemi.layers:
            if wanted is None or layer.name in wanted:
                yield feed, cfg, timer, builder.layer_path(layer)
