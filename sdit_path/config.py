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
LINEAR_AXES = ("X", "Y", "Z")


@dataclass(frozen=True, slots=True)
class AxisLimits:
    """Travel and dynamic limits of one machine axis (program coordinates, mm)."""

    name: str
    travel_mm: tuple[float, float]
    max_velocity_mm_per_s: float
    max_acceleration_mm_per_s2: float
    max_jerk_mm_per_s3: float


@dataclass(frozen=True, slots=True)
class MachineConfig:
    name: str
    axes: tuple[AxisLimits, ...]

    def axis(self, name: str) -> AxisLimits:
        for ax in self.axes:
            if ax.name == name:
                return ax
        raise KeyError(name)


@dataclass(frozen=True, slots=True)
class BallbarConfig:
    """The instrument and where its pivot ball sits (program coordinates)."""

    bar_length_mm: float
    pivot_mm: tuple[float, float, float]
    ball_diameter_mm: float
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


@dataclass(frozen=True, slots=True)
class Config:
    source: str
    machine: MachineConfig
    ballbar: BallbarConfig
    test: TestConfig
    post: PostConfig
    text: str = field(default="", repr=False, compare=False)


# --------------------------------------------------------------------------- reading


def _line_of(text: str, dotted: str) -> int | None:
    """Best-effort line number (1-based) of a dotted key in TOML text."""
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
        line = _line_of(self.text, key) if key else None
        where = f"{self.source}:{line}" if line else self.source
        return ConfigError(where, f"{key}: {message}" if key else message)

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
            raise self.fail(key, f"expected one of {', '.join(choices)}, got {value!r}")
        return value

    def vector(self, data: dict, key: str, length: int, default: tuple | None = None,
               unit: str = "") -> tuple[float, ...]:
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
        return tuple(float(v) for v in value)

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


def _describe(value: Any) -> str:
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"string {value!r}"
    return f"{type(value).__name__} {value!r}"


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

_AXIS_KEYS = ("travel_mm", "max_velocity_mm_per_s", "max_acceleration_mm_per_s2",
              "max_jerk_mm_per_s3")


def _machine(r: _Reader, root: dict) -> MachineConfig:
    m = r.table(root, "machine", ("name", "axes"))
    name = r.string(m, "machine.name")
    axes_table = r.table(m, "machine.axes", LINEAR_AXES)
    axes = []
    for ax in LINEAR_AXES:
        key = f"machine.axes.{ax}"
        a = r.table(axes_table, key, _AXIS_KEYS)
        lo, hi = r.vector(a, f"{key}.travel_mm", 2, unit="mm")
        if not lo < hi:
            raise r.fail(f"{key}.travel_mm", f"expected [min, max] with min < max, got [{lo:g}, {hi:g}]")
        axes.append(AxisLimits(
            name=ax, travel_mm=(lo, hi),
            max_velocity_mm_per_s=r.number(a, f"{key}.max_velocity_mm_per_s", gt=0, unit="mm/s"),
            max_acceleration_mm_per_s2=r.number(a, f"{key}.max_acceleration_mm_per_s2", gt=0,
                                                unit="mm/s^2"),
            max_jerk_mm_per_s3=r.number(a, f"{key}.max_jerk_mm_per_s3", gt=0, unit="mm/s^3"),
        ))
    return MachineConfig(name=name, axes=tuple(axes))


def _ballbar(r: _Reader, root: dict, machine: MachineConfig) -> BallbarConfig:
    b = r.table(root, "ballbar", ("bar_length_mm", "pivot_mm", "ball_diameter_mm",
                                  "sensor_range_mm", "length_range_mm"))
    length_range = r.vector(b, "ballbar.length_range_mm", 2, default=(50.0, 600.0), unit="mm")
    if not 0 < length_range[0] <= length_range[1]:
        raise r.fail("ballbar.length_range_mm",
                     f"expected [min, max] with 0 < min <= max, got {list(length_range)}")
    length = r.number(b, "ballbar.bar_length_mm", gt=0, unit="mm")
    if not length_range[0] <= length <= length_range[1]:
        raise r.fail("ballbar.bar_length_mm",
                     f"expected a bar length within the instrument's reach "
                     f"{length_range[0]:g}..{length_range[1]:g} mm (ballbar.length_range_mm), "
                     f"got {length:g} mm")
    ball = r.number(b, "ballbar.ball_diameter_mm", default=12.7, gt=0, unit="mm")
    if not ball < length:
        raise r.fail("ballbar.ball_diameter_mm",
                     f"expected a ball diameter smaller than the bar length {length:g} mm, got {ball:g}")
    sensor = r.number(b, "ballbar.sensor_range_mm", default=1.0, gt=0, le=10.0, unit="mm")
    pivot = r.vector(b, "ballbar.pivot_mm", 3, unit="mm")
    for value, ax in zip(pivot, machine.axes):
        lo, hi = ax.travel_mm
        if not lo <= value <= hi:
            raise r.fail("ballbar.pivot_mm",
                         f"pivot {ax.name}={value:g} mm is outside the {ax.name} travel "
                         f"[{lo:g}, {hi:g}] mm (machine.axes.{ax.name}.travel_mm)")
    return BallbarConfig(bar_length_mm=length, pivot_mm=pivot, ball_diameter_mm=ball,
                         sensor_range_mm=sensor, length_range_mm=length_range)


def _test(r: _Reader, root: dict, machine: MachineConfig) -> TestConfig:
    t = r.table(root, "test", ("track_elevations_deg", "nodes_per_track", "subsegments_per_sector",
                               "dwell_s", "feed_mm_per_min", "passes", "transit", "projection",
                               "curve"))
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
    if elev[-1] >= 90:
        raise r.fail("test.track_elevations_deg",
                     f"expected elevations < 90 deg (the pole is the node TOP), got {elev[-1]:g}")
    nodes = r.integer(t, "test.nodes_per_track", 6, ge=1, le=72)
    subs = r.integer(t, "test.subsegments_per_sector", 3, ge=1, le=20)
    dwell = r.number(t, "test.dwell_s", 2.0, gt=0, le=3600, unit="s")
    feed = r.number(t, "test.feed_mm_per_min", gt=0, unit="mm/min")
    slowest = min(ax.max_velocity_mm_per_s for ax in machine.axes) * 60.0
    fastest_path = math.sqrt(sum((ax.max_velocity_mm_per_s * 60.0) ** 2 for ax in machine.axes))
    if feed > fastest_path:
        raise r.fail("test.feed_mm_per_min",
                     f"expected a feed the machine can reach (<= {fastest_path:.0f} mm/min from the "
                     f"axis velocity limits; slowest axis {slowest:.0f} mm/min), got {feed:g}")
    passes = r.strings(t, "test.passes", PASSES)
    for p in passes:
        if p not in PASSES:
            raise r.fail("test.passes", f"expected passes among {', '.join(PASSES)}, got {p!r}")
    if len(set(passes)) != len(passes):
        raise r.fail("test.passes", f"expected each pass at most once, got {list(passes)}")
    transit = r.string(t, "test.transit", "meridian", TRANSITS)
    projection = r.string(t, "test.projection", "stereographic", PROJECTIONS)
    c = r.table(t, "test.curve", ("amplitude", "waves_per_sector", "cap_elevation_deg"),
                required=False)
    amplitude = r.number(c, "test.curve.amplitude", 1.0, gt=0, le=1)
    waves = r.integer(c, "test.curve.waves_per_sector", 1, ge=1, le=10)
    cap = r.number(c, "test.curve.cap_elevation_deg", (elev[-1] + 90.0) / 2.0, unit="deg")
    if not elev[-1] < cap < 90:
        raise r.fail("test.curve.cap_elevation_deg",
                     f"expected a value between the top track ({elev[-1]:g} deg) and 90 deg, got {cap:g}")
    return TestConfig(track_elevations_deg=elev, nodes_per_track=nodes, subsegments_per_sector=subs,
                      dwell_s=dwell, feed_mm_per_min=feed, passes=passes, transit=transit,
                      projection=projection,
                      curve=CurveConfig(amplitude=amplitude, waves_per_sector=waves,
                                        cap_elevation_deg=cap))


def _post(r: _Reader, root: dict) -> PostConfig:
    from .nc.registry import known_controllers  # the registry is the one source of names

    p = r.table(root, "post", ("controllers", "program_prefix", "decimals", "spline_degree",
                               "spline_tolerance_um", "chord_tolerance_um", "work_offset",
                               "comment"))
    controllers = r.strings(p, "post.controllers", ("sinumerik840d", "linuxcnc"))
    known = known_controllers()
    for name in controllers:
        if name not in known:
            raise r.fail("post.controllers",
                         f"unknown controller {name!r}; known controllers: {', '.join(sorted(known))}")
    if len(set(controllers)) != len(controllers):
        raise r.fail("post.controllers", f"expected each controller once, got {list(controllers)}")
    offset = r.string(p, "post.work_offset", "G54")
    if not re.fullmatch(r"G5(00|[4-9]|0[5-9]|[1-9][0-9])|G54\.1 P[0-9]+", offset):
        raise r.fail("post.work_offset",
                     f"expected a work offset such as G54..G59 or G500 (machine frame), got {offset!r}")
    return PostConfig(
        controllers=controllers,
        program_prefix=r.string(p, "post.program_prefix", "SDIT"),
        decimals=r.integer(p, "post.decimals", 6, ge=3, le=9),
        spline_degree=r.integer(p, "post.spline_degree", 3, ge=2, le=3),
        spline_tolerance_um=r.number(p, "post.spline_tolerance_um", 0.01, gt=0, le=100, unit="um"),
        chord_tolerance_um=r.number(p, "post.chord_tolerance_um", 0.1, gt=0, le=100, unit="um"),
        work_offset=offset,
        comment=r.string(p, "post.comment", ""),
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
    r.no_unknown(root, "", ("machine", "ballbar", "test", "post"))
    machine = _machine(r, root)
    ballbar = _ballbar(r, root, machine)
    test = _test(r, root, machine)
    post = _post(r, root)
    return Config(source=source, machine=machine, ballbar=ballbar, test=test, post=post, text=text)


def load_config(path: str | Path | None = None) -> Config:
    """Load a config file, or the bundled default sample when ``path`` is None."""
    if path is None:
        text = sample_path(DEFAULT_SAMPLE).read_text(encoding="utf-8")
        return parse_config(text, source=f"samples/{DEFAULT_SAMPLE}")
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(str(p), "no such file; expected a TOML configuration") from None
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


def sample_path(name: str) -> Path:
    """Path of a bundled sample, in the installed package or the source checkout."""
    installed = resources.files("sdit_path") / "samples" / name
    if installed.is_file():
        return Path(str(installed))
    checkout = Path(__file__).resolve().parent.parent / "samples" / name
    if checkout.is_file():
        return checkout
    raise ConfigError(name, "bundled sample not found; the installation is incomplete")
