"""Layer paths: the order in which a layer program moves, dwells and moves again.

A layer program (all moves on the sphere, so the bar can stay mounted):

1. starts at its start node and dwells there;
2. with ``transit = "meridian"`` (default) every program starts and ends at ``A-1``
   and climbs the 0 deg meridian to its own lower track, dwelling at every node it
   passes, so one mounting serves all layers;
3. the top layer visits the pole: up the meridian to ``TOP``, dwell, back;
4. the forward pass runs sector 1..n counter-clockwise (seen from +Z), the reverse pass
   the same curves backwards; the machine dwells at every static node it reaches;
5. it descends the meridian back to ``A-1``.

Each dwell-to-dwell motion is one :class:`Run`: a fitted clamped B-spline whose pieces
(identification segments or transits) start and end on knots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Config
from ..errors import PlanError
from .curves import MeridianCurve, WaveCurve
from .hemisphere import TOP, Hemisphere, Layer
from .nurbs import BSplineCurve, FittedRun, fit_run


@dataclass(frozen=True, slots=True)
class PathPiece:
    """A named stretch of a run: a segment (``D3-2``) or a transit (``A-1>B-1``)."""

    id: str
    kind: str
    u_start: float
    u_end: float
    length_mm: float
    max_radial_deviation_mm: float


@dataclass(frozen=True, slots=True)
class Run:
    """Motion from one dwell to the next along one spline."""

    curve: BSplineCurve
    pieces: tuple[PathPiece, ...]
    start_node: str
    end_node: str
    direction: str  # "forward", "reverse" or "transit"

    @property
    def length_mm(self) -> float:
        return sum(p.length_mm for p in self.pieces)

    def reversed(self, direction: str) -> "Run":
        a, b = self.curve.domain
        pieces = tuple(PathPiece(p.id, p.kind, a + b - p.u_end, a + b - p.u_start, p.length_mm,
                                 p.max_radial_deviation_mm) for p in reversed(self.pieces))
        return Run(self.curve.reversed(), pieces, self.end_node, self.start_node, direction)


@dataclass(frozen=True, slots=True)
class Dwell:
    """A stop at a static node. ``position_mm : (3,) float``."""

    node_id: str
    position_mm: np.ndarray
    seconds: float


@dataclass(frozen=True, slots=True)
class LayerPath:
    layer: str
    start_node: str
    start_mm: np.ndarray
    items: tuple[Run | Dwell, ...]

    @property
    def runs(self) -> tuple[Run, ...]:
        return tuple(i for i in self.items if isinstance(i, Run))

    @property
    def dwells(self) -> tuple[Dwell, ...]:
        return tuple(i for i in self.items if isinstance(i, Dwell))

    def segment_order(self) -> tuple[str, ...]:
        return tuple(p.id for r in self.runs for p in r.pieces if p.kind == "segment")


def _run_from_fit(fit: FittedRun, ids: list[str], kinds: list[str], start: str, end: str,
                  direction: str) -> Run:
    pieces = tuple(PathPiece(i, k, lo, hi, length, dev) for i, k, (lo, hi), length, dev in
                   zip(ids, kinds, fit.piece_ranges, fit.piece_lengths_mm,
                       fit.piece_max_deviation_mm))
    return Run(fit.curve, pieces, start, end, direction)


class PathBuilder:
    """Fits every run of a hemisphere once and assembles layer paths from them."""

    def __init__(self, config: Config, hemisphere: Hemisphere):
        self.config = config
        self.hemi = hemisphere
        post = config.post
        self._fit_kw = dict(degree=post.spline_degree, tolerance_mm=post.spline_tolerance_um * 1e-3,
                            decimals=post.decimals)
        self._meridian: dict[tuple[str, str], Run] = {}

    # -- runs ---------------------------------------------------------------------------

    def _fit(self, curves, start_node: str, end_node: str, ids, kinds, direction, label) -> Run:
        h = self.hemi
        fit = fit_run(curves, h.centre_mm, h.radius_mm, h.node(start_node).position_mm,
                      h.node(end_node).position_mm, label=label, **self._fit_kw)
        return _run_from_fit(fit, ids, kinds, start_node, end_node, direction)

    def sector_run(self, layer: Layer, sector: int) -> Run:
        h, t = self.hemi, self.config.test
        span = 2.0 * math.pi / h.nodes_per_track
        curves = [WaveCurve(h.centre_mm, h.radius_mm, layer.lower_elevation_rad,
                            layer.upper_elevation_rad, t.curve.amplitude, t.curve.waves_per_sector,
                            span, t.projection, s.azimuth_start_rad, s.azimuth_end_rad)
                  for s in layer.segments if s.sector == sector]
        ids = [s.id for s in layer.segments if s.sector == sector]
        start, end = layer.sector_nodes(sector, h.nodes_per_track)
        return self._fit(curves, start, end, ids, ["segment"] * len(ids), "forward",
                         f"segments {ids[0]}..{ids[-1]}")

    def meridian_run(self, start_node: str, end_node: str) -> Run:
        """Transit along the 0 deg meridian between two nodes (fitted upwards once)."""
        key = (start_node, end_node)
        if key in self._meridian:
            return self._meridian[key]
        rev = (end_node, start_node)
        if rev in self._meridian:
            run = self._meridian[rev].reversed("transit")
        else:
            h = self.hemi
            a, b = h.node(start_node), h.node(end_node)
            curve = MeridianCurve(h.centre_mm, h.radius_mm, 0.0, a.elevation_rad, b.elevation_rad)
            label = f"{start_node}>{end_node}"
            run = self._fit([curve], start_node, end_node, [label], ["transit"], "transit",
                            f"transit {label}")
        self._meridian[key] = run
        return run

    # -- layer paths ----------------------------------------------------------------------

    def layer_path(self, layer: Layer) -> LayerPath:
        h, t = self.hemi, self.config.test
        n = h.nodes_per_track
        dwell = t.dwell_s
        items: list[Run | Dwell] = []

        def stop(node_id: str) -> None:
            items.append(Dwell(node_id, h.node(node_id).position_mm, dwell))

        first = f"{layer.lower_track}-1"
        track_names = [tr.name for tr in h.tracks]
        climb = track_names[: track_names.index(layer.lower_track) + 1]
        start = f"{climb[0]}-1" if t.transit == "meridian" else first
        stop(start)
        if t.transit == "meridian":
            for a, b in zip(climb, climb[1:]):
                items.append(self.meridian_run(f"{a}-1", f"{b}-1"))
                stop(f"{b}-1")
        if layer.is_cap:
            items.append(self.meridian_run(first, TOP))
            stop(TOP)
            items.append(self.meridian_run(TOP, first))
            stop(first)
        forward = [self.sector_run(layer, k) for k in range(1, n + 1)]
        if "forward" in t.passes:
            for run in forward:
                items.append(run)
                stop(run.end_node)
        if "reverse" in t.passes:
            for run in reversed(forward):
                items.append(run.reversed("reverse"))
                stop(run.start_node)
        if t.transit == "meridian":
            for a, b in zip(climb[::-1], climb[::-1][1:]):
                items.append(self.meridian_run(f"{a}-1", f"{b}-1"))
                stop(f"{b}-1")
        return LayerPath(layer.name, start, h.node(start).position_mm, tuple(items))


def check_travel(path: LayerPath, config: Config) -> None:
    """Every control point (hence the whole curve, by the convex hull) within travel."""
    for run in path.runs:
        q = run.curve.control_points_mm
        for i, ax in enumerate(config.machine.axes):
            lo, hi = ax.travel_mm
            below, above = lo - q[:, i].min(), q[:, i].max() - hi
            if below > 0 or above > 0:
                over = max(below, above)
                j = int(np.argmin(q[:, i]) if below > 0 else np.argmax(q[:, i]))
                u = j / max(1, len(q) - 1) * (run.curve.domain[1] - run.curve.domain[0])
                where = next((p.id for p in run.pieces if p.u_start <= u <= p.u_end),
                             run.pieces[0].id)
                side = "min" if below > 0 else "max"
                limit = lo if below > 0 else hi
                raise PlanError(
                    f"layer {path.layer}, {where}: the path leaves the {ax.name} travel by "
                    f"{over:.3f} mm ({ax.name}={q[j, i]:.3f} mm beyond the {side} {limit:g} mm of "
                    f"machine.axes.{ax.name}.travel_mm); move ballbar.pivot_mm or shorten the bar")
