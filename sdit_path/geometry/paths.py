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

from ..config import Config, TestConfig
from .curves import MeridianCurve, TrackCurve, WaveCurve
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
    """Motion along one spline, from a dwell (or a mounting point) to the next.
    ``start_node``/``end_node`` are static node ids, or ``""`` where the run starts or
    ends between segments (next to a segment left out).  ``feed_mm_per_min`` is the
    run's programmed feed, worked out once here (``TestConfig.run_feed``: a re-planned
    sector at its own feed, everything else at the test's) and read by the reach
    check, the timing and the program alike."""

    curve: BSplineCurve
    pieces: tuple[PathPiece, ...]
    start_node: str
    end_node: str
    direction: str  # "forward", "reverse" or "transit"
    feed_mm_per_min: float

    @property
    def length_mm(self) -> float:
        return sum(p.length_mm for p in self.pieces)

    def reversed(self, direction: str) -> "Run":
        """The same curve backwards.  Segments keep their ids; a transit ``A>B``
        becomes ``B>A``."""
        a, b = self.curve.domain

        def rename(p: PathPiece) -> str:
            if p.kind == "transit" and ">" in p.id:
                start, end = p.id.split(">", 1)
                return f"{end}>{start}"
            return p.id

        pieces = tuple(PathPiece(rename(p), p.kind, a + b - p.u_end, a + b - p.u_start,
                                 p.length_mm, p.max_radial_deviation_mm)
                       for p in reversed(self.pieces))
        return Run(self.curve.reversed(), pieces, self.end_node, self.start_node, direction,
                   self.feed_mm_per_min)


@dataclass(frozen=True, slots=True)
class Dwell:
    """A stop at a static node. ``position_mm : (3,) float``."""

    node_id: str
    position_mm: np.ndarray
    seconds: float


@dataclass(frozen=True, slots=True)
class Remount:
    """The bar comes off at ``from_mm``, the machine repositions through ``via_mm
    (k, 3)`` (all outside the sphere), and the bar goes back on at ``to_mm``: what a
    layer program does to step over segments it leaves out (``skipped``)."""

    from_mm: np.ndarray
    via_mm: np.ndarray
    to_mm: np.ndarray
    skipped: tuple[str, ...]


#: the suffix of a re-measure program's layer name (``D_R``: re-planned sectors of D)
REMEASURE = "_R"


@dataclass(frozen=True, slots=True)
class LayerPath:
    layer: str  # the layer's name, or with REMEASURE for a re-measure program
    start_node: str
    start_mm: np.ndarray
    items: tuple[Run | Dwell | Remount, ...]
    omitted: tuple[str, ...] = ()

    @property
    def base_layer(self) -> str:
        """The layer of the hemisphere this path runs on."""
        return self.layer.removesuffix(REMEASURE)

    @property
    def remeasure(self) -> bool:
        return self.layer != self.base_layer

    @property
    def runs(self) -> tuple[Run, ...]:
        return tuple(i for i in self.items if isinstance(i, Run))

    @property
    def dwells(self) -> tuple[Dwell, ...]:
        return tuple(i for i in self.items if isinstance(i, Dwell))

    def segment_order(self) -> tuple[str, ...]:
        return tuple(p.id for r in self.runs for p in r.pieces if p.kind == "segment")


def _run_from_fit(fit: FittedRun, ids: list[str], kinds: list[str], start: str, end: str,
                  direction: str, test: TestConfig) -> Run:
    pieces = tuple(PathPiece(i, k, lo, hi, length, dev) for i, k, (lo, hi), length, dev in
                   zip(ids, kinds, fit.piece_ranges, fit.piece_lengths_mm,
                       fit.piece_max_deviation_mm))
    return Run(fit.curve, pieces, start, end, direction, test.run_feed(pieces))


class PathBuilder:
    """Fits every run of a hemisphere once and assembles layer paths from them."""

    def __init__(self, config: Config, hemisphere: Hemisphere):
        self.config = config
        self.hemi = hemisphere
        post = config.post
        self._fit_kw = dict(degree=post.spline_degree, tolerance_mm=post.spline_tolerance_um * 1e-3,
                            decimals=post.decimals)
        self._meridian: dict[tuple[str, str], Run] = {}
        self._runs: dict[tuple, Run] = {}

    # -- runs ---------------------------------------------------------------------------

    def _fit(self, curves, start: str | np.ndarray, end: str | np.ndarray, ids, kinds,
             direction, label) -> Run:
        """Fit a run between two nodes (ids) or points (``(3,)`` arrays)."""
        h = self.hemi
        a = h.node(start).position_mm if isinstance(start, str) else start
        b = h.node(end).position_mm if isinstance(end, str) else end
        fit = fit_run(curves, h.centre_mm, h.radius_mm, a, b, label=label, **self._fit_kw)
        return _run_from_fit(fit, ids, kinds, start if isinstance(start, str) else "",
                             end if isinstance(end, str) else "", direction, self.config.test)

    def _wave(self, layer: Layer, seg) -> WaveCurve:
        h, t = self.hemi, self.config.test
        span = 2.0 * math.pi / h.nodes_per_track
        amplitude, waves, projection = t.curve.for_sector(layer.name, seg.sector, t.projection)
        return WaveCurve(h.centre_mm, h.radius_mm, layer.lower_elevation_rad,
                         layer.upper_elevation_rad, amplitude, waves, span, projection,
                         seg.azimuth_start_rad, seg.azimuth_end_rad,
                         t.curve.crest_for(layer.name, seg.sector))

    def segment_run(self, layer: Layer, segs: list) -> Run:
        """One run over consecutive segments of one sector (the whole sector is cached)."""
        h = self.hemi
        sector = segs[0].sector
        whole = [s for s in layer.segments if s.sector == sector]
        key = (layer.name, tuple(s.id for s in segs))
        if key in self._runs:
            return self._runs[key]
        curves = [self._wave(layer, s) for s in segs]
        start_node, end_node = layer.sector_nodes(sector, h.nodes_per_track)
        start = start_node if segs[0] is whole[0] else curves[0](np.array([0.0]))[0]
        end = end_node if segs[-1] is whole[-1] else curves[-1](np.array([1.0]))[0]
        ids = [s.id for s in segs]
        run = self._fit(curves, start, end, ids, ["segment"] * len(ids), "forward",
                        f"segments {ids[0]}..{ids[-1]}")
        self._runs[key] = run
        return run

    def sector_run(self, layer: Layer, sector: int) -> Run:
        return self.segment_run(layer, [s for s in layer.segments if s.sector == sector])

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

    def remount(self, a: np.ndarray, b: np.ndarray, skipped: tuple[str, ...],
                standoff_mm: float = 30.0) -> Remount:
        """Off the sphere from ``a`` to ``b``: out radially by ``standoff_mm``, up above
        the hemisphere, across, down, and in radially; every via point lies outside the
        sphere of radius R + standoff."""
        h = self.hemi
        c, r = h.centre_mm, h.radius_mm
        out_a = c + (a - c) * (r + standoff_mm) / r
        out_b = c + (b - c) * (r + standoff_mm) / r
        z_safe = c[2] + r + 2 * standoff_mm
        via = np.array([out_a, [out_a[0], out_a[1], z_safe], [out_b[0], out_b[1], z_safe], out_b])
        return Remount(np.array(a), via, np.array(b), skipped)

    def track_run(self, start_node: str, end_node: str) -> Run:
        """Transit along the track of two of its nodes, the shorter way round."""
        h = self.hemi
        a, b = h.node(start_node), h.node(end_node)
        d = (b.azimuth_rad - a.azimuth_rad + math.pi) % (2 * math.pi) - math.pi
        if abs(abs(d) - math.pi) < 1e-12:
            d = abs(d)  # half way round: counter-clockwise
        curve = TrackCurve(h.centre_mm, h.radius_mm, a.elevation_rad, a.azimuth_rad,
                           a.azimuth_rad + d)
        label = f"{start_node}>{end_node}"
        return self._fit([curve], start_node, end_node, [label], ["transit"], "transit",
                         f"transit {label}")

    def remeasure_path(self, layer: Layer, sectors: tuple[int, ...]) -> LayerPath:
        """A short program that runs only ``sectors`` of ``layer`` (with the test's
        passes and their static nodes), starting and ending where the layer program
        does: up the meridian from the first track's node 1 (with a meridian transit),
        along the layer's lower track to each sector and back, and down again."""
        h, t = self.hemi, self.config.test
        items: list[Run | Dwell | Remount] = []
        at = [""]

        def stop(node_id: str) -> None:
            items.append(Dwell(node_id, h.node(node_id).position_mm, t.dwell_s))
            at[0] = node_id

        def add(run: Run) -> None:
            items.append(run)
            stop(run.end_node)

        def go(node_id: str) -> None:
            if at[0] != node_id:
                add(self.track_run(at[0], node_id))

        first = f"{layer.lower_track}-1"
        names = [tr.name for tr in h.tracks]
        climb = names[: names.index(layer.lower_track) + 1] if t.transit == "meridian" else [layer.lower_track]
        stop(f"{climb[0]}-1")
        for a, b in zip(climb, climb[1:]):
            add(self.meridian_run(f"{a}-1", f"{b}-1"))
        for sector in sorted(set(sectors)):
            run = self.sector_run(layer, sector)
            for p in t.passes:
                r = run if p == "forward" else run.reversed("reverse")
                go(r.start_node)
                add(r)
        go(first)
        for a, b in zip(climb[::-1], climb[::-1][1:]):
            add(self.meridian_run(f"{a}-1", f"{b}-1"))
        start = f"{climb[0]}-1"
        return LayerPath(layer.name + REMEASURE, start, np.array(h.node(start).position_mm),
                         tuple(items))

    # -- layer paths ----------------------------------------------------------------------

    def layer_path(self, layer: Layer, excluded: frozenset[str] = frozenset()) -> LayerPath:
        """The layer program's path; segments and transits in ``excluded`` are left out
        and stepped over with a remount of the bar."""
        h, t = self.hemi, self.config.test
        items: list[Run | Dwell | Remount] = []

        def stop(node_id: str) -> None:
            items.append(Dwell(node_id, h.node(node_id).position_mm, t.dwell_s))

        def add(run: Run) -> None:
            items.append(run)
            if run.end_node:
                stop(run.end_node)

        def here() -> np.ndarray | None:
            runs = [i for i in items if isinstance(i, Run)]
            return runs[-1].curve.control_points_mm[-1] if runs else None

        def go_to(run: Run, skipped: tuple[str, ...]) -> None:
            """Remount to the start of ``run`` unless the machine is already there."""
            a, b = here(), run.curve.control_points_mm[0]
            if a is not None and np.linalg.norm(a - b) > 1e-9:
                items.append(self.remount(a, b, skipped))
                if run.start_node:
                    stop(run.start_node)

        # stretches of consecutive feasible segments (runs split at the nodes), and the
        # ids left out before each stretch
        stretches: list[list[list]] = []
        gaps: list[tuple[str, ...]] = []
        current: list[list] = []
        gap: list[str] = []
        for seg in layer.segments:
            if seg.id in excluded:
                if current:
                    stretches.append(current)
                    current = []
                gap.append(seg.id)
                continue
            if not current:
                gaps.append(tuple(gap))
                gap = []
            if current and current[-1][-1].sector == seg.sector:
                current[-1].append(seg)
            else:
                current.append([seg])
        if current:
            stretches.append(current)
        omitted = tuple(s.id for s in layer.segments if s.id in excluded)
        if not stretches:
            return LayerPath(layer.name, "", np.zeros(3), (), omitted)
        forward = [[self.segment_run(layer, g) for g in st] for st in stretches]
        backward = [[r.reversed("reverse") for r in reversed(st)] for st in reversed(forward)]
        back_gaps = [()] + [tuple(reversed(g)) for g in reversed(gaps[1:])]

        first = f"{layer.lower_track}-1"
        names = [tr.name for tr in h.tracks]
        climb = names[: names.index(layer.lower_track) + 1]
        lead = [self.meridian_run(f"{a}-1", f"{b}-1") for a, b in zip(climb, climb[1:])]
        cap = [self.meridian_run(first, TOP), self.meridian_run(TOP, first)] if layer.is_cap else []
        leaves_from_first = forward[0][0].start_node == first
        use_lead = (t.transit == "meridian" and leaves_from_first
                    and not any(r.pieces[0].id in excluded for r in lead))
        use_cap = bool(cap) and leaves_from_first and not any(r.pieces[0].id in excluded for r in cap)
        omitted += tuple(r.pieces[0].id for r in lead + cap if r.pieces[0].id in excluded)

        passes = [(forward, gaps) if p == "forward" else (backward, back_gaps) for p in t.passes]
        if use_lead:
            start_node = f"{climb[0]}-1"
        else:
            first_run = passes[0][0][0][0]
            start_node = first_run.start_node
        start_mm = (h.node(start_node).position_mm if start_node
                    else passes[0][0][0][0].curve.control_points_mm[0])
        if start_node:
            stop(start_node)
        for run in (lead if use_lead else []) + (cap if use_cap else []):
            add(run)
        for stretch_runs, stretch_gaps in passes:
            for runs, skipped in zip(stretch_runs, stretch_gaps):
                go_to(runs[0], skipped)
                for run in runs:
                    add(run)
        if use_lead and [i for i in items if isinstance(i, Run)][-1].end_node == first:
            for a, b in zip(climb[::-1], climb[::-1][1:]):
                add(self.meridian_run(f"{a}-1", f"{b}-1"))
        return LayerPath(layer.name, start_node, np.array(start_mm), tuple(items), omitted)
