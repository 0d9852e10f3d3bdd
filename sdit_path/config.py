"""Configuration: one TOML file describes the machine, the ballbar, the test and the post.

Loading validates everything up front.  Every problem raises
:class:`~sdit_path.errors.ConfigError` whose message names the file, the line (when it
can be found) and the dotted key, says what was expected and what arrived.  Unknown
keys are errors too, so a misspelt or wrongly-unitised key (``feed_mm_per_s``) is
caught instead of silently ignored.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from .errors import ConfigError

#: The bundled default sample, planned when the CLI is given no config.
DEFAULT_SAMPLE = "vmc_3axis.toml"

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
#: Default direction of an axis by name and by the branch carrying it.
_DEFAULT_DIRECTION = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0),
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

    def run_feed(self, pieces, feed_mm_per_min: float | None = None) -> float:
        """The feed (mm/min) of a run made of ``pieces`` (with ``id`` and ``kind``): a
        sector's curves at their override's feed, transits at ``feed_mm_per_min`` (by
        default the test's)."""
        base = self.feed_mm_per_min if feed_mm_per_min is None else feed_mm_per_min
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
    """Trajectory export: ``sample_rate_hz`` of ``DIR/trajectories/<program>.csv.gz``."""

    sample_rate_hz: float
    export_trajectories: bool


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
    work_offset: str
    comment: str
    five_axis_mode: str


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


# --------------------------------------------------------------------------- reading


def _line_of(text: str, dotted: str) -> int | None:
    """Best-effort line number (1-based) of a dotted key in TOML text."""
    m = re.fullmatch(r"(.+)\[(\d+)\](?:\.(.+))?", dotted)
    if m:  # an array of tables: the k-th [[table]] header, then the key below it
        table, k, key = m.group(1), int(m.group(2)), m.group(3)
        lines = text.splitlines()
        starts = [i for i, raw in enumerate(lines)
                  if re.match(rf"^\s*\[\[\s*{re.escape(table)}\s*\]\]", raw)]
        if k >= len(starts):
            return None
        end = next((i for i in range(starts[k] + 1, len(lines))
                    if re.match(r"^\s*\[", lines[i])), len(lines))
        for i in range(starts[k] + 1, end):
            if key and re.match(rf"^\s*{re.escape(key)}\s*=", lines[i]):
                return i + 1
        return starts[k] + 1
    parts = dotted.split(".")
    table: list[str] = []
    header = re.compile(r"^\s*\[\s*([^\]]+?)\s*\]\s*(#.*)?$")
    for number, raw in enumerate(text.splitlines(), start=1):
        m = header.match(raw)
        if m:
            table = [p.strip().strip('"') for p in m.group(1).split(".")]
            continue
        m = re.match(r"^\s*([A-Za-z0-9_\-\.\"]+)\s*=", raw)
        if not m:
            continue
        key = [p.strip().strip('"') for p in m.group(1).split(".")]
        if table + key == parts:
            return number
    # a table itself, e.g. a missing key inside it: point at its header
    for number, raw in enumerate(text.splitlines(), start=1):
        m = header.match(raw)
        if m and [p.strip().strip('"') for p in m.group(1).split(".")] == parts[:-1]:
            return number
    return None


class _Reader:
    """Reads typed values from a nested dict, naming file, line and key on errors."""

    def __init__(self, source: str, text: str):
        self.source = source
        self.text = text

    def fail(self, key: str, message: str) -> ConfigError:
        line = _line_of(self.text, key) if key and len(key) < 200 else None
        where = f"{self.source}:{line}" if line else self.source
        shown = key if len(key) <= 80 else key[:77] + "..."
        return ConfigError(where, f"{shown}: {message}" if key else message)

    def table(self, data: dict, key: str, known: tuple[str, ...], required: bool = True) -> dict:
        value = data.get(key.rsplit(".", 1)[-1])
        if value is None:
            if required:
                raise self.fail(key, "missing table; expected a [" + key + "] section")
            value = {}
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table, got {_describe(value)}")
        self.no_unknown(value, key, known)
        return value

    def no_unknown(self, data: dict, prefix: str, known: tuple[str, ...]) -> None:
        for k in data:
            if k not in known:
                dotted = f"{prefix}.{k}" if prefix else k
                raise self.fail(dotted, f"unknown key; expected one of: {', '.join(known)}")

    def number(self, data: dict, key: str, default: float | None = None, *,
               gt: float | None = None, ge: float | None = None,
               lt: float | None = None, le: float | None = None, unit: str = "") -> float:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, f"missing; expected a number{_unit(unit)}")
            return float(default)
        value = data[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"expected a number{_unit(unit)}, got {_describe(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise self.fail(key, f"expected a finite number{_unit(unit)}, got {value}")
        _check_bounds(self, key, value, gt, ge, lt, le, unit)
        return value

    def integer(self, data: dict, key: str, default: int | None = None, *,
                ge: int | None = None, le: int | None = None) -> int:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, "missing; expected an integer")
            return default
        value = data[name]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"expected an integer, got {_describe(value)}")
        _check_bounds(self, key, float(value), None, ge, None, le, "")
        return value

    def string(self, data: dict, key: str, default: str | None = None,
               choices: tuple[str, ...] | None = None) -> str:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, "missing; expected a string")
            return default
        value = data[name]
        if not isinstance(value, str):
            raise self.fail(key, f"expected a string, got {_describe(value)}")
        if choices is not None and value not in choices:
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {_short(value)}")
        if len(value) > 1000:
            raise self.fail(key, f"expected at most 1000 characters, got {len(value)}")
        return value

    def vector(self, data: dict, key: str, length: int, default: tuple | None = None,
               unit: str = "", bound: float = 1e4) -> tuple[float, ...]:
        """``length`` finite numbers, each within +-``bound`` (a physical plausibility
        limit, 10 m by default: nothing on a machine tool lies further away)."""
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            if default is None:
                raise self.fail(key, f"missing; expected {length} numbers{_unit(unit)}")
            return tuple(float(v) for v in default)
        value = data[name]
        if (not isinstance(value, list) or len(value) != length
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise self.fail(key, f"expected a list of {length} numbers{_unit(unit)}, "
                                 f"got {_describe(value)}")
        out = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in out):
            raise self.fail(key, f"expected finite numbers, got {list(out)}")
        if any(abs(v) > bound for v in out):
            raise self.fail(key, f"expected values within +-{bound:g}{_unit(unit)} (a plausible "
                                 f"machine), got {[float(f'{v:.6g}') for v in out]}")
        return out

    def numbers(self, data: dict, key: str, default: tuple, unit: str = "") -> tuple[float, ...]:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            return tuple(float(v) for v in default)
        value = data[name]
        if (not isinstance(value, list) or not value
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
            raise self.fail(key, f"expected a non-empty list of numbers{_unit(unit)}, "
                                 f"got {_describe(value)}")
        out = tuple(float(v) for v in value)
        if not all(math.isfinite(v) for v in out):
            raise self.fail(key, f"expected finite numbers, got {list(out)}")
        return out

    def boolean(self, data: dict, key: str, default: bool) -> bool:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            return default
        value = data[name]
        if not isinstance(value, bool):
            raise self.fail(key, f"expected true or false, got {_describe(value)}")
        return value

    def strings(self, data: dict, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
        name = key.rsplit(".", 1)[-1]
        if name not in data:
            return default
        value = data[name]
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise self.fail(key, f"expected a non-empty list of strings, got {_describe(value)}")
        return tuple(value)


def _unit(unit: str) -> str:
    return f" in {unit}" if unit else ""


def _short(text: str, limit: int = 60) -> str:
    """repr of a user's string, cut so that an error line stays one readable line."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + f"... ({len(text)} chars)"


def _describe(value: Any) -> str:
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"string {_short(value)}"
    return f"{type(value).__name__} {_short(repr(value))}"


def _check_bounds(reader: _Reader, key: str, value: float, gt, ge, lt, le, unit: str) -> None:
    u = f" {unit}" if unit else ""
    if gt is not None and not value > gt:
        raise reader.fail(key, f"expected a value > {gt:g}{u}, got {value:g}")
    if ge is not None and not value >= ge:
        raise reader.fail(key, f"expected a value >= {ge:g}{u}, got {value:g}")
    if lt is not None and not value < lt:
        raise reader.fail(key, f"expected a value < {lt:g}{u}, got {value:g}")
    if le is not None and not value <= le:
        raise reader.fail(key, f"expected a value <= {le:g}{u}, got {value:g}")


# --------------------------------------------------------------------------- sections

_LINEAR_KEYS = ("type", "direction", "travel_mm", "max_velocity_mm_per_s",
                "max_acceleration_mm_per_s2", "max_jerk_mm_per_s3")
_ROTARY_KEYS = ("type", "direction", "point_mm", "travel_deg", "max_velocity_deg_per_s",
                "max_acceleration_deg_per_s2", "max_jerk_deg_per_s3")


def _unit_vector(r: _Reader, data: dict, key: str, default) -> tuple[float, float, float]:
    v = r.vector(data, key, 3, default=default)
    n = math.sqrt(sum(x * x for x in v))
    if n < 1e-12:
        raise r.fail(key, "expected a non-zero direction vector")
    return tuple(x / n for x in v)


def _axis(r: _Reader, a: dict, key: str, name: str, on_workpiece: bool) -> Axis:
    kind = r.string(a, f"{key}.type", "rotary" if name in "ABC" else "linear", ("linear", "rotary"))
    r.no_unknown(a, key, _ROTARY_KEYS if kind == "rotary" else _LINEAR_KEYS)
    default = _DEFAULT_DIRECTION[name]
    if kind == "linear" and on_workpiece:
        default = tuple(-x for x in default)  # the table moves against the program axis
    direction = _unit_vector(r, a, f"{key}.direction", default)
    if kind == "linear":
        lo, hi = r.vector(a, f"{key}.travel_mm", 2, unit="mm", bound=1e5)
        scale, unit, point = 1.0, "mm", (0.0, 0.0, 0.0)
    else:
        lo, hi = r.vector(a, f"{key}.travel_deg", 2, unit="deg", bound=1e5)
        scale, unit = math.pi / 180.0, "deg"
        point = r.vector(a, f"{key}.point_mm", 3, default=(0.0, 0.0, 0.0), unit="mm")
    if not lo < hi:
        raise r.fail(f"{key}.travel_{unit}", f"expected [min, max] with min < max, got [{lo:g}, {hi:g}]")
    # plausibility bounds: the slowest and the fastest machine tools, with room to spare
    # (linear motors reach about 3 m/s, 5 g and 1e6 mm/s^3; direct-drive tables 3000 deg/s)
    vel, acc, jerk = _LIMIT_BOUNDS[kind]
    return Axis(
        name=name, kind=kind, direction=direction, point_mm=point,
        travel=(lo * scale, hi * scale),
        max_velocity=r.number(a, f"{key}.max_velocity_{unit}_per_s", ge=vel[0], le=vel[1],
                              unit=f"{unit}/s") * scale,
        max_acceleration=r.number(a, f"{key}.max_acceleration_{unit}_per_s2", ge=acc[0],
                                  le=acc[1], unit=f"{unit}/s^2") * scale,
        max_jerk=r.number(a, f"{key}.max_jerk_{unit}_per_s3", ge=jerk[0], le=jerk[1],
                          unit=f"{unit}/s^3") * scale,
    )


#: (min, max) of velocity, acceleration and jerk limits, per axis kind (mm or deg)
_LIMIT_BOUNDS = {"linear": ((0.1, 2e4), (1.0, 2e5), (10.0, 1e9)),
                 "rotary": ((0.1, 1e5), (1.0, 1e6), (10.0, 1e10))}


def _machine(r: _Reader, root: dict) -> MachineConfig:
    m = r.table(root, "machine", ("name", "axes", "workpiece_chain", "tool_chain", "tool_length_mm",
                                  "spindle_direction"))
    name = r.string(m, "machine.name")
    workpiece = r.strings(m, "machine.workpiece_chain", ("X", "Y"))
    tool = r.strings(m, "machine.tool_chain", ("Z",))
    chain = workpiece + tool
    for ax in chain:
        if ax not in AXIS_NAMES:
            raise r.fail("machine.workpiece_chain" if ax in workpiece else "machine.tool_chain",
                         f"unknown axis {_short(ax)}; expected axis names among {', '.join(AXIS_NAMES)}")
    if len(set(chain)) != len(chain):
        raise r.fail("machine.workpiece_chain", f"an axis appears twice in the chains: {list(chain)}")
    axes_table = r.table(m, "machine.axes", chain)
    axes = []
    for ax in chain:
        key = f"machine.axes.{ax}"
        a = axes_table.get(ax)
        if not isinstance(a, dict):
            raise r.fail(key, f"missing table; the chains name axis {ax}, expected a [{key}] section")
        axes.append(_axis(r, a, key, ax, ax in workpiece))
    linear = [a for a in axes if not a.is_rotary]
    if len(linear) != 3:
        raise r.fail("machine.workpiece_chain",
                     f"expected exactly 3 linear axes in the chains, got {len(linear)}")
    det = _det3([a.direction for a in linear])
    if abs(det) < 1e-6:
        raise r.fail("machine.axes", "the 3 linear axis directions must be independent")
    if any(a.is_rotary for a in axes if a.name in tool):
        raise r.fail("machine.tool_chain", "rotary axes in the tool branch (swivel heads) are not "
                                           "supported yet; put rotary axes in machine.workpiece_chain")
    return MachineConfig(
        name=name, axes=tuple(axes), workpiece_chain=workpiece, tool_chain=tool,
        tool_length_mm=r.number(m, "machine.tool_length_mm", 0.0, ge=0, le=2000, unit="mm"),
        spindle_direction=_unit_vector(r, m, "machine.spindle_direction", (0.0, 0.0, 1.0)))


def _det3(rows) -> float:
    (a, b, c), (d, e, f), (g, h, i) = rows
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _ballbar(r: _Reader, root: dict, machine: MachineConfig) -> BallbarConfig:
    b = r.table(root, "ballbar", ("bar_length_mm", "pivot_mm", "ball_diameter_mm",
                                  "bar_diameter_mm", "sensor_range_mm", "length_range_mm"))
    length_range = r.vector(b, "ballbar.length_range_mm", 2, default=(50.0, 600.0), unit="mm",
                            bound=3000)
    if not 0 < length_range[0] <= length_range[1]:
        raise r.fail("ballbar.length_range_mm",
                     f"expected [min, max] with 0 < min <= max, got {list(length_range)}")
    length = r.number(b, "ballbar.bar_length_mm", gt=0, unit="mm")
    if not length_range[0] <= length <= length_range[1]:
        raise r.fail("ballbar.bar_length_mm",
                     f"expected a bar length within the instrument's reach "
                     f"{length_range[0]:g}..{length_range[1]:g} mm (ballbar.length_range_mm), "
                     f"got {length:g} mm")
    ball = r.number(b, "ballbar.ball_diameter_mm", default=12.7, ge=1, le=100, unit="mm")
    if not ball < length:
        raise r.fail("ballbar.ball_diameter_mm",
                     f"expected a ball diameter smaller than the bar length {length:g} mm, got {ball:g}")
    sensor = r.number(b, "ballbar.sensor_range_mm", default=1.0, gt=0, le=10.0, unit="mm")
    bar = r.number(b, "ballbar.bar_diameter_mm", default=min(12.0, ball), ge=0.5, unit="mm")
    if bar > ball:
        raise r.fail("ballbar.bar_diameter_mm",
                     f"expected a bar no thicker than the balls ({ball:g} mm), got {bar:g}")
    pivot = r.vector(b, "ballbar.pivot_mm", 3, unit="mm")
    return BallbarConfig(bar_length_mm=length, pivot_mm=pivot, ball_diameter_mm=ball,
                         bar_diameter_mm=bar, sensor_range_mm=sensor, length_range_mm=length_range)


def _test(r: _Reader, root: dict, machine: MachineConfig) -> TestConfig:
    t = r.table(root, "test", ("track_elevations_deg", "nodes_per_track", "subsegments_per_sector",
                               "dwell_s", "feed_mm_per_min", "passes", "transit", "projection",
                               "curve", "rotary", "remeasure"))
    elev = r.numbers(t, "test.track_elevations_deg", (0.0, 18.0, 36.0, 54.0, 72.0), unit="deg")
    if len(elev) > 25:
        raise r.fail("test.track_elevations_deg", f"expected at most 25 tracks, got {len(elev)}")
    if elev[0] < 0:
        raise r.fail("test.track_elevations_deg",
                     f"expected elevations >= 0 deg (a hemisphere above the pivot), got {elev[0]:g}")
    for a, b in zip(elev, elev[1:]):
        if not b > a:
            raise r.fail("test.track_elevations_deg",
                         f"expected strictly increasing elevations, got {a:g} then {b:g}")
        if b - a < 1.0:
            raise r.fail("test.track_elevations_deg",
                         f"expected tracks at least 1 deg apart (a layer needs room for its "
                         f"curves), got {a:g} then {b:g}")
    if elev[-1] >= 90:
        raise r.fail("test.track_elevations_deg",
                     f"expected elevations < 90 deg (the pole is the node TOP), got {elev[-1]:g}")
    nodes = r.integer(t, "test.nodes_per_track", 6, ge=1, le=72)
    subs = r.integer(t, "test.subsegments_per_sector", 3, ge=1, le=20)
    dwell = r.number(t, "test.dwell_s", 2.0, gt=0, le=3600, unit="s")
    feed = _feed(r, t, "test.feed_mm_per_min", machine)
    passes = r.strings(t, "test.passes", PASSES)
    for p in passes:
        if p not in PASSES:
            raise r.fail("test.passes", f"expected passes among {', '.join(PASSES)}, got {_short(p)}")
    if len(set(passes)) != len(passes):
        raise r.fail("test.passes", f"expected each pass at most once, got {list(passes)}")
    transit = r.string(t, "test.transit", "meridian", TRANSITS)
    projection = r.string(t, "test.projection", "stereographic", PROJECTIONS)
    c = r.table(t, "test.curve", ("amplitude", "waves_per_sector", "cap_elevation_deg",
                                  "override"), required=False)
    amplitude = r.number(c, "test.curve.amplitude", 1.0, gt=0, le=1)
    waves = r.integer(c, "test.curve.waves_per_sector", 1, ge=1, le=10)
    cap = r.number(c, "test.curve.cap_elevation_deg", (elev[-1] + 90.0) / 2.0, le=90, unit="deg")
    if not elev[-1] < cap < 90:
        raise r.fail("test.curve.cap_elevation_deg",
                     f"expected a value between the top track ({elev[-1]:g} deg) and 90 deg, got {cap:g}")
    rotary = _rotary(r, t, machine)
    overrides = _overrides(r, c, len(elev), nodes, machine, rotary.schedule)
    return TestConfig(track_elevations_deg=elev, nodes_per_track=nodes, subsegments_per_sector=subs,
                      dwell_s=dwell, feed_mm_per_min=feed, passes=passes, transit=transit,
                      projection=projection,
                      curve=CurveConfig(amplitude=amplitude, waves_per_sector=waves,
                                        cap_elevation_deg=cap,
                                        overrides=overrides),
                      rotary=rotary,
                      remeasure=_remeasure(r, t, len(elev), nodes))


def _sector_name(r: _Reader, key: str, sector, tracks: int, nodes: int) -> str:
    letters = "ABCDEFGHIJKLMNOPQRSTUVWXY"[:tracks]
    ok = (isinstance(sector, str) and len(sector) >= 2 and sector[0] in letters
          and sector[1:].isdigit() and 1 <= int(sector[1:]) <= nodes
          and str(int(sector[1:])) == sector[1:])
    if not ok:
        raise r.fail(key, f"expected a layer letter ({letters[0]}-{letters[-1]}) and a sector "
                          f"number 1-{nodes}, such as {letters[-1]}{min(3, nodes)}, got "
                          f"{_short(sector) if isinstance(sector, str) else _describe(sector)}")
    return sector


def _remeasure(r: _Reader, t: dict, tracks: int, nodes: int) -> tuple[str, ...]:
    m = r.table(t, "test.remeasure", ("sectors",), required=False)
    raw = m.get("sectors", [])
    if not isinstance(raw, list):
        raise r.fail("test.remeasure.sectors", f"expected a list of sectors such as [\"D3\"], "
                                               f"got {_describe(raw)}")
    out = [_sector_name(r, "test.remeasure.sectors", s, tracks, nodes) for s in raw]
    if len(set(out)) != len(out):
        raise r.fail("test.remeasure.sectors", f"expected each sector at most once, got {out}")
    return tuple(sorted(out, key=lambda x: (x[0], int(x[1:]))))


def _feed(r: _Reader, t: dict, key: str, machine: MachineConfig, default=None) -> float:
    """A feed in mm/min the programs can write and the machine can reach."""
    feed = r.number(t, key, default, gt=0, unit="mm/min")
    if feed < 1.0:
        raise r.fail(key, f"expected a feed of at least 1 mm/min (programs write F with 3 "
                          f"decimals, and a slower test would last days), got {feed:g}")
    slowest = min(ax.max_velocity for ax in machine.linear_axes) * 60.0
    fastest_path = math.sqrt(sum((ax.max_velocity * 60.0) ** 2 for ax in machine.linear_axes))
    if feed > fastest_path:
        raise r.fail(key, f"expected a feed the machine can reach (<= {fastest_path:.0f} mm/min "
                          f"from the axis velocity limits; slowest axis {slowest:.0f} mm/min), "
                          f"got {feed:g}")
    return feed


def _overrides(r: _Reader, c: dict, tracks: int, nodes: int, machine: MachineConfig,
               schedule: str) -> tuple[SectorCurve, ...]:
    """``[[test.curve.override]]``: one table per re-planned sector."""
    raw = c.get("override", [])
    key = "test.curve.override"
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list) or not all(isinstance(o, dict) for o in raw):
        raise r.fail(key, f"expected [[{key}]] tables, got {_describe(raw)}")
    if len(raw) > 25 * 72:
        raise r.fail(key, f"expected at most one override per sector, got {len(raw)}")
    out, seen = [], set()
    base = key
    for i, o in enumerate(raw, start=1):
        key = f"{base}[{i}]" if len(raw) > 1 else base
        r.no_unknown(o, key, ("sector", "amplitude", "waves_per_sector", "projection",
                              "feed_mm_per_min", "tilt_offset_deg", "crest_at"))
        sector = _sector_name(r, f"{key}.sector", r.string(o, f"{key}.sector"), tracks, nodes)
        if sector in seen:
            raise r.fail(f"{key}.sector", f"expected each sector at most once, got {sector} twice")
        seen.add(sector)
        if "tilt_offset_deg" in o and schedule != "moving":
            raise r.fail(f"{key}.tilt_offset_deg",
                         f"expected test.rotary.schedule = \"moving\" for a tilt offset (the "
                         f"'{schedule}' schedule holds the tilt axis still), got it on {sector}")
        out.append(SectorCurve(
            sector,
            r.number(o, f"{key}.amplitude", gt=0, le=1) if "amplitude" in o else None,
            r.integer(o, f"{key}.waves_per_sector", ge=1, le=10) if "waves_per_sector" in o else None,
            r.string(o, f"{key}.projection", choices=PROJECTIONS) if "projection" in o else None,
            _feed(r, o, f"{key}.feed_mm_per_min", machine) if "feed_mm_per_min" in o else None,
            r.number(o, f"{key}.tilt_offset_deg", ge=-TILT_OFFSET_MAX_DEG, le=TILT_OFFSET_MAX_DEG,
                     unit="deg") if "tilt_offset_deg" in o else None,
            r.number(o, f"{key}.crest_at", ge=CREST_RANGE[0], le=CREST_RANGE[1])
            if "crest_at" in o else None))
    return tuple(sorted(out, key=lambda x: (x.sector[0], int(x.sector[1:]))))


def _rotary(r: _Reader, t: dict, machine: MachineConfig) -> RotaryConfig:
    rot = r.table(t, "test.rotary", ("schedule", "locked_deg", "tilt_axis", "turn_axis",
                                     "hold_azimuth_deg", "tilt_at_equator_deg", "tilt_at_pole_deg"),
                  required=False)
    names = [a.name for a in machine.rotary_axes]
    schedule = r.string(rot, "test.rotary.schedule", "locked", SCHEDULES)
    locked_table = rot.get("locked_deg", {})
    if not isinstance(locked_table, dict):
        raise r.fail("test.rotary.locked_deg", "expected a table of axis = angle in deg, e.g. {B = 0, C = 0}")
    r.no_unknown(locked_table, "test.rotary.locked_deg", tuple(names))
    locked = tuple((n, math.radians(r.number(locked_table, f"test.rotary.locked_deg.{n}", 0.0,
                                               ge=-1e5, le=1e5, unit="deg"))) for n in names)
    tilt = r.string(rot, "test.rotary.tilt_axis", names[0] if len(names) == 2 else "")
    turn = r.string(rot, "test.rotary.turn_axis", names[-1] if names else "")
    if schedule == "moving":
        if len(names) != 2:
            raise r.fail("test.rotary.schedule",
                         f"'moving' needs two rotary axes (tilt and turn), the machine has {len(names)}")
        for key, value in (("tilt_axis", tilt), ("turn_axis", turn)):
            if value not in names:
                raise r.fail(f"test.rotary.{key}",
                             f"expected one of the rotary axes {', '.join(names)}, got {_short(value)}")
        if tilt == turn:
            raise r.fail("test.rotary.turn_axis", "tilt and turn axes must differ")
        dz = machine.axis(turn).direction[2]
        if abs(dz) < 0.5:
            raise r.fail(f"machine.axes.{turn}.direction",
                         f"the 'moving' schedule turns the table about a near-vertical axis; "
                         f"expected {turn}'s direction within 60 deg of Z, got "
                         f"{[round(x, 4) for x in machine.axis(turn).direction]} (normalised)")
    return RotaryConfig(
        schedule=schedule, locked_rad=locked, tilt_axis=tilt, turn_axis=turn,
        hold_azimuth_rad=math.radians(r.number(rot, "test.rotary.hold_azimuth_deg", 0.0,
                                               ge=-360, le=360, unit="deg")),
        tilt_at_equator_rad=math.radians(r.number(rot, "test.rotary.tilt_at_equator_deg", 0.0,
                                                  ge=-360, le=360, unit="deg")),
        tilt_at_pole_rad=math.radians(r.number(rot, "test.rotary.tilt_at_pole_deg", 0.0,
                                               ge=-360, le=360, unit="deg")))


def _check(r: _Reader, root: dict) -> CheckConfig:
    c = r.table(root, "check", ("travel_margin_mm", "angle_margin_deg", "safety_clearance_mm",
                                "pose_spacing_mm"), required=False)
    return CheckConfig(
        travel_margin_mm=r.number(c, "check.travel_margin_mm", 0.0, ge=0, le=1000, unit="mm"),
        angle_margin_rad=math.radians(r.number(c, "check.angle_margin_deg", 0.0, ge=0, le=90,
                                               unit="deg")),
        safety_clearance_mm=r.number(c, "check.safety_clearance_mm", 1.0, ge=0, le=200, unit="mm"),
        # below 0.05 mm the pose count (and memory) grows past millions per layer while
        # the clearance it finds changes by nanometres
        pose_spacing_mm=r.number(c, "check.pose_spacing_mm", 0.5, ge=0.05, le=0.5, unit="mm"))


_PART_KEYS = ("name", "body", "shape", "size_mm", "position_mm", "axis", "mesh_file")
_SIZES = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "mesh": 0}
#: Parts sdit-path adds itself: the two balls and the bar between them.
BALLBAR_PARTS = ("pivot_ball", "tool_ball", "bar")


def _scene(r: _Reader, root: dict, machine: MachineConfig) -> SceneConfig:
    sc = r.table(root, "scene", ("parts", "allowed_contacts"), required=False)
    raw_parts = sc.get("parts", [])
    if not isinstance(raw_parts, list) or not all(isinstance(p, dict) for p in raw_parts):
        raise r.fail("scene.parts", "expected an array of tables [[scene.parts]]")
    bodies = ("bed",) + machine.workpiece_chain + machine.tool_chain
    parts, names = [], set(BALLBAR_PARTS)
    for k, p in enumerate(raw_parts):
        key = f"scene.parts[{k}]"
        r.no_unknown(p, key, _PART_KEYS)
        name = r.string(p, f"{key}.name")
        if name in names:
            raise r.fail(f"{key}.name", f"part name {name!r} is used twice (or is reserved)")
        names.add(name)
        body = r.string(p, f"{key}.body", choices=bodies)
        shape = r.string(p, f"{key}.shape", choices=SHAPES)
        n = _SIZES[shape]
        size = r.vector(p, f"{key}.size_mm", n, unit="mm", bound=1e4) if n else ()
        if any(v < 0.01 for v in size):
            raise r.fail(f"{key}.size_mm", f"expected sizes of at least 0.01 mm, got {list(size)}")
        mesh = r.string(p, f"{key}.mesh_file", "") if shape == "mesh" else ""
        if shape == "mesh" and not mesh:
            raise r.fail(f"{key}.mesh_file", "a mesh part needs mesh_file (an STL path)")
        parts.append(ScenePart(name=name, body=body, shape=shape, size_mm=size,
                               position_mm=r.vector(p, f"{key}.position_mm", 3, default=(0, 0, 0),
                                                    unit="mm"),
                               axis=_unit_vector(r, p, f"{key}.axis", (0.0, 0.0, 1.0)),
                               mesh_file=mesh))
    allowed = []
    raw_allowed = sc.get("allowed_contacts", [])
    if not isinstance(raw_allowed, list) or not all(
            isinstance(x, list) and len(x) == 2 and all(isinstance(y, str) for y in x)
            for x in raw_allowed):
        raise r.fail("scene.allowed_contacts", "expected a list of [part, part] name pairs")
    for a, b in raw_allowed:
        for n in (a, b):
            if n not in names:
                raise r.fail("scene.allowed_contacts", f"unknown part {_short(n)}; parts: {', '.join(sorted(names))}")
        allowed.append((a, b))
    return SceneConfig(parts=tuple(parts), allowed_contacts=tuple(allowed))


def _post(r: _Reader, root: dict) -> PostConfig:
    from .nc.registry import known_controllers  # the registry is the one source of names

    p = r.table(root, "post", ("controllers", "program_prefix", "decimals", "spline_degree",
                               "spline_tolerance_um", "chord_tolerance_um", "work_offset",
                               "comment", "five_axis_mode"))
    controllers = r.strings(p, "post.controllers", ("sinumerik840d", "linuxcnc"))
    known = known_controllers()
    for name in controllers:
        if name not in known:
            raise r.fail("post.controllers",
                         f"unknown controller {_short(name)}; known controllers: {', '.join(sorted(known))}")
    if len(set(controllers)) != len(controllers):
        raise r.fail("post.controllers", f"expected each controller once, got {list(controllers)}")
    offset = r.string(p, "post.work_offset", "G54")
    if not re.fullmatch(r"G5(00|[4-9]|0[5-9]|[1-9][0-9])|G54\.1 P([1-9][0-9]{0,2})", offset) or (
            offset.startswith("G54.1") and int(offset.split("P")[1]) > 300):
        raise r.fail("post.work_offset",
                     f"expected a work offset such as G54..G59, G54.1 P1..P300 or G500 (machine "
                     f"frame), got {offset[:40]!r}")
    return PostConfig(
        controllers=controllers,
        program_prefix=r.string(p, "post.program_prefix", "SDIT"),
        decimals=r.integer(p, "post.decimals", 6, ge=3, le=9),
        spline_degree=r.integer(p, "post.spline_degree", 3, ge=2, le=3),
        spline_tolerance_um=r.number(p, "post.spline_tolerance_um", 0.01, ge=0.001, le=100,
                                     unit="um"),
        chord_tolerance_um=r.number(p, "post.chord_tolerance_um", 0.1, ge=0.001, le=100, unit="um"),
        work_offset=offset,
        comment=r.string(p, "post.comment", ""),
        five_axis_mode=r.string(p, "post.five_axis_mode", "traori", FIVE_AXIS_MODES),
    )


def parse_config(text: str, source: str = "<config>") -> Config:
    """Parse and validate TOML ``text``; ``source`` names it in error messages."""
    try:
        root = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        where = f"{source}:{m.group(1)}" if m else source
        raise ConfigError(where, f"cannot parse TOML: {msg}") from None
    r = _Reader(source, text)
    r.no_unknown(root, "", ("machine", "ballbar", "test", "post", "check", "scene", "timing"))
    machine = _machine(r, root)
    ballbar = _ballbar(r, root, machine)
    test = _test(r, root, machine)
    post = _post(r, root)
    check = _check(r, root)
    scene = _scene(r, root, machine)
    tm = r.table(root, "timing", ("sample_rate_hz", "export_trajectories"), required=False)
    timing = TimingConfig(
        sample_rate_hz=r.number(tm, "timing.sample_rate_hz", 1000.0, ge=10, le=5000, unit="Hz"),
        export_trajectories=r.boolean(tm, "timing.export_trajectories", True))
    _pivot_reachable(r, machine, ballbar, test)
    return Config(source=source, machine=machine, ballbar=ballbar, test=test, post=post,
                  check=check, scene=scene, timing=timing, text=text)


def _pivot_reachable(r: _Reader, machine: MachineConfig, ballbar: BallbarConfig,
                     test: TestConfig) -> None:
    """The tool ball must be able to reach the pivot position itself (rotary axes at
    their locked angles): a pivot outside the travel is a config mistake."""
    from .machine.kinematics import Kinematics  # the chain is the one source of truth

    kin = Kinematics(machine)
    angles = dict(test.rotary.locked_rad)
    q = kin.inverse([ballbar.pivot_mm], {n: [v] for n, v in angles.items()})
    for j, ax in enumerate(kin.axes):
        lo, hi = ax.travel
        v = float(q[0, j])
        if not lo - 1e-9 <= v <= hi + 1e-9:
            raise r.fail("ballbar.pivot_mm",
                         f"pivot {list(ballbar.pivot_mm)} mm needs {ax.name}={ax.to_display(v):.3f} "
                         f"{ax.unit}, outside the {ax.name} travel [{ax.to_display(lo):g}, "
                         f"{ax.to_display(hi):g}] {ax.unit} (machine.axes.{ax.name})")


def load_config(path: str | Path | None = None) -> Config:
    """Load a config file, or the bundled default sample when ``path`` is None."""
    if path is None:
        text = sample_path(DEFAULT_SAMPLE).read_text(encoding="utf-8")
        return parse_config(text, source=f"samples/{DEFAULT_SAMPLE}")
    p = Path(path)
    raw_name = str(path)
    looks_like_a_path = ("/" in raw_name or "\\" in raw_name or raw_name.endswith(".toml")
                         or raw_name.startswith("."))
    if not looks_like_a_path and not p.exists():
        name = f"{raw_name}.toml"
        if name in bundled_samples():
            text = sample_path(name).read_text(encoding="utf-8")
            return parse_config(text, source=f"samples/{name}")
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        names = ", ".join(n.removesuffix(".toml") for n in bundled_samples())
        raise ConfigError(str(p), f"no such file; expected a TOML configuration file, or the "
                                  f"bare name of a bundled sample ({names})") from None
    except IsADirectoryError:
        raise ConfigError(str(p), "is a directory; expected a TOML configuration file") from None
    except OSError as exc:
        raise ConfigError(str(p), f"cannot read: {exc.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(f"{p}:{line}", "not UTF-8 text; expected a TOML configuration") from None
    return parse_config(text, source=str(p))


def bundled_samples() -> list[str]:
    """File names of the bundled sample configurations."""
    return sorted(p.name for p in sample_path(DEFAULT_SAMPLE).parent.glob("*.toml"))


def sample_path(name: str) -> Path:
    """Path of a bundled sample, in the installed package or the source checkout."""
    installed = resources.files("sdit_path") / "samples" / name
    if installed.is_file():
        return Path(str(installed))
    checkout = Path(__file__).resolve().parent.parent / "samples" / name
    if checkout.is_file():
        return checkout
    raise ConfigError(name, "bundled sample not found; the installation is incomplete")
