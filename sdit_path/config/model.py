"""The configuration's values: one frozen dataclass per TOML table, in the internal
units (mm, s, rad), and the names every table may hold."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

PASSES = ("forward", "reverse")
TRANSITS = ("meridian", "none")
PROJECTIONS = ("stereographic", "vertical")
AXIS_NAMES = ("X", "Y", "Z", "A", "B", "C")
SCHEDULES = ("locked", "moving")
#: the largest tilt offset a sector may take (deg): beyond it the table tilts far from
#: the schedule the rest of the test holds, and the patch's boundary slopes grow steep
TILT_OFFSET_MAX_DEG = 30.0
#: where a sector's wave may crest (fraction of the sector): within it the azimuth warp
#: that moves the crest stays monotone with margin (it folds beyond 0.29 and 0.71)
CREST_RANGE = (0.3, 0.7)
SHAPES = ("box", "cylinder", "capsule", "sphere", "mesh")
FIVE_AXIS_MODES = ("traori", "machine")
TIMING_CONTROLS = ("jerk_limited", "linuxcnc")
#: Default direction of an axis by name and by the branch carrying it.
DEFAULT_DIRECTION = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0),
                      "A": (1.0, 0.0, 0.0), "B": (0.0, 1.0, 0.0), "C": (0.0, 0.0, 1.0)}


@dataclass(frozen=True, slots=True)
class Axis:
    """One machine axis.

    ``kind`` is ``"linear"`` or ``"rotary"``.  Limits are in the axis' own internal
    unit: mm (and mm/s, mm/s^2, mm/s^3) for linear axes, rad (rad/s ...) for rotary
    ones.  ``direction`` is the unit vector, in the bed frame with every axis at 0,
    along which the carried body moves (linear) or about which it turns by the
    right-hand rule (rotary) when the axis value increases; for an axis under the
    table that is normally the opposite of the programmed direction.  ``point_mm`` is
    a point of a rotary axis line (bed frame, every axis at 0).
    """

    name: str
    kind: str
    direction: tuple[float, float, float]
    point_mm: tuple[float, float, float]
    travel: tuple[float, float]
    max_velocity: float
    max_acceleration: float
    max_jerk: float

    @property
    def is_rotary(self) -> bool:
        return self.kind == "rotary"

    @property
    def unit(self) -> str:
        return "deg" if self.is_rotary else "mm"

    def to_display(self, value: float) -> float:
        """Internal value (mm or rad) in the unit users read (mm or deg)."""
        return math.degrees(value) if self.is_rotary else value


@dataclass(frozen=True, slots=True)
class MachineConfig:
    """The kinematic chain: ``workpiece_chain`` lists the axes from the bed to the table
    (the table frame, in which the program and the pivot are given, is the bed frame
    when every axis is at 0); ``tool_chain`` the axes from the bed to the spindle.  The
    spindle gauge point is at the bed origin with every axis at 0 and the ball centre
    ``tool_length_mm`` from it against ``spindle_direction``."""

    name: str
    axes: tuple[Axis, ...]
    workpiece_chain: tuple[str, ...]
    tool_chain: tuple[str, ...]
    tool_length_mm: float
    spindle_direction: tuple[float, float, float]

    def axis(self, name: str) -> Axis:
        for ax in self.axes:
            if ax.name == name:
                return ax
        raise KeyError(name)

    @property
    def rotary_axes(self) -> tuple[Axis, ...]:
        return tuple(a for a in self.axes if a.is_rotary)

    @property
    def linear_axes(self) -> tuple[Axis, ...]:
        return tuple(a for a in self.axes if not a.is_rotary)


@dataclass(frozen=True, slots=True)
class BallbarConfig:
    """The instrument and where its pivot ball sits (program coordinates)."""

    bar_length_mm: float
    pivot_mm: tuple[float, float, float]
    ball_diameter_mm: float
    bar_diameter_mm: float
    sensor_range_mm: float
    length_range_mm: tuple[float, float]


@dataclass(frozen=True, slots=True)
class CurveConfig:
    """Shape of the S-like identification curves.

    ``amplitude`` is the fraction of the layer's projected ring the wave spans (1.0
    touches both bounding tracks); ``waves_per_sector`` the number of crests between
    two neighbouring nodes (the sector's sub-segments divide it evenly in azimuth); ``cap_elevation_deg`` bounds the wave of the top layer (the cap up to
    TOP), which has no upper track of its own.
    """

    amplitude: float
    waves_per_sector: int
    cap_elevation_deg: float
    overrides: tuple["SectorCurve", ...] = ()

    def override(self, sector: str) -> "SectorCurve | None":
        """The override of ``sector`` (``D3``: layer and 1-based sector), if it has one."""
        return next((o for o in self.overrides if o.sector == sector), None)

    def for_sector(self, layer: str, sector: int, projection: str) -> tuple[float, int, str]:
        """(amplitude, waves per sector, projection) of the curves of one sector: its
        override where there is one (``sector`` is 1-based, as in ``D3``)."""
        o = self.override(f"{layer}{sector}")
        if o is None:
            return self.amplitude, self.waves_per_sector, projection
        return (self.amplitude if o.amplitude is None else o.amplitude,
                self.waves_per_sector if o.waves_per_sector is None else o.waves_per_sector,
                projection if o.projection is None else o.projection)

    def crest_for(self, layer: str, sector: int) -> float:
        """Where the curves of a sector crest, as a fraction of the sector (0.5: mid-sector,
        unless its override moves it)."""
        o = self.override(f"{layer}{sector}")
        return 0.5 if o is None or o.crest_at is None else o.crest_at

    def feed_for(self, segment_id: str, feed_mm_per_min: float) -> float:
        """The feed (mm/min) of the curves of a segment (``D3-2``): its sector's
        override where it sets one, else ``feed_mm_per_min`` (the test's)."""
        o = self.override(segment_id.split("-")[0])
        return feed_mm_per_min if o is None or o.feed_mm_per_min is None else o.feed_mm_per_min


@dataclass(frozen=True, slots=True)
class SectorCurve:
    """A re-planned sector (``[[test.curve.override]]``): its curves' own amplitude,
    waves and projection (None: the test's).  Every curve keeps the sector's nodes on
    the lower track with zero slope there, so any values stay tangent-continuous with
    the neighbours.  ``feed_mm_per_min``: the sector's curves run at their own feed
    (the transits and the other sectors at the test's).  ``tilt_offset_deg`` (the
    ``moving`` rotary schedule only): the tilt axis leaves its schedule by up to this
    angle over the sector's patch, ``offset * sin^2(pi a) * sin^2(pi e)`` with ``a`` and
    ``e`` the fractions of the patch's azimuth and elevation spans: a function of the
    ball's place alone (every stage computes the same angles), zero with zero slope on
    the patch's boundary (the nodes, the tracks, the neighbours).  ``crest_at``: where
    in the sector (a fraction of its azimuth span, 0.3-0.7; 0.5 as planned) a single
    wave crests - the wave's phase within the sector, nodes and zero slopes kept (see
    ``geometry.curves``)."""

    sector: str  # layer and 1-based sector, e.g. "D3"
    amplitude: float | None = None
    waves_per_sector: int | None = None
    projection: str | None = None
    feed_mm_per_min: float | None = None
    tilt_offset_deg: float | None = None
    crest_at: float | None = None


@dataclass(frozen=True, slots=True)
class RotaryConfig:
    """How the rotary axes move during the test.

    ``locked``: every rotary axis stays at ``locked_rad`` (the paper's 3-axis run on a
    5-axis machine).  ``moving``: the turn axis follows the bar's azimuth so that the
    bar keeps the azimuth ``hold_azimuth_rad`` in the machine, and the tilt axis moves
    linearly with the bar's elevation from ``tilt_at_equator_rad`` to
    ``tilt_at_pole_rad``.  Angles are radians.
    """

    schedule: str
    locked_rad: tuple[tuple[str, float], ...]
    tilt_axis: str
    turn_axis: str
    hold_azimuth_rad: float
    tilt_at_equator_rad: float
    tilt_at_pole_rad: float


@dataclass(frozen=True, slots=True)
class TestConfig:
    __test__ = False  # not a pytest class

    track_elevations_deg: tuple[float, ...]
    nodes_per_track: int
    subsegments_per_sector: int
    dwell_s: float
    feed_mm_per_min: float
    passes: tuple[str, ...]
    transit: str
    projection: str
    curve: CurveConfig
    rotary: RotaryConfig
    #: sectors (``D3``) that get a short re-measure program of their layer
    #: (``[test.remeasure] sectors``; written by ``replan`` for the sectors it changed)
    remeasure: tuple[str, ...] = ()

    def remeasure_sectors(self, layer: str) -> tuple[int, ...]:
        return tuple(int(s[1:]) for s in self.remeasure if s[0] == layer)

    def run_feed(self, pieces) -> float:
        """The feed (mm/min) of a run made of ``pieces`` (with ``id`` and ``kind``): a
        sector's curves at their override's feed, transits at the test's.  Worked out
        once, when the run is built (``geometry.paths.Run.feed_mm_per_min``)."""
        base = self.feed_mm_per_min
        feeds = {self.curve.feed_for(p.id, base) for p in pieces if p.kind == "segment"}
        return min(feeds) if feeds else base

    def sector_feeds(self, layer: str) -> tuple[tuple[str, float], ...]:
        """(sector, feed) of the sectors of ``layer`` that run at their own feed."""
        return tuple((o.sector, o.feed_mm_per_min) for o in self.curve.overrides
                     if o.sector[0] == layer and o.feed_mm_per_min is not None)


@dataclass(frozen=True, slots=True)
class CheckConfig:
    """Reachability and interference settings."""

    travel_margin_mm: float
    angle_margin_rad: float
    safety_clearance_mm: float
    pose_spacing_mm: float


@dataclass(frozen=True, slots=True)
class TimingConfig:
    """Trajectory export: ``sample_rate_hz`` of ``DIR/trajectories/<program>.csv.gz``;
    ``control``: whose motion the plan's timing predicts: ``jerk_limited`` (ours, under
    the axes' velocity, acceleration and jerk limits: what a jerk-limited control such
    as the 840D runs) or ``linuxcnc`` (what LinuxCNC 2.9's planner does with our
    LinuxCNC program)."""

    sample_rate_hz: float
    export_trajectories: bool
    control: str = "jerk_limited"


@dataclass(frozen=True, slots=True)
class ScenePart:
    """A collision part attached to a body (an axis name, or ``bed``), placed with
    every axis at 0 in the bed frame.  ``shape`` is box, cylinder, capsule, sphere or
    mesh; ``size_mm`` holds (x, y, z) for a box, (radius, length) for a cylinder or
    capsule, (radius,) for a sphere; cylinders and capsules are centred on
    ``position_mm`` along ``axis``; meshes are read from ``mesh_file``."""

    name: str
    body: str
    shape: str
    size_mm: tuple[float, ...]
    position_mm: tuple[float, float, float]
    axis: tuple[float, float, float]
    mesh_file: str


@dataclass(frozen=True, slots=True)
class SceneConfig:
    parts: tuple[ScenePart, ...]
    allowed_contacts: tuple[tuple[str, str], ...]


@dataclass(frozen=True, slots=True)
class PostConfig:
    controllers: tuple[str, ...]
    program_prefix: str
    decimals: int
    spline_degree: int
    spline_tolerance_um: float
    chord_tolerance_um: float
    chord_curve_tolerance_um: float
    work_offset: str
    comment: str
    five_axis_mode: str
    #: the program takes the operator to the bar and back (approach, stops, retract)
    operator_sequence: bool = True
    #: where the approach starts and the retract ends: the ball centre in the table
    #: frame (None: above the pivot, 50 mm over the sphere)
    safe_position_mm: tuple[float, float, float] | None = None
    approach_feed_mm_per_min: float = 2000.0


@dataclass(frozen=True, slots=True)
class Config:
    source: str
    machine: MachineConfig
    ballbar: BallbarConfig
    test: TestConfig
    post: PostConfig
    check: CheckConfig
    scene: SceneConfig
    timing: TimingConfig
    text: str = field(default="", repr=False, compare=False)

