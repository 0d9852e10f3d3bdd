"""Partition of the hemisphere the spindle ball sweeps around the pivot.

Tracks are latitude circles named A, B, C ... from the lowest elevation up; the pole is
the node ``TOP``.  Each track carries ``nodes_per_track`` static nodes, ``A-1`` at
azimuth 0 and then every ``360/n`` degrees counter-clockwise seen from +Z.  A layer is
named after its lower track and reaches the next track up; the top layer is the cap
up to TOP.  A layer has one sector per node interval and each sector
``subsegments_per_sector`` sub-segments, so a segment id reads ``D3-2``: layer D,
sector 3, sub-segment 2, exactly as the paper names them.

Azimuth 0 is +X of the program frame; angles are radians internally.
"""

from __future__ import annotations

import math
import re
import string
from dataclasses import dataclass

import numpy as np

from ..arrays import frozen

from ..config import Config

TOP = "TOP"



@dataclass(frozen=True, slots=True)
class Track:
    name: str
    elevation_rad: float


@dataclass(frozen=True, slots=True)
class Node:
    """A static calibration node.  ``position_mm : (3,) float`` in program coordinates."""

    id: str
    track: str
    azimuth_rad: float
    elevation_rad: float
    position_mm: np.ndarray


@dataclass(frozen=True, slots=True)
class Segment:
    """One identification segment: the patch between two elevations and two azimuths."""

    id: str
    layer: str
    sector: int
    subsegment: int
    azimuth_start_rad: float
    azimuth_end_rad: float
    lower_elevation_rad: float
    upper_elevation_rad: float


@dataclass(frozen=True, slots=True)
class Layer:
    """``upper_elevation_rad`` is the next track up, or the cap bound for the top layer."""

    name: str
    lower_track: str
    upper_track: str
    lower_elevation_rad: float
    upper_elevation_rad: float
    is_cap: bool
    segments: tuple[Segment, ...]

    def sector_nodes(self, sector: int, nodes_per_track: int) -> tuple[str, str]:
        """Lower-track nodes at the start and the end of ``sector`` (1-based)."""
        a = f"{self.lower_track}-{sector}"
        b = f"{self.lower_track}-{sector % nodes_per_track + 1}"
        return a, b


@dataclass(frozen=True, slots=True)
class Hemisphere:
    """``centre_mm : (3,) float`` pivot ball centre; ``radius_mm`` bar length."""

    centre_mm: np.ndarray
    radius_mm: float
    tracks: tuple[Track, ...]
    nodes: tuple[Node, ...]
    layers: tuple[Layer, ...]
    nodes_per_track: int
    subsegments_per_sector: int

    def node(self, node_id: str) -> Node:
        for n in self.nodes:
            if n.id == node_id:
                return n
        raise KeyError(node_id)

    def point(self, azimuth_rad: float, elevation_rad: float) -> np.ndarray:
        """Point on the sphere, program coordinates (mm)."""
        ce = math.cos(elevation_rad)
        return self.centre_mm + self.radius_mm * np.array(
            [ce * math.cos(azimuth_rad), ce * math.sin(azimuth_rad), math.sin(elevation_rad)])

    @property
    def segment_count(self) -> int:
        return sum(len(layer.segments) for layer in self.layers)


#: a test segment's id (``D3-2``: layer, sector, sub-segment; group 1 the layer); the
#: transits between nodes (``A-1>B-1``) and the nodes themselves do not match
TEST_SEGMENT = re.compile(r"^([A-Z]+)\d+-\d+$")


def track_names(count: int) -> tuple[str, ...]:
    return tuple(string.ascii_uppercase[:count])


def partition(config: Config) -> Hemisphere:
    """Tracks, nodes, layers and segments for the configured test."""
    t = config.test
    centre = frozen(config.ballbar.pivot_mm)
    radius = config.ballbar.bar_length_mm
    names = track_names(len(t.track_elevations_deg))
    elevations = [math.radians(e) for e in t.track_elevations_deg]
    tracks = tuple(Track(n, e) for n, e in zip(names, elevations))
    n_nodes = t.nodes_per_track
    subs = t.subsegments_per_sector

    nodes: list[Node] = []
    for track in tracks:
        for k in range(n_nodes):
            az = 2.0 * math.pi * k / n_nodes
            ce = math.cos(track.elevation_rad)
            pos = centre + radius * np.array([ce * math.cos(az), ce * math.sin(az),
                                              math.sin(track.elevation_rad)])
            nodes.append(Node(f"{track.name}-{k + 1}", track.name, az, track.elevation_rad,
                              frozen(pos)))
    nodes.append(Node(TOP, TOP, 0.0, math.pi / 2, frozen(centre + [0.0, 0.0, radius])))

    layers = []
    cap = math.radians(t.curve.cap_elevation_deg)
    for i, track in enumerate(tracks):
        is_cap = i == len(tracks) - 1
        upper_name = TOP if is_cap else tracks[i + 1].name
        upper = cap if is_cap else tracks[i + 1].elevation_rad
        segs = []
        step = 2.0 * math.pi / (n_nodes * subs)
        for sector in range(1, n_nodes + 1):
            for sub in range(1, subs + 1):
                j = (sector - 1) * subs + (sub - 1)
                segs.append(Segment(f"{track.name}{sector}-{sub}", track.name, sector, sub,
                                    j * step, (j + 1) * step, track.elevation_rad, upper))
        layers.append(Layer(track.name, track.name, upper_name, track.elevation_rad, upper,
                            is_cap, tuple(segs)))
    return Hemisphere(centre, radius, tracks, tuple(nodes), tuple(layers), n_nodes, subs)
